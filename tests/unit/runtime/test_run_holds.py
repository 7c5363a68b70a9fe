"""Holds across runs: a new run does not release what the run's end did not cause
(an agent with no Zenoh session, its clock and its inputs driven by hand)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from cohosted import ControlSample, Payload

from federation.core import wire
from federation.core.holds import Change, Hold, Trigger
from federation.core.keys import AgentId
from federation.runtime import links as links_module
from federation.runtime.agent import AgentRuntime
from federation.runtime.clock import ExecClock
from schemas.config import AgentConfig

LEAD = AgentId.parse("rome/l")


class _Sink:
    """A status publisher that keeps what it is given."""

    def __init__(self, into: list[str]):
        self.into = into

    def put(self, payload: str, **kwargs: Any) -> None:
        self.into.append(payload)


class Follower:
    def __init__(self, **settings: Any) -> None:
        self.now = 1000.0
        self.clock = ExecClock(source=lambda: self.now)
        config = AgentConfig(lab="kiruna", name="f", role="follower", follow=str(LEAD), **settings)
        self.agent = AgentRuntime(config, session=None, clock=self.clock)  # type: ignore[arg-type]
        self.statuses: list[str] = []
        self.agent.reporter.publisher = _Sink(self.statuses)
        self.agent.peer_seen(LEAD, True)
        self.seq = 0

    def sync(self) -> None:
        """One sync exchange with the leader (its clock 5 ms ahead, 10 ms round trip)."""
        link = self.agent.peers[LEAD].link
        assert link is not None
        t1 = wire.decode_request(link.client.request(self.clock.now()))
        self.now += 0.01
        link.client.receive(wire.encode_reply(t1, t1 + 0.010, wire.Pose()), self.clock.now())

    def synced(self) -> None:
        """Five exchanges with the leader, 0.1 s apart: its clock is known."""
        for _ in range(5):
            self.sync()
            self.now += 0.09

    def pose(self) -> None:
        t = self.clock.now()
        self.agent.latest_poses[LEAD] = wire.PoseSample(t, wire.Pose(heading=1.0, omega=0.5))
        self.agent.pose_received_at[LEAD] = t

    def command(self, name: str, **fields: Any) -> None:
        self.seq += 1
        if name == "start":
            fields = {"duration": 100.0} | fields  # a run must end
        command = {"command": name, "seq": self.seq, "issuer": "op"} | fields
        self.agent.commands.on_control(ControlSample(command))  # type: ignore[arg-type]

    def step(self, dt: float = 0.01) -> None:
        self.now += dt
        self.agent.control_step()

    def in_a_run(self) -> None:
        """Synced with the leader, in run r1 (started on receipt), its pose fresh."""
        self.synced()
        self.command("start", run_id="r1")
        self.pose()
        self.step()


@pytest.mark.parametrize("ending", ["done", "abort, reset"])
def test_a_new_run_does_not_release_a_follower_whose_pose_is_still_stale(ending: str) -> None:
    f = Follower()
    f.synced()
    f.command("start", run_id="r1", duration=1.5)
    f.pose()
    f.step()
    assert f.agent.run_state.mode == "running" and f.agent.hold is None
    f.step(1.0)  # the leader's pose stops: stale hold
    assert f.agent.hold == "stale" and f.agent.platform.held
    if ending == "done":
        f.step(1.0)  # the run's 1.5 s are over
    else:
        f.command("abort")
        f.step()
        f.command("reset")
        f.step()
    assert f.agent.run_state.mode in ("done", "waiting", "armed"), f.agent.run_state.mode
    assert f.agent.hold in ("done", "reset")
    assert f.agent.platform.held
    ready = f.agent.readiness(f.clock.now())
    assert not ready.platform and ready.platform_detail == "held (stale)"
    f.command("start", run_id="r2")
    for _ in range(3):
        f.sync()  # the leader still answers sync; only its pose has stopped
        f.step(0.5)
        assert f.agent.platform.held, f.agent.run_state.mode
        assert f.agent.hold == "stale"
    # The pose flows again and a sync completes since: the link watch releases it.
    f.pose()
    f.step()
    f.sync()
    f.pose()
    f.step()
    assert f.agent.hold is None and not f.agent.platform.held


def test_an_abort_nested_too_deep_to_read_is_still_honoured() -> None:
    # json.loads raised RecursionError on it; the handler logged a traceback and held
    # nothing: "an abort is honoured when it says abort in JSON" was broken.
    f = Follower()
    f.in_a_run()
    assert f.agent.run_state.mode == "running" and not f.agent.platform.held
    deep = b'{"command": "abort", "a": ' + b"[" * 200_000 + b"]" * 200_000 + b"}"
    f.agent.commands.on_control(_RawSample(deep))  # type: ignore[arg-type]
    assert f.agent.platform.held
    f.step()
    assert f.agent.run_state.mode == "aborted" and f.agent.hold == "aborted"
    assert f.agent.counters["control_malformed"] == 1


class _RawSample:
    def __init__(self, data: bytes):
        self.payload = Payload(data)
        self.key_expr = "fedlab/default/@control"


class _LeftItsArea:
    """A scenario whose platform has left its area (what control_step reads)."""

    workspace_held = True
    area_detail = "left its area"

    def __init__(self) -> None:
        self.runs = 0
        self.counters: dict[str, int] = {}

    def workspace(self) -> None:
        return None

    def reference(self, *args: object) -> None:
        return None

    def new_run(self) -> None:
        self.runs += 1


@pytest.mark.parametrize("ending", ["abort, reset", "done"])
def test_a_workspace_hold_outlasts_the_runs_end_and_the_next_start(ending: str) -> None:
    # Relabelled done/reset, then cleared by the next start: status showed no hold and
    # preflight passed, while the platform stayed held (or, on a platform without the
    # area's own guard, was released).
    f = Follower()
    f.synced()
    f.command("start", run_id="r1", duration=1.0)
    f.pose()
    f.step()
    scenario = _LeftItsArea()
    f.agent.scenario = scenario  # type: ignore[assignment]
    f.pose()
    f.step()
    assert f.agent.hold == "workspace" and f.agent.platform.held
    if ending == "done":
        f.pose()
        f.step(1.0)
    else:
        f.command("abort")
        f.step()
        f.command("reset")
        f.step()
    assert f.agent.hold == "workspace"
    f.command("start", run_id="r2")
    for _ in range(3):
        f.sync()
        f.pose()
        f.step(0.1)
    assert scenario.runs >= 1  # the new run's guidance starts afresh
    assert f.agent.hold == "workspace" and f.agent.platform.held
    ready = f.agent.readiness(f.clock.now())
    assert not ready.platform and ready.platform_detail == "held (workspace)"
    assert f.agent.status().hold == "workspace"


def test_no_pose_is_published_before_the_platforms_first_fix() -> None:
    # A restarted member published its filter's prior (its table's origin) as its pose,
    # and another member's formation track moved 0.27 m towards it.
    now = [1000.0]
    clock = ExecClock(source=lambda: now[0])
    config = AgentConfig(lab="rome", name="l", role="leader", platform="knatte")
    agent = AgentRuntime(config, session=None, clock=clock)  # type: ignore[arg-type]
    sent: list[bytes] = []

    class Publisher:
        def put(self, payload: bytes, **kwargs: Any) -> None:
            sent.append(payload)

    agent._pose_pub = Publisher()
    agent._source_info = lambda: None  # type: ignore[assignment, method-assign, return-value]
    agent.publish_pose()
    assert sent == [] and agent.counters["pose_withheld_no_fix"] == 1
    for _ in range(60):  # the simulated cameras' fixes, until they agree (0.3 s)
        now[0] += 0.01
        agent.control_step()
    agent.publish_pose()
    assert len(sent) == 1


def _stale_then_flowing() -> Follower:
    """A follower in a run, held for a stale pose, whose pose flows again and a sync
    has completed since: its next step (after a pose) judges the link resumed."""
    f = Follower()
    f.in_a_run()
    f.step(1.0)  # stale hold
    assert f.agent.hold == "stale"
    f.pose()
    f.sync()
    return f


def test_an_abort_handled_while_a_step_releases_a_link_hold_wins() -> None:
    # The step judged the link resumed; before its trigger reached the supervisor, the
    # abort ran in full on Zenoh's thread (valves closed, run aborted). The link's
    # release then lifts the stale hold alone: the abort's stands.
    f = _stale_then_flowing()
    real = f.agent.safety.apply

    def abort_meanwhile(trigger: Trigger) -> Change:
        if trigger is Trigger.LINK_RESUMED:
            assert f.agent.link_watch.holding is False  # judged resumed
            f.command("abort")  # on "Zenoh's thread", between the judgement and the release
        return real(trigger)

    f.agent.safety.apply = abort_meanwhile  # type: ignore[method-assign]
    f.pose()
    f.step()
    assert f.agent.run_state.mode == "aborted"
    assert f.agent.platform.held
    assert f.agent.hold == "aborted"  # the release saw the abort: held, said why


def test_no_release_judged_before_an_abort_follows_its_hold() -> None:
    # The abort held on Zenoh's thread and changed the run's mode only later; in between
    # the loop's step judged the link resumed, released (the run still "running") and
    # stepped with valves free after the abort's hold.
    import threading

    f = _stale_then_flowing()
    f.pose()  # the next step judges the link resumed
    platform = f.agent.platform
    real_hold, real_step = platform.hold, platform.step
    aborted_hold = threading.Event()
    held_at_step: list[bool] = []

    def hold() -> None:
        real_hold()
        if threading.current_thread() is not threading.main_thread():
            aborted_hold.set()
            threading.Event().wait(0.3)  # the abort's thread descheduled after its hold

    def step(*args: Any, **kwargs: Any) -> Any:
        held_at_step.append(platform.held)
        return real_step(*args, **kwargs)

    platform.hold = hold  # type: ignore[method-assign]
    platform.step = step  # type: ignore[method-assign]
    abort = threading.Thread(target=f.command, args=("abort",))
    abort.start()
    try:
        assert aborted_hold.wait(5.0)
        f.step()  # the loop's step, meanwhile
    finally:
        abort.join(5.0)
    assert held_at_step == [True], held_at_step  # no step after the abort's hold ran free
    f.step()
    assert f.agent.run_state.mode == "aborted" and platform.held
    assert f.agent.hold == "aborted"


def _late_start_meanwhile(f: Follower, meanwhile: Callable[[], None]) -> None:
    """A start just after its instant, applied on "Zenoh's thread", which is descheduled
    as it tells the supervisor the run started; ``meanwhile`` runs on the loop's thread
    in that pause."""
    import threading

    agent = f.agent
    real = agent.safety.apply_locked
    deciding = threading.Event()

    def slow(trigger: Trigger) -> Change:
        if (
            trigger is Trigger.RUN_STARTED
            and threading.current_thread() is not threading.main_thread()
        ):
            deciding.set()
            threading.Event().wait(0.3)  # descheduled before the decision
        return real(trigger)

    agent.safety.apply_locked = slow  # type: ignore[method-assign]
    t_sim = agent.sim_time(f.clock.now())
    assert t_sim is not None
    start = threading.Thread(
        target=f.command, args=("start",), kwargs={"run_id": "r1", "at": t_sim - 0.5}
    )
    start.start()
    try:
        assert deciding.wait(5.0)
        meanwhile()
    finally:
        start.join(5.0)
        agent.safety.apply_locked = real  # type: ignore[method-assign]


def test_a_start_released_on_zenohs_thread_does_not_undo_a_stale_hold_meanwhile() -> None:
    # A start arriving just after its instant starts the run on Zenoh's thread; the
    # loop's step meanwhile judges the leader's pose stale. Whichever the supervisor
    # hears first, the platform stays held for the stale link.
    f = Follower(wait_start=True)
    f.synced()
    f.pose()
    f.step()
    _late_start_meanwhile(f, lambda: f.step(1.0))  # the leader's pose 1 s old meanwhile
    agent = f.agent
    assert agent.run_state.mode == "running"
    assert agent.link_watch.holding and agent.platform.held and agent.hold == "stale"


def test_a_step_never_runs_free_while_a_cause_of_hold_stands() -> None:
    # Whatever released the platform (a path not yet thought of), the next step holds
    # it again while the link is judged stale or a cause is named.
    f = Follower()
    f.in_a_run()
    f.step(1.0)  # stale hold
    assert f.agent.hold == "stale"
    f.agent.platform.release()
    f.step(0.01)
    assert f.agent.platform.held and f.agent.hold == "stale"
    assert f.agent.counters["holds_restored"] == 1


def test_an_agent_begins_held_and_its_first_step_restores_nothing() -> None:
    # The supervisor begins with the agent waiting for its run: the platform is held
    # from the start, so the first step finds nothing released to hold again.
    for settings in ({}, {"wait_start": True}):
        f = Follower(**settings)
        assert f.agent.platform.held and f.agent.hold == "waiting"
        f.step()
        assert f.agent.platform.held
        assert f.agent.counters.get("holds_restored", 0) == 0


def test_a_command_for_other_participants_is_ignored() -> None:
    # A start for another lab's experiment had armed every waiting agent of the
    # federation, none preflighted or awaited, and released each at the start instant.
    f = Follower(wait_start=True)
    f.synced()
    f.pose()
    others = ["lab3/a", "lab3/b"]
    f.command("start", run_id="r1", experiment="docking", participants=others)
    f.step()
    assert f.agent.run_state.mode == "waiting" and f.agent.platform.held
    (outcome,) = [c for c in f.agent.command_log if c.command == "start"]
    assert outcome.outcome == "ignored" and "not a participant of docking" in outcome.detail
    f.command("start", run_id="r2", participants=[*others, "kiruna/f"])  # named: armed
    f.step()
    assert f.agent.run_state.mode in ("armed", "running")
    f.command("abort", participants=others)  # an abort is for everyone, named or not
    f.step()
    assert f.agent.run_state.mode == "aborted" and f.agent.platform.held


def test_a_follower_held_for_a_contested_leader_is_not_ready() -> None:
    f = Follower()
    f.agent.safety.apply(Trigger.CONTESTED)
    ready = f.agent.readiness(f.clock.now())
    assert not ready.platform and ready.platform_detail == "held (contested)"


def test_an_applied_command_is_reported_at_the_next_step_not_a_second_later() -> None:
    # ctl waits for it before a start: with a status a second apart, a start 1.5 s
    # ahead was often aborted for want of a confirmation.
    f = Follower()
    f.step()
    before = len(f.statuses)
    f.command("start", run_id="r1")
    f.step()
    assert len(f.statuses) == before + 1
    assert json.loads(f.statuses[-1])["commands"][-1]["command"] == "start"


def _heard(f: Follower, source: str) -> bool:
    """A pose of the leader from session ``source`` reaches the follower."""
    return f.agent.intake.contest_verdict(LEAD, "pose", source, f.now)


def _rejoins(f: Follower) -> None:
    f.agent.peer_seen(LEAD, False)
    f.now += 3.0
    f.agent.peer_seen(LEAD, True)


def test_the_reference_restarted_mid_run_aborts_the_run_here() -> None:
    """Its new process waits, flies no maneuver and may count time afresh: the follower
    had flown on, on the old clock, to the end of the run or never."""
    f = Follower()
    f.synced()
    f.command("start", run_id="r1", duration=60.0)
    assert _heard(f, "aaaa")
    f.pose()
    f.step()
    assert f.agent.run_state.mode == "running" and not f.agent.platform.held
    _rejoins(f)
    assert _heard(f, "bbbb")  # a new session for the leader
    assert f.agent.platform.held  # at once, on the thread that heard it
    assert f.agent.run_state.mode == "aborted" and f.agent.hold == "aborted"
    assert f.agent.counters["reference_restarted"] == 1
    f.step()
    assert f.agent.platform.held
    # A reset and a new start: the new session is the reference now.
    f.command("reset")
    f.synced()
    f.command("start", run_id="r2", duration=60.0)
    assert _heard(f, "bbbb")
    f.pose()
    f.step()
    assert f.agent.run_state.mode == "running" and not f.agent.platform.held


def test_a_cut_longer_than_the_lease_is_not_a_restart() -> None:
    """The reference left and came back with the same session: the run goes on."""
    f = Follower()
    f.synced()
    f.command("start", run_id="r1", duration=60.0)
    assert _heard(f, "aaaa")
    _rejoins(f)
    assert _heard(f, "aaaa")
    assert f.agent.run_state.mode == "running"
    assert f.agent.counters["reference_restarted"] == 0


@pytest.mark.parametrize("when", ["waiting", "no ctl run"])
def test_a_new_reference_session_outside_a_ctl_run_aborts_nothing(when: str) -> None:
    f = Follower()
    if when == "no ctl run":  # an agent started on its own runs from reference time 0
        f.agent.commands.run_state = type(f.agent.run_state)(autostart=True)
    f.synced()
    assert _heard(f, "aaaa")
    _rejoins(f)
    assert _heard(f, "bbbb")
    assert f.agent.run_state.mode != "aborted"
    assert f.agent.counters["reference_restarted"] == 0


def test_the_reference_clock_stepping_mid_run_aborts_the_run_here() -> None:
    """Run time would jump by the step (the run ends early, or never)."""
    f = Follower()
    f.synced()
    f.command("start", run_id="r1", duration=60.0)
    f.pose()
    f.step()
    for _ in range(5):  # the leader's clock jumps 2 s ahead: three exchanges confirm it
        link = f.agent.peers[LEAD].link
        assert link is not None
        t1 = wire.decode_request(link.client.request(f.clock.now()))
        f.now += 0.01
        reply = wire.encode_reply(t1, t1 + 2.010, wire.Pose())
        links_module.on_link_reply(link, _Reply(reply))  # type: ignore[arg-type]
        f.now += 0.09
    assert f.agent.counters["clock_steps"] == 1
    assert f.agent.run_state.mode == "aborted" and f.agent.platform.held
    assert f.agent.counters["reference_clock_steps"] == 1


class _Reply:
    """What ``_on_sync_reply`` reads of a zenoh.Reply (no replier id)."""

    def __init__(self, payload: bytes):
        self.ok = type("Ok", (), {"payload": Payload(payload), "attachment": None})
        self.replier_id = None


def test_a_start_for_a_run_recorded_here_already_is_refused(tmp_path: Path) -> None:
    """A run id used again had truncated the finished recording its manifest listed."""
    f = Follower()
    f.agent.config = f.agent.config.model_copy(update={"runs_dir": tmp_path})
    folder = tmp_path / "r1"
    folder.mkdir()
    old = folder / "kiruna-f.mcap"
    old.write_bytes(b"the first run's recording")
    f.synced()
    f.command("start", run_id="r1", duration=10.0)
    assert f.agent.run_state.run_id is None and f.agent.recordings.run is None
    outcome = f.agent.command_log[-1]
    assert outcome.outcome == "ignored" and "recorded here already" in outcome.detail
    assert old.read_bytes() == b"the first run's recording"
    f.command("start", run_id="r2", duration=10.0)
    assert f.agent.run_state.run_id == "r2" and f.agent.recordings.run is not None
    f.agent.recordings.end_run(wait=True)


def test_an_own_pose_that_is_not_finite_is_not_sent_and_holds() -> None:
    """encode_pose raised in the loop: every agent of the process stopped."""
    f = Follower()
    f.agent.pose = wire.Pose(heading=math.nan)
    f.agent.publish_pose()  # no publisher needed: nothing is sent
    assert f.agent.counters["pose_not_finite"] == 1 and f.agent.platform.held
    assert f.agent.hold == "nonfinite"  # said, and nothing releases it
    ready = f.agent.readiness(f.clock.now())
    assert not ready.platform and ready.platform_detail == "held (nonfinite)"


def test_a_full_disk_never_stops_the_loop(tmp_path: Path) -> None:
    from federation.runtime.runs import RunRecording

    run = RunRecording(tmp_path, "r1", "kiruna/f", None, "{}", None)
    run._status_file = open("/dev/full", "w", encoding="utf-8")  # noqa: SIM115
    run.status_line("{}")  # ENOSPC on flush: counted, not raised
    assert run.status_write_errors == 1
    run.finish(wait=True)
    run.status_line("{}")  # after finish, on another thread's close: nothing


def test_at_its_end_the_platform_is_held_before_the_last_status() -> None:
    """A status put or file write that waited had delayed the hold at a stop."""
    f = Follower()
    order: list[str] = []
    hold = f.agent.platform.hold
    f.agent.platform.hold = lambda: (order.append("hold"), hold())[1]  # type: ignore[method-assign]
    f.agent.reporter.publisher = type("Sink", (), {"put": lambda *a, **k: order.append("status")})()
    f.agent.end()
    assert order == ["hold", "status"] and f.agent.platform.held
    assert f.agent.hold == "ended"


def test_a_platform_waits_for_its_run_held() -> None:
    """A simulated KNATTE leader waiting for ctl start: its valves had fired from the
    agent's start, steering to heading 0 (422 valve-steps open in 10 s)."""
    now = [1000.0]
    clock = ExecClock(source=lambda: now[0])
    config = AgentConfig(
        lab="kiruna", name="knatte", role="leader", platform="knatte", wait_start=True
    )
    agent = AgentRuntime(config, session=None, clock=clock)  # type: ignore[arg-type]
    agent.reporter.publisher = _Sink([])
    opened = 0
    for _ in range(1000):  # 10 s waiting, its first fix included
        now[0] += 0.01
        agent.control_step()
        opened += sum(agent.platform.valves)  # type: ignore[attr-defined]
    assert agent.platform.held and agent.hold == "waiting" and opened == 0
    ready = agent.readiness(clock.now())
    assert ready.platform  # waiting is not a fault: preflight passes
    command = {"command": "start", "seq": 1, "issuer": "op", "at": clock.now() + 0.5,
               "run_id": "r1", "duration": 30.0}  # fmt: skip
    agent.commands.on_control(ControlSample(command))  # type: ignore[arg-type]
    for _ in range(40):  # armed: still held
        now[0] += 0.01
        agent.control_step()
    assert agent.run_state.mode == "armed" and agent.platform.held
    for _ in range(20):  # its start: released, flying its maneuver
        now[0] += 0.01
        agent.control_step()
    assert agent.run_state.mode == "running" and not agent.platform.held
    assert agent.hold is None


