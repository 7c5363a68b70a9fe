"""``fedlab replay`` against a live run on loopback: a leader and a follower fly the
paper's maneuver live, both recorded; the leader's recording is then replayed as a
ghost that a new live follower tracks. The follower receives the ghost's poses
stamped on the live reference clock, its reference trails the recorded heading by a
few ms at most, its heading's RMS error from the leader's is within 1.5 times the one
it had against the live leader, the ghost's status says it is a replay, and a second
replay under the live ghost's name is refused (exit 2)."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from lifecycle import fedlab
from loopback import FOLLOWER, LEADER, Labs, Process, client_config

from federation.core import keys, wire
from federation.fleet.launch import wait_for
from federation.report import tracking
from federation.report.analysis import best_shift
from federation.runtime.mcapfile import read_messages
from federation.runtime.replayfile import Recording

pytestmark = pytest.mark.integration


MOVING = (0.7, 3.8)  # s of run time the leader turns in (the maneuver's still 0.5 s before)


def experiment(path: Path, agent: str, duration: float, follower: str | None = None) -> Path:
    """An experiment ``agent`` leads (its clock is reference time); ``follower``, if
    given, follows it."""
    follows = (
        f'[[participants]]\nagent = "{follower}"\nrole = "follower"\nplatform = "pinocchio"\n'
        f'follow = "{agent}"\n'
        if follower
        else ""
    )
    path.write_text(
        f'name = "replay"\nduration = {duration}\nstart_delay = 1.0\n'
        "[maneuver]\nstill = 0.5\nduration = 10.0\namplitude_deg = 20.0\n"
        f'[[participants]]\nagent = "{agent}"\nrole = "leader"\nplatform = "knatte"\n' + follows,
        encoding="utf-8",
    )
    return path


def ready(line: dict[str, Any]) -> bool:
    """Waiting for a start, its platform's fix taken and the reference clock locked."""
    checks = line.get("ready") or {}
    return (
        line["mode"] == "waiting"
        and bool(checks.get("platform"))
        and bool(checks.get("reference_locked"))
    )


def heading_rms_deg(follower: Path, leader: Path) -> float:
    """RMS (deg) of the follower's heading sent minus the leader's at the same run time,
    over the maneuver (``MOVING``), from the two recordings."""
    return tracking.recorded_error(follower, leader, MOVING, FOLLOWER, LEADER).rms_deg


def run_times(record: Path, agent: str) -> list[float]:
    """The run times of the poses ``agent`` sent in its run, from its recording."""
    return [p.run_time for p in Recording(record, agent).poses() if p.run_time is not None]


def assert_full_rate(record: Path, agent: str) -> None:
    """20 Hz with no gap: the 4 s run's 80 poses less 10, and the maneuver's 62 (3.1 s)
    less 6. ``fedlab bench replay``'s smoke test scores the same recordings beside the
    parallel suite, where a starved process leaves gaps (49 of 56 seen); the rate is
    asserted here, where the cores are free."""
    times = np.array(run_times(record, agent))
    low, high = MOVING
    moving = int(((times >= low) & (times <= high)).sum())
    print(f"{agent} in {record.name}: {len(times)} poses in its run, {moving} moving")
    assert len(times) > 70 and moving > 56, (record.name, agent, len(times), moving)


def start(exp: Path, run_id: str, endpoint: str) -> None:
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(exp), "--run-id", run_id, "--in", "1.5", "-e", endpoint
    )
    assert started.returncode == 0, started.stdout + started.stderr


