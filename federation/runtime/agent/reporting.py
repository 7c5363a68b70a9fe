"""What an agent says of itself: its counters, its status line (published, appended
to ``--status-json`` and recorded), what preflight checks (``ready``), and the
warnings status gives rise to (a link near the loop's delay margin, a silent peer)."""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from typing import IO, TYPE_CHECKING, Any

import zenoh

from agents.analysis import Margins, heading_margins
from federation.core.channels import Channel
from federation.core.counters import Count
from federation.core.ring import FloatRing
from federation.runtime.runs import low_space
from federation.runtime.status import loop_stats
from schemas.messages import Readiness, Status

if TYPE_CHECKING:
    from agents.interface import Platform
    from federation.runtime.agent.commands import RunControl
    from federation.runtime.agent.intake import PoseIntake
    from federation.runtime.agent.peers import PeerTable
    from federation.runtime.agent.recordings import Recordings
    from federation.runtime.agent.services import AgentServices

__all__ = ["RateLimitedLog", "Reporter"]

log = logging.getLogger("fedlab.agent")

_CHAIN_DETAIL = {
    "no_fix": "no metrology fix yet",
    "stale_fix": "metrology fix stale",
    "stale_imu": "IMU silent",
    "settling": "estimate settling (its velocity not yet known)",
    "nonfinite": "estimate or reference not finite",
    "fix_rejected": "metrology fixes rejected ({rejected})",
    "fix_restart": "estimate restarted from outlier fixes: ctl reset",
    "device_restart": "device restarted, not yet confirmed",
}
"""What preflight says of the reason the GNC chain would keep every valve closed."""


class RateLimitedLog:
    """Logs the first ``burst`` events of a kind, then every ``every``-th, with its count."""

    def __init__(self, logger: logging.Logger, burst: int = 5, every: int = 100):
        self.logger, self.burst, self.every = logger, burst, every
        self.counts: Counter[str] = Counter()
        self._lock = threading.Lock()

    def __call__(self, kind: str, message: str) -> None:
        with self._lock:
            self.counts[kind] += 1
            n = self.counts[kind]
        if n <= self.burst or n % self.every == 0:
            self.logger.warning("rejected %s (#%d): %s", kind, n, message)


def _margins(platform: Platform) -> Margins | None:
    """Heading-loop margins of a platform that has a physical description."""
    config = platform.config
    if config is None:
        return None
    try:
        return heading_margins(config)
    except ValueError as error:
        log.warning("no delay margin for %s: %s", config.name, error)
        return None