def test_the_platforms_counters_reach_status() -> None:
    # A real table's bad checksums, write timeouts and failsafe reports, or a simulated
    # one's closed steps, had reached neither status nor the recording.
    f = Follower(platform="pinocchio")
    f.step()  # held until its run is under way: the chain's valves closed, counted
    counters = f.agent.status().counters
    assert counters.get("closed_held", 0) >= 1, counters
    assert "imu_rejected" in counters and "closed_no_fix" in counters


def test_a_malformed_command_naming_its_issuer_is_reported_as_such() -> None:
    # A newer ctl's field (or a value out of range) was dropped without a trace in
    # status: ctl said "command not seen", not why.
    f = Follower()
    command = {"command": "start", "seq": 7, "issuer": "op", "run_id": "r1", "colour": "red"}
    f.agent.commands.on_control(ControlSample(command))  # type: ignore[arg-type]
    (outcome,) = [c for c in f.agent.command_log if c.seq == 7]
    assert (outcome.command, outcome.issuer, outcome.outcome) == ("start", "op", "malformed")
    assert "colour" in outcome.detail
    f.agent.commands.on_control(ControlSample({"nonsense": True}))  # type: ignore[arg-type]
    assert len(f.agent.command_log) == 1  # nothing to report it under
    assert f.agent.counters["control_malformed"] == 2


