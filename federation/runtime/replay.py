"""``fedlab replay``: a recorded agent's poses published on a live federation at their
recorded run time (a ghost), on an open Zenoh session.

The ghost stands where an agent would: a liveliness token on its name, a sync
queryable on its own clock (a follower of it syncs with it as with any agent), a pose
publisher and a status publisher. It syncs with the live run's reference as agents do
(:class:`~federation.runtime.syncglue.SyncQuerier`, :class:`~federation.core.sync.SyncClient`)
and stamps each pose on reference time (:func:`~federation.core.wire.encode_stamp`);
when the reference is its own name, its own clock is reference time. Its status says
``platform: "replay:<file>"`` and carries a ``replay`` field; live agents' statuses name
the run it plays against (:class:`~federation.core.replayplan.RunWatch`).

It fails closed: a pose due while the reference clock's estimate is missing or its
bound beyond ``max_bound`` is not sent (counted, its reason in the status). It ends, its
token undeclared, when the recording ends, when ``stop`` is set (a signal) or when the
live run is aborted or done. What is decided (which pose, which refusal) is in
:mod:`federation.core.replayplan`.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from federation.core import keys, wire
from federation.core.clockfilter import ClockFilter
from federation.core.keys import AgentId
from federation.core.replayplan import ReplayPlan, RunWatch, Target, refusals
from federation.core.sync import SyncClient, serve
from federation.runtime.clock import ExecClock
from federation.runtime.names import name_alive
from federation.runtime.replayfile import Recording, hardware_of
from federation.runtime.session import undeclare_all
from federation.runtime.syncglue import Answer, SyncQuerier, serve_query

__all__ = ["ReplayRefused", "Replayer", "check_target"]

log = logging.getLogger("fedlab.replay")

SYNC_PERIOD = 0.1  # s between sync requests to the reference
STATUS_PERIOD = 0.5  # s between status messages
MAX_STEP = 0.02  # s the loop sleeps at most (a run announced, a stop, a status)


class ReplayRefused(ValueError):
    """The replay may not take the name it was given: every reason, one per line."""


def check_target(
    session: zenoh.Session,
    federation: str,
    recording: Recording,
    target: AgentId,
    target_platform: str | None = None,
) -> None:
    """Raise :class:`ReplayRefused` if ``recording`` may not be replayed as ``target``
    (:data:`federation.core.replayplan.REFUSALS`); ``target_platform``: the platform the
    target name's own config says (None: the file's record of that name, if any)."""
    if target_platform is None and str(target) != recording.agent:
        target_platform = recording.platform_of(str(target))
    facts = Target(
        recorded=recording.agent,
        target=str(target),
        live=name_alive(session, keys.agent_key(federation, target)),
        recorded_hardware=hardware_of(recording.platform_of(recording.agent)),
        target_hardware=hardware_of(target_platform),
        target_known=target_platform is None or hardware_of(target_platform) is not None,
    )
    refused = refusals(facts)
    if refused:
        raise ReplayRefused("\n".join(f"refused ({row}): {text}" for row, text in refused))


class Replayer:
    """One ghost on an open session: ``start()``, ``run(stop)`` -> why it ended, ``close()``."""

    def __init__(
        self,
        session: zenoh.Session,
        federation: str,
        recording: Recording,
        me: AgentId,
        max_bound: float = 0.05,
        clock: ExecClock | None = None,
    ):
        self.session, self.federation, self.recording, self.me = session, federation, recording, me
        self.max_bound = max_bound
        self.clock = clock or ExecClock()
        self.plan = ReplayPlan(recording.poses())
        self.watch = RunWatch(str(me))
        self.pose = wire.Pose()
        self.reference: str | None = None  # LAB/NAME whose clock is reference time
        self.client: SyncClient | None = None
        self.withheld = 0
        self.withheld_why: str | None = None
        self.ended: str | None = None
        self.mode = "waiting"  # waiting, replaying, paused, ended
        self.run_time: float | None = None
        self._lock = threading.Lock()  # the reference, its client: Zenoh's threads and the loop
        self._querier: SyncQuerier | None = None
        self._declared: list[Any] = []
        self._pose_pub: Any = None
        self._pose_pub_id: Any = None
        self._status_pub: Any = None
        self._joined = False
        self._sn = 0

    def key(self, topic: str | None = None) -> str:
        return keys.agent_key(self.federation, self.me, topic)

    def start(self) -> None:
        """Declare the ghost: sync queryable, publishers, the statuses heard, its token."""
        s, callback = self.session, zenoh.handlers.Callback
        self._declared.append(
            s.declare_queryable(self.key("sync"), callback(self._on_sync_query, indirect=False))
        )
        self._pose_pub = s.declare_publisher(
            self.key("pose"), express=True, reliability=zenoh.Reliability.BEST_EFFORT
        )
        self._status_pub = s.declare_publisher(self.key("status"))
        self._declared += [self._pose_pub, self._status_pub]
        self._pose_pub_id = self._pose_pub.id  # read once: each read builds a new object
        self._declared.append(
            s.declare_subscriber(
                keys.all_of(self.federation, "status"), callback(self._on_status, indirect=False)
            )
        )
        self._declared.append(s.liveliness().declare_token(self.key()))
        log.info(
            "replay of %s from %s up as %s", self.recording.agent, self.recording.path, self.me
        )

    def close(self) -> None:
        """Say it ended, then undeclare everything (its token goes)."""
        self.mode = "ended"
        try:
            self.publish_status()
        except Exception as error:  # the session closing
            log.debug("last status not sent: %s", error)
        with self._lock:
            querier, self._querier = self._querier, None
        if querier is not None:
            querier.close()
        undeclare_all(self._declared)

    # -- time ------------------------------------------------------------------------
    def reference_now(self, t_exec: float) -> tuple[float, float] | None:
        """Reference time at own time ``t_exec`` and its error bound (None: not known)."""
        with self._lock:
            reference, client = self.reference, self.client
        if reference is None:
            return None
        if reference == str(self.me):
            return t_exec, 0.0
        if client is None:
            return None
        offset, delay, spread = client.offset_at(t_exec), client.delay, client.estimator.bound
        if offset is None or delay is None:
            return None
        return t_exec + offset, delay + (spread or 0.0)

    # -- the loop --------------------------------------------------------------------
    def run(self, stop: threading.Event) -> str:
        """Play until the recording ends, ``stop`` is set or the live run ends; why."""
        next_sync = next_status = time.monotonic()
        while self.ended is None:
            if stop.is_set():
                self.ended = "stopped"
                break
            host = time.monotonic()
            if host >= next_sync:
                self._request_sync()
                next_sync = host + SYNC_PERIOD
            wait = self.step()
            if host >= next_status:
                self.publish_status()
                next_status = host + STATUS_PERIOD
            if self.ended is None:
                stop.wait(max(0.0, min(wait, next_sync - host, next_status - host, MAX_STEP)))
        log.info("replay as %s ends: %s", self.me, self.ended)
        return self.ended

    def step(self) -> float:
        """Publish the pose due now, if any; seconds until the next one is due."""
        if self.watch.ended is not None:
            self.ended = f"the live run ended ({self.watch.ended})"
            return 0.0
        if self.plan.finished:
            self.ended = "the recording ended"
            return 0.0
        run = self.watch.run
        if run is None:
            return MAX_STEP
        with self._lock:
            if self.reference != run.reference:
                self._use_reference(run.reference)
        t_exec = self.clock.now()
        ref = self.reference_now(t_exec)
        if ref is None:
            self.mode, self.run_time = "waiting", None
            self.withheld_why = f"no estimate of {run.reference}'s clock yet"
            return MAX_STEP
        run_time = run.run_time(ref[0])
        self.run_time = run_time
        if run_time is None:
            self.mode = "paused"
            return MAX_STEP
        if not self._joined:
            self._joined = True
            if run_time > 0:  # a run under way: played from its present
                skipped = self.plan.skip_to(run_time)
                log.info(
                    "run %s under way at %.3f s: %d poses skipped", run.run_id, run_time, skipped
                )
        self.mode = "replaying"
        due = self.plan.due(run_time)
        if due is not None:
            # Stamped at the instant it was recorded for, not when it leaves: a pose sent
            # late (a busy host, the loop's step) says so by its age, as a live one does.
            lag = max(0.0, run_time - due.run_time)
            self._publish(due.pose, t_exec - lag, (ref[0] - lag, ref[1]))
        following = self.plan.next_due
        return MAX_STEP if following is None else following - run_time

    def _publish(self, pose: wire.Pose, t_exec: float, ref: tuple[float, float]) -> None:
        """Send one pose stamped on reference time, unless the stamp is not good enough."""
        with self._lock:
            reference = self.reference
        assert reference is not None
        if ref[1] > self.max_bound:
            self.withheld += 1
            self.withheld_why = (
                f"reference bound {ref[1] * 1e3:.1f} ms > {self.max_bound * 1e3:.1f} ms"
            )
            return
        self.pose = pose
        self._sn += 1
        self._pose_pub.put(
            wire.encode_pose(t_exec, pose),
            source_info=zenoh.SourceInfo(self._pose_pub_id, self._sn),
            attachment=wire.encode_stamp(wire.reference_id(reference), ref[0], ref[1]),
        )

    # -- sync with the reference -----------------------------------------------------
    def _use_reference(self, reference: str) -> None:
        """Sync with ``reference`` from now on (under the lock)."""
        if self._querier is not None:
            self._querier.close()
        self.reference, self.client, self._querier = reference, None, None
        if reference == str(self.me):
            return
        self.client = SyncClient(ClockFilter(), timeout=0.5)
        key = keys.agent_key(self.federation, AgentId.parse(reference), "sync")
        self._querier = SyncQuerier(self.session, key, 0.5, self.clock.read, self._on_answer)

    def _request_sync(self) -> None:
        with self._lock:
            client, querier = self.client, self._querier
            if client is None or querier is None:
                return
            payload = client.request(self.clock.now())
        try:
            querier.request(payload)
        except Exception as error:  # the session closing, a refusal: the next one may pass
            log.debug("sync request to %s failed: %s", self.reference, error)

    def _on_answer(self, answer: Answer) -> None:
        with self._lock:
            if answer.ok and self.client is not None:
                self.client.receive(answer.payload(), answer.t3)

    def _on_sync_query(self, query: zenoh.Query) -> None:
        t2 = self.clock.now()  # read on arrival: the paper's t2

        def answer(payload: zenoh.ZBytes | None) -> tuple[bytes, bytes | None] | None:
            request = b"" if payload is None else payload.to_bytes()
            try:
                served = serve(request, t2, self.pose, self.clock.now())
            except wire.DecodeError:
                return None
            return served.payload, served.attachment

        serve_query(query, answer)

    # -- statuses --------------------------------------------------------------------
    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            if parsed is None:
                return
            status = json.loads(sample.payload.to_bytes())
            if isinstance(status, dict) and status.get("agent") == str(parsed[0]):
                self.watch.observe(str(parsed[0]), status)
                with self._lock:  # synced before a run: a start finds the estimate ready
                    reference = status.get("reference")
                    heard = status.get("replay") is None and str(parsed[0]) != str(self.me)
                    if self.reference is None and isinstance(reference, str) and heard:
                        self._use_reference(reference)
        except Exception:
            log.exception("status on %s failed", sample.key_expr)

    def status(self) -> dict[str, Any]:
        """The ghost's status: marked a replay (``platform``, ``replay``)."""
        t_exec = self.clock.now()
        ref = self.reference_now(t_exec)
        run = self.watch.run
        return {
            "agent": str(self.me), "federation": self.federation, "role": "leader",
            "reference": self.reference or str(self.me), "t_exec": t_exec,
            "t_sim": None if ref is None else ref[0], "mode": self.mode,
            "run_time": self.run_time, "run_id": None if run is None else run.run_id,
            "platform": f"replay:{Path(self.recording.path).name}", "follow": None,
            "peers": {},
            "replay": {
                "file": str(self.recording.path), "agent": self.recording.agent,
                "reference_bound": None if ref is None else ref[1],
                "poses_sent": self.plan.given - self.withheld, "poses_skipped": self.plan.skipped,
                "poses_withheld": self.withheld, "withheld_why": self.withheld_why,
                "recorded_run_time": self.plan.last_run_time, "ended": self.ended,
            },
        }  # fmt: skip

    def publish_status(self) -> None:
        if self._status_pub is not None:
            self._status_pub.put(json.dumps(self.status()))


def replay(
    session: zenoh.Session,
    federation: str,
    path: Path,
    agent: AgentId,
    stop: threading.Event,
    as_name: AgentId | None = None,
    as_platform: str | None = None,
    max_bound: float = 0.05,
) -> str:
    """Replay ``agent``'s recording in ``path`` as ``as_name`` (default: its own name)
    until it ends; why it ended. Raises :class:`ReplayRefused` (a ``ValueError``, as is
    a file that holds no poses of ``agent``) before anything is declared."""
    recording = Recording(path, str(agent))
    target = as_name or agent
    check_target(session, federation, recording, target, as_platform)
    ghost = Replayer(session, federation, recording, target, max_bound)
    ghost.start()
    try:
        return ghost.run(stop)
    finally:
        ghost.close()