class Reporter:
    """The counters and status of ``owner`` (an agent), from what its parts hold."""

    def __init__(
        self,
        owner: AgentServices,
        intake: PoseIntake,
        peer_table: PeerTable,
        commands: RunControl,
        recordings: Recordings,
    ):
        self.owner = owner
        self.intake = intake
        self.peer_table = peer_table
        self.commands = commands
        self.recordings = recordings
        self.counters: Counter[Count] = Counter()
        self._count_lock = threading.Lock()
        self.lateness = FloatRing(2000)  # control ticks' lateness (s)
        self.rejects = RateLimitedLog(log)
        self.margins = _margins(owner.platform)
        self._delay_warned = False
        self.status_file: IO[str] | None = None
        self.publisher: Any = None  # the status publisher, declared at start
        # The status's rejoin and admit_run fields (the agent's rejoin gives them).
        self.rejoin_report: Callable[[], dict[str, str | None]] = dict
        self.role_report: Callable[[], dict[str, object]] = dict  # the status's claim

    def count(self, name: Count) -> None:
        """Bump a counter; callbacks may run on several Zenoh threads at once."""
        with self._count_lock:
            self.counters[name] += 1

    def snapshot(self) -> dict[Count, int]:
        """Every counter: the agent's, its scenario's, its platform's, its run recording's."""
        owner = self.owner
        with self._count_lock:
            counters = dict(self.counters)
        if owner.scenario is not None:  # workspace clamps and holds, relative sensing
            counters |= owner.scenario.counters
        # The platform's own: a serial link's bad checksums, write timeouts, the device's
        # failsafe reports and restarts, the chain's closed steps.
        counters |= owner.platform.counters
        return counters | self.recordings.counters()

    def loop_stats(self) -> dict[str, float]:
        """Control loop timing: rate and lateness of the recent ticks (ms)."""
        return loop_stats(self.owner.platform.rate, self.lateness.values())

    # -- status ----------------------------------------------------------------------
    def status(self) -> Status:
        owner = self.owner
        t_exec, host = owner.clock.read()
        t_sim = owner.sim_time(t_exec)
        follow = owner.follow
        received = self.intake.latest_poses.get(follow) if follow else None
        # Its samples are stamped on its clock: their age is measured on it.
        follow_now = owner.timebase.peer_time(follow, t_exec) if follow else None
        pose_age = None if received is None or follow_now is None else follow_now - received.t
        state = self.commands.run_state
        return Status(
            agent=str(owner.me), federation=owner.config.federation, role=owner.config.role,
            reference=str(owner.reference), t_exec=t_exec, host_monotonic=host, t_sim=t_sim,
            mode=state.mode, run_time=state.run_time(t_sim), run_id=state.run_id,
            duration=state.duration, start_at=state.start_at, frozen_total=state.frozen_total,
            experiment=self.commands.experiment, ready=self.readiness(t_exec),
            commands=list(self.commands.log), platform=owner.config.platform,
            follow=None if follow is None else str(follow), hold=owner.safety.hold,
            pose_age=pose_age, valves_confirmed=owner.platform.valves_confirmed,
            pose=list(owner.pose), peers=self.peer_table.views(t_exec, host),
            counters=owner.counter_snapshot(), contested=self.intake.contested(host),
            workspace=None if owner.scenario is None else owner.scenario.workspace(),
            loop=self.loop_stats(), **self.commands.transitions(), **self.rejoin_report(),
            **self.role_report(),
        )  # fmt: skip

    def readiness(self, t_exec: float) -> Readiness:
        """What preflight checks: platform, recording, the reference clock's estimate."""
        owner = self.owner
        locked, bound = True, 0.0 if owner.reference == owner.me else None
        if owner.reference != owner.me:
            peer = self.peer_table.peers.get(owner.reference)
            with self.peer_table.lock:
                client = None if peer is None else peer.client
                estimator = None if client is None else client.estimator
                locked = estimator is not None and estimator.locked
                bound = None if estimator is None else estimator.bound
        cfg = owner.config
        recording = self.recordings.recorder is not None
        target = cfg.record if recording else cfg.runs_dir
        low = low_space(cfg) if not recording else None
        detail = self.platform_detail()
        return Readiness(
            platform=not detail,
            platform_detail=detail,
            recording=target is not None and low is None,
            recording_to=low or (None if target is None else str(target)),
            reference_locked=locked,
            reference_bound=bound,
        )

    def platform_detail(self) -> str:
        """Why the platform is not ready ("" if it is): a hold a start does not lift, a
        valve command not confirmed, or why the chain would keep every valve closed were
        the platform not held (held waiting for its run, the chain's reason is "held":
        a platform with no fix fails preflight all the same)."""
        owner = self.owner
        blocking = owner.safety.blocking()
        if blocking is not None:
            return f"held ({blocking})"
        platform = owner.platform
        if platform.valves_confirmed is False:
            return "valve command not confirmed (a write to the device was cut off)"
        reason, acquiring = platform.cause, platform.acquiring
        if acquiring is not None and reason in ("no_fix", "stale_fix"):
            return f"metrology fixes being acquired ({acquiring[0]} of {acquiring[1]} agree)"
        rejected = platform.last_rejection or "off the table or outliers"
        return _CHAIN_DETAIL.get(reason or "", "").format(rejected=rejected)

    # -- publishing ------------------------------------------------------------------
    def publish(self) -> None:
        """Build the status, publish it, append it to ``--status-json`` and the run's
        recording, record it; warn of what it shows."""
        owner = self.owner
        status = owner.status()  # the agent's, as a kind of agent may say more
        self._check_delay_margin(status)
        self.peer_table.warn_silent(status)
        line = status.model_dump_json()
        self.publisher.put(line, encoding=zenoh.Encoding.APPLICATION_JSON)
        if self.status_file is not None:
            try:
                self.status_file.write(line + "\n")
                self.status_file.flush()
            except (OSError, ValueError) as error:  # a full disk: the agent flies on
                self.count(Count.STATUS_WRITE_ERRORS)
                self.rejects("status line", f"{owner.config.status_json}: {error}")
        if not self.recordings.status_line(line):
            self.count(Count.STATUS_WRITE_ERRORS)
        if owner.recording(Channel.STATUS):
            owner.record(Channel.STATUS, line.encode())  # the line published: encoded once

    def _check_delay_margin(self, status: Status) -> None:
        """Warn once when the followed link's delay exceeds a quarter of the loop's delay
        margin (``fedlab analyze``); again if it recovers and crosses once more."""
        follow = self.owner.follow
        if self.margins is None or follow is None:
            return
        view = status.peers.get(str(follow))
        delay = None if view is None else view.delay
        warning = None if delay is None else self.margins.warn(delay)
        if warning and not self._delay_warned:
            log.warning("%s", warning)
        self._delay_warned = warning is not None

    def close(self) -> None:
        if self.status_file is not None:
            self.status_file.close()
            self.status_file = None