def test_a_release_for_one_cause_does_not_undo_a_hold_for_another() -> None:
    # A start applied on Zenoh's thread let go of the waiting hold by the run's mode
    # alone: a hold for another cause made meanwhile on the loop's thread (its own pose
    # not finite: held for good) was released and its reason wiped.
    f = Follower(wait_start=True)
    f.synced()
    f.pose()
    f.step()
    agent = f.agent
    assert agent.hold == "waiting"

    def nonfinite() -> None:
        agent.pose = wire.Pose(x=float("nan"))
        agent.publish_pose()

    _late_start_meanwhile(f, nonfinite)
    assert agent.run_state.mode == "running"
    assert agent.platform.held and agent.hold == "nonfinite"


@pytest.mark.parametrize(
    ("reason", "said"),
    [("fix_rejected", "fixes rejected"), ("device_restart", "not yet confirmed")],
)
def test_a_platform_closed_for_rejected_fixes_or_a_restart_is_not_ready(
    reason: str, said: str
) -> None:
    f = Follower(platform="pinocchio")
    f.agent.platform.chain.cause = reason  # type: ignore[attr-defined]
    ready = f.agent.readiness(f.clock.now())
    assert not ready.platform and said in ready.platform_detail


def test_a_held_platform_is_judged_by_what_would_close_it_unheld() -> None:
    # Waiting for its run the platform is held, its chain's reason "held": preflight
    # had passed a platform with no fix at all, and a restart from outliers then went
    # unseen until the run had started.
    f = Follower(platform="pinocchio", wait_start=True)
    chain = f.agent.platform.chain  # type: ignore[attr-defined]
    f.step()
    assert f.agent.platform.held and chain.reason == "held" and chain.cause == "no_fix"
    ready = f.agent.readiness(f.clock.now())
    # Its simulated camera's first fix came with the first step: one of three so far.
    assert not ready.platform
    assert ready.platform_detail == "metrology fixes being acquired (1 of 3 agree)"
    chain._restarted = True
    f.step()
    assert f.agent.hold == "fix_restart"  # seen while waiting, not at the start