class Heard:
    """The ghost's poses (payload, stamp) and statuses as a client hears them."""

    def __init__(self, endpoint: str, who: str):
        self.poses: list[tuple[wire.PoseSample, wire.RefStamp]] = []
        self.statuses: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self.session = zenoh.open(client_config(endpoint))
        agent = keys.AgentId.parse(who)
        self.subs = [
            self.session.declare_subscriber(keys.agent_key("default", agent, "pose"), self._pose),
            self.session.declare_subscriber(
                keys.agent_key("default", agent, "status"), self._status
            ),
        ]

    def _pose(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment
        assert attachment is not None
        with self._lock:
            self.poses.append(
                (
                    wire.decode_pose(sample.payload.to_bytes()),
                    wire.decode_stamp(attachment.to_bytes()),
                )
            )

    def _status(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.statuses.append(json.loads(sample.payload.to_bytes()))

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


# The trail within 5 ms holds while the ghost's poses flow with no gap past the link
# watch's threshold: a claim about the host's time. Beside the parallel suite a starved
# replay process left a 172 ms gap, a safe hold, and a 56.7 ms trail after the capture.
@pytest.mark.timing
def test_a_replayed_leader_drives_a_live_follower(labs: Labs, tmp_path: Path) -> None:
    router = labs.router("kiruna")
    # A short live run, both recorded: the leader's recording is the one replayed.
    exp = experiment(tmp_path / "rec.toml", LEADER, 4.0, follower=FOLLOWER)
    leader = labs.agent(LEADER, router, "--experiment", str(exp), record=True)
    live = labs.agent(
        FOLLOWER, router, "--experiment", str(exp), "--sync-window", "2",
        role="follower", follow=LEADER, record=True,
    )  # fmt: skip
    for agent in (leader, live):  # a start needs both platforms' fix and a locked estimate
        agent.until(ready, timeout=15, what="ready")
    start(exp, "recorded", router.endpoint)
    for agent in (leader, live):
        agent.until(lambda s: s["mode"] == "done", timeout=10, what="done")
    assert leader.stop() == 0 and live.stop() == 0
    recorded = list(Recording(leader.record, LEADER).poses())
    assert recorded and recorded[-1].run_time > 3.5
    assert_full_rate(leader.record, LEADER)
    assert_full_rate(live.record, FOLLOWER)
    # Read now: the follower flown against the replay records to the same file.
    against_live = heading_rms_deg(live.record, leader.record)

    # Live: a follower of the recorded leader's name, its own clock the reference, on the
    # platform it flew against the live leader.
    config = tmp_path / "follower.toml"
    config.write_text(
        f'lab = "rome"\nname = "pinocchio"\nrole = "follower"\nfollow = "{LEADER}"\n'
        f'reference = "{FOLLOWER}"\nplatform = "pinocchio"\n',
        encoding="utf-8",
    )
    follower = labs.agent(
        FOLLOWER, router, "--agent-config", str(config), "--wait-start", "--sync-window", "2",
        role="follower", follow=LEADER, record=True,
    )  # fmt: skip
    follower.until(lambda s: s["mode"] == "waiting", timeout=10, what="waiting")
    heard = Heard(router.endpoint, LEADER)
    try:
        ghost = Process(
            labs.fleet, "replay",
            ["replay", str(leader.record), "--agent", LEADER, "-e", router.endpoint],
        )  # fmt: skip
        ghost.start()
        assert wait_for(lambda: bool(heard.statuses), timeout=10), ghost.log()
        # Refused while the ghost holds the name.
        refused, _ = fedlab("replay", str(leader.record), "--agent", LEADER, "-e", router.endpoint)
        assert refused.returncode == 2, refused.stdout + refused.stderr
        assert f"an agent named {LEADER} is live" in refused.stderr
        follower.wait_samples(LEADER, 10, timeout=10)  # the follower syncs with the ghost
        start(experiment(tmp_path / "live.toml", FOLLOWER, 4.0), "live", router.endpoint)
        line = follower.until(lambda s: s["mode"] == "done", timeout=12, what="done")
        assert wait_for(lambda: not ghost.alive(), timeout=5), "the ghost did not end"
        assert ghost.stop() == 0
        assert "replay of kiruna/knatte ended" in ghost.log()
    finally:
        heard.close()
    assert follower.stop() == 0
    assert_full_rate(follower.record, FOLLOWER)

    status = heard.statuses[-1]
    assert status["platform"] == f"replay:{leader.record.name}", status
    assert status["replay"]["agent"] == LEADER and status["replay"]["poses_sent"] > 50, status
    # Stamped on the live reference clock: a pose's reference time is its recorded run time.
    start_at = line["start_at"]
    times = np.array([p.run_time for p in recorded])
    heading = np.array([p.pose.heading for p in recorded])
    assert len(heard.poses) > 50
    errors = []
    # A stamp's bound is the ghost's one-way delay plus its estimate's bound
    # (docs/protocol.md): a few ms on an idle loopback, tens on shared cores (42 ms seen).
    for pose, stamp in heard.poses:
        assert stamp.t_ref is not None and stamp.bound is not None and 0 < stamp.bound < 0.25
        assert stamp.ref_id == wire.reference_id(FOLLOWER)
        recorded_at = times[heading == pose.pose.heading]  # the recorded pose it replays
        assert len(recorded_at), pose
        errors.append(float(np.min(np.abs(recorded_at - (stamp.t_ref - start_at)))))
    late = max(errors)
    print(f"ghost poses: {len(heard.poses)}, stamp vs recorded run time: max {late * 1e6:.3f} µs")
    assert late < 1e-6  # stamped at the instant recorded, however late it left
    # The follower's reference trails the recorded heading by a few ms.
    reference = [
        m for m in read_messages(follower.record)["/reference"] if m.get("run_time") is not None
    ]
    trail = best_shift(
        [m["run_time"] for m in reference], np.unwrap([m["heading_ref"] for m in reference]),
        times, np.unwrap(heading), MOVING,
    )  # fmt: skip
    assert trail is not None
    print(f"follower reference trails the recorded heading by {trail * 1e3:.2f} ms")
    assert abs(trail) < 0.005
    # The same leader's maneuver, live and replayed: the follower tracks both alike.
    against_replay = heading_rms_deg(follower.record, leader.record)
    ratio = against_replay / against_live
    print(
        f"follower heading RMS error over the maneuver: {against_live:.4f} deg against the "
        f"live leader, {against_replay:.4f} deg against its replay (ratio {ratio:.3f})"
    )
    assert against_replay <= 1.5 * against_live