class _Run:
    """A run recording whose finish takes ``seconds`` on its own thread."""

    run_id = "r1"

    def __init__(self, order: list[str], seconds: float):
        self.order, self.seconds = order, seconds

    def finish(self, wait: bool = False) -> Any:
        import threading

        def work() -> None:
            threading.Event().wait(self.seconds)
            self.order.append("finished")

        thread = threading.Thread(target=work)
        thread.start()
        if wait:
            thread.join()
        return thread


class _Entity:
    def __init__(self, order: list[str]):
        self.order = order

    def undeclare(self) -> None:
        self.order.append("undeclared")


def test_a_closing_agent_finishes_its_run_while_its_name_is_its_own() -> None:
    # Its token went first: a process started under the name at once found the run
    # unfinished and recovered it beside the finish.
    f, order = Follower(), []
    f.agent.recordings.run = _Run(order, 0.1)  # type: ignore[assignment]
    f.agent._declared = [_Entity(order)]
    f.agent.close()
    assert order == ["finished", "undeclared"]


def test_a_hosted_agent_closing_waits_for_no_disk() -> None:
    # In fedlab host the loop that steps the other agents closed an ended one: a large
    # recording's checksum had stalled them all.
    import time

    f, order = Follower(), []
    f.agent.recordings.run = _Run(order, 1.0)  # type: ignore[assignment]
    f.agent._declared = [_Entity(order)]
    t0 = time.monotonic()
    f.agent.close(wait=False)
    assert time.monotonic() - t0 < 0.5 and order == ["undeclared"]
    (thread,) = f.agent.finishing
    thread.join(5.0)
    assert order == ["undeclared", "finished"]


def test_an_estimate_restarted_from_outliers_holds_until_ctl_reset() -> None:
    # Agreeing outlier fixes are where the platform is only if the metrology is right:
    # a frozen one repeating a wrong value had taken over the estimate and flown by it.
    f = Follower(platform="pinocchio", wait_start=True)
    f.synced()
    f.command("start", run_id="r1", at=(f.agent.sim_time(f.clock.now()) or 0.0) + 0.02)
    for _ in range(20):  # the platform's first fixes agree: its chain controls
        f.pose()
        f.step()
    assert f.agent.run_state.mode == "running"
    assert f.agent.platform.chain.reason is None  # type: ignore[attr-defined]
    f.agent.platform.chain._restarted = True  # type: ignore[attr-defined]
    f.step()  # the chain closes every valve (fix_restart); the agent sees it next step
    f.step()
    assert f.agent.hold == "fix_restart" and f.agent.platform.held
    assert f.agent.run_state.mode == "aborted"  # the ctl run ended here
    assert f.agent.counters["fix_restart_holds"] == 1
    assert "fix_restart" in f.agent.readiness(f.clock.now()).platform_detail
    f.command("reset")
    f.step()
    assert not f.agent.platform.chain._restarted  # type: ignore[attr-defined]
    assert f.agent.hold == "reset"


@pytest.mark.parametrize("mode", ["waiting", "done", "aborted", "reset"])
def test_a_confirmed_reset_lifts_a_restarted_estimate_in_every_mode(mode: str) -> None:
    # An idle leader held for fix_restart while already waiting: ctl reset was confirmed
    # ("applied") and the hold stayed, since a reset while waiting changes no mode.
    f = Follower(platform="pinocchio", wait_start=True)
    f.synced()
    if mode == "done":
        f.command("start", run_id="r1", duration=0.05)
        f.pose()
        f.step()
        f.step(0.1)
    elif mode == "aborted":
        f.command("abort")
    elif mode == "reset":
        f.command("abort")
        f.command("reset")
    f.step()
    assert f.agent.run_state.mode == ("waiting" if mode == "reset" else mode)
    f.agent.platform.chain._restarted = True  # type: ignore[attr-defined]
    f.step()
    assert f.agent.safety.holds(Hold.FIX_RESTART) and f.agent.platform.held
    f.command("reset")
    (outcome,) = [c for c in f.agent.command_log if c.command == "reset"][-1:]
    assert outcome.outcome == "applied", outcome
    f.step()
    assert not f.agent.safety.standing & {Hold.FIX_RESTART, Hold.ABORTED, Hold.DONE}
    assert f.agent.hold == "reset" and f.agent.platform.held  # until the next start
    assert f.agent.readiness(f.clock.now()).platform_detail != "held (fix_restart)"


def test_a_closing_agent_takes_no_start_while_its_recording_finishes() -> None:
    # Its subscribers stay while the run's recording finishes (up to 30 s): a start then
    # armed a run no one would finish and released the platform after close's hold.
    import threading

    f = Follower(wait_start=True)
    f.synced()
    order: list[str] = []

    class Slow(_Run):
        def finish(self, wait: bool = False) -> Any:
            t_sim = f.agent.sim_time(f.clock.now())
            f.command("start", run_id="r2", at=(t_sim or 0.0) - 0.1)  # arrives meanwhile
            return super().finish(wait)

    f.agent.recordings.run = Slow(order, 0.05)  # type: ignore[assignment]
    closer = threading.Thread(target=f.agent.close)
    closer.start()
    closer.join(5.0)
    assert f.agent.run_state.mode == "waiting" and f.agent.platform.held
    (outcome,) = [c for c in f.agent.command_log if c.command == "start"]
    assert outcome.outcome == "ignored" and "stopping" in outcome.detail


def test_a_valve_command_not_confirmed_shows_in_status_and_preflight() -> None:
    # A serial write cut off: the valves are commanded closed but nothing says the device
    # got it (its heartbeat failsafe covers the line). That had reached neither status
    # nor preflight.
    f = Follower(platform="pinocchio")
    f.synced()
    assert f.agent.status().valves_confirmed is None  # no link to confirm
    f.agent.platform.valves_confirmed = False  # type: ignore[attr-defined]
    status = f.agent.status()
    assert status.valves_confirmed is False
    assert status.ready is not None and not status.ready.platform
    assert "not confirmed" in status.ready.platform_detail
    f.agent.platform.valves_confirmed = True  # type: ignore[attr-defined]
    status = f.agent.status()
    assert status.valves_confirmed is True and "confirmed" not in status.ready.platform_detail


def test_a_start_blocking_hold_set_or_lifted_is_reported_at_once() -> None:
    """A stale link's hold, set and lifted while waiting for a run, each publishes a
    status at its step (the loop's once-a-second status aside): preflight reads the
    latest status, so a hold lifted must not still show in it for up to a second."""
    f = Follower()
    f.synced()
    f.pose()
    f.step()
    f.step()
    assert f.agent.hold is None or f.agent.hold == "waiting", f.agent.hold
    quiet = len(f.statuses)
    for _ in range(5):  # the pose fresh: nothing to report between periodic statuses
        f.pose()
        f.step()
    assert len(f.statuses) == quiet
    f.step(1.0)  # the leader's pose stops: stale hold
    assert f.agent.safety.blocking() == "stale"
    assert len(f.statuses) == quiet + 1
    held = json.loads(f.statuses[-1])["ready"]
    assert not held["platform"] and held["platform_detail"] == "held (stale)"
    f.step()  # still stale: nothing new to say
    assert len(f.statuses) == quiet + 1
    # The pose flows again and a sync completes since: the link watch lifts the hold.
    f.pose()
    f.step()
    f.sync()
    f.pose()
    f.step()
    assert f.agent.safety.blocking() is None
    assert len(f.statuses) == quiet + 2
    assert json.loads(f.statuses[-1])["ready"]["platform"]
