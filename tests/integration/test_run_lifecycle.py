"""A run between two labs from start to end, with real processes: preflight refuses a
start with a participant missing; a run ends in ``done`` on its own with valves
closed and its recording finalized; a second run starts without restarting any
agent; an abort is honoured after poisoned commands; ctl fails fast on a closed port."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from lifecycle import QUICK_LOCK, as_json, fedlab, participants, runs_dir, write_experiment
from loopback import FOLLOWER, LEADER, STATUS_PERIOD, Labs

from federation.core import keys
from federation.fleet.launch import free_port, wait_for
from federation.runtime.control import START_IN_MIN
from federation.runtime.recorder import read_messages, read_metadata

pytestmark = pytest.mark.integration

LOCKED = 25.0  # s: the agents start (slow on a busy host), then the estimate locks 2 s in
RUN = 3.0  # s of the first run: a run that ends on its own, as one of any length does


def finalized(labs: Labs, who: str, run_id: str) -> Path:
    """``who``'s recording of ``run_id`` once its manifest is written (bounded wait)."""
    stem = who.replace("/", "-")
    folder = runs_dir(labs, who) / run_id
    manifest = folder / f"{stem}.manifest.json"
    assert wait_for(manifest.exists, timeout=10), f"{who}: {run_id} never finalized"
    return folder / f"{stem}.mcap"


def locked(line: dict[str, object]) -> bool:
    ready = line.get("ready") or {}
    return bool(isinstance(ready, dict) and ready.get("reference_locked"))


def test_start_with_a_participant_missing_starts_nothing(labs: Labs, tmp_path: Path) -> None:
    pair = labs.pair()
    experiment = write_experiment(tmp_path / "exp.toml", 20)
    leader = labs.agent(
        LEADER, pair.kiruna, "--experiment", str(experiment),
        "--runs-dir", str(runs_dir(labs, LEADER)),
    )  # fmt: skip
    leader.until(lambda line: line["mode"] == "waiting", timeout=20, what="waiting")
    done, _ = fedlab("ctl", "start", "--experiment", str(experiment), "-e", pair.kiruna.endpoint)
    assert done.returncode == 1, done.stdout + done.stderr
    assert FOLLOWER in done.stdout and "absent" in done.stdout, done.stdout
    assert "nothing was started" in done.stdout
    seen = len(leader.lines())  # three status lines more: still waiting, nothing armed
    assert wait_for(lambda: len(leader.lines()) >= seen + 3, timeout=10), leader.latest()
    assert all(line["mode"] == "waiting" for line in leader.lines())
    status, _ = fedlab(
        "ctl", "status", "--json", "--experiment", str(experiment), "-e", pair.kiruna.endpoint
    )
    table = as_json(status)
    assert status.returncode == 1 and table["ready"] is False
    rows = {row["agent"]: row for row in table["agents"]}
    assert rows[LEADER]["checks"]["synced"]["ok"] and not rows[FOLLOWER]["ok"]


@pytest.mark.scenario
def test_a_run_ends_in_done_and_a_second_starts_without_restarts(
    labs: Labs, tmp_path: Path
) -> None:
    pair = labs.pair()
    experiment = write_experiment(tmp_path / "exp.toml", RUN)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    pids = {who: labs.fleet.procs[a.name].pid for who, a in agents.items()}
    agents[FOLLOWER].until(locked, timeout=LOCKED, what="reference clock locked")

    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "first",
        "-e", pair.rome.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    for agent in agents.values():
        line = agent.until(lambda s: s["mode"] == "done", timeout=30, what="done")
        assert line["run_id"] == "first" and line["run_time"] == pytest.approx(RUN, abs=1e-6)
        assert line["hold"] == "done"

    for who in agents:
        mcap = finalized(labs, who, "first")
        stem = who.replace("/", "-")
        manifest = json.loads(mcap.with_name(f"{stem}.manifest.json").read_text())
        assert {f["name"] for f in manifest["files"]} == {f"{stem}.mcap", f"{stem}.jsonl"}
        rec = read_messages(mcap)  # finalized: summary and index readable
        meta = read_metadata(mcap)["fedlab.run"]
        assert meta["run_id"] == "first" and meta["experiment"].startswith('name = "lifecycle"')
        assert meta["zenoh_version"] and meta["fedlab_version"] and meta["host"]
        ended = next(e for e in rec["/control"] if e["event"] == "done")
        after = [r for r in rec["/reference"] if r["host_monotonic"] > ended["host_monotonic"]]
        running = [r for r in rec["/reference"] if r["mode"] == "running"]
        assert running and max(r["run_time"] for r in running) <= RUN + 1e-6
        # The recording closed with the run: at most the step that ended it came after.
        assert all(r["valves_open"] == 0 and r["mode"] == "done" for r in after)

    # A second run: same processes, no restart.
    second, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "second",
        "--duration", "2", "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert second.returncode == 0, second.stdout + second.stderr
    for agent in agents.values():
        agent.until(
            lambda s: s["mode"] == "done" and s["run_id"] == "second", timeout=15, what="done again"
        )
    assert {who: labs.fleet.procs[a.name].pid for who, a in agents.items()} == pids
    assert all(a.alive() for a in agents.values())


@pytest.mark.scenario
@pytest.mark.timing  # a wall-clock bound: the safe hold within 100 ms of the abort
def test_abort_is_honoured_within_100_ms_after_poisoned_commands(
    labs: Labs, tmp_path: Path
) -> None:
    """ctl runs in the test's process (the hold is timed from the instant ctl stamps on
    sending the abort, nothing here is about ctl's own process), each start announced
    the least ctl allows ahead (START_IN_MIN, 1 s) rather than the experiment's 1.5 s."""
    import zenoh
    from inprocess import fedlab_here
    from loopback import client_config

    soon = f"{START_IN_MIN:g}"

    pair = labs.pair()
    experiment = write_experiment(tmp_path / "exp.toml", 60)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    agents[FOLLOWER].until(locked, timeout=LOCKED, what="reference clock locked")
    started = fedlab_here(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "poisoned",
        "--in", soon, "-e", pair.rome.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    for agent in agents.values():
        agent.until(lambda s: s["mode"] == "running", timeout=10, what="running")

    # What used to disable every later command: a huge seq, and a seq from a wall
    # clock 30 s ahead (issued_at 30 s ahead too), both from the issuer "ctl".
    now_ms = time.time_ns() // 1_000_000
    poison = [
        {"command": "resume", "seq": 10**30, "issuer": "ctl"},
        {"command": "resume", "seq": now_ms + 30_000, "issuer": "ctl", "issued_at": 1e9},
    ]
    with zenoh.open(client_config(pair.kiruna.endpoint)) as session:
        for command in poison:
            session.put(keys.control_key("default"), json.dumps(command))
    for agent in agents.values():
        agent.until(
            lambda s: s["counters"].get("commands_dropped", 0) >= 1, timeout=5, what="dropped"
        )
        outcomes = {(c["seq"], c["outcome"]) for c in agent.latest()["commands"]}
        assert (10**30, "seq out of range") in outcomes
        assert (now_ms + 30_000, "ignored") in outcomes  # admitted, but resume while running

    # Sent at once; ctl then hears who confirms it for two of the agents' status periods.
    aborted = fedlab_here(
        "ctl", "abort", "--discover", f"{2 * STATUS_PERIOD:g}", "--json", "-e", pair.rome.endpoint
    )
    result = as_json(aborted)
    assert aborted.returncode == 0 and result["ok"], aborted.stdout + aborted.stderr
    sent = result["sent_monotonic"]  # this host's monotonic clock, as the agents'
    for who in agents:
        rec = read_messages(finalized(labs, who, "poisoned"))
        held = next(e for e in rec["/control"] if e["event"] == "aborted")
        latency = held["host_monotonic"] - sent
        print(f"{who}: safe hold {latency * 1e3:.1f} ms after ctl published the abort")
        assert 0 <= latency < 0.100, who
    for agent in agents.values():
        line = agent.until(lambda s: s["mode"] == "aborted", timeout=5, what="aborted")
        assert line["hold"] == "aborted" and line["ready"]["platform"] is False

    # A start is refused until an operator resets; then a new run starts, no restart.
    refused = fedlab_here("ctl", "start", "--experiment", str(experiment), "-e", pair.rome.endpoint)
    assert refused.returncode == 1 and "mode aborted" in refused.stdout, refused.stdout
    reset = fedlab_here("ctl", "reset", "--experiment", str(experiment), "-e", pair.rome.endpoint)
    assert reset.returncode == 0, reset.stdout + reset.stderr
    # A run of 1 s: that it starts and ends in done is the claim, not its length.
    again = fedlab_here(
        "ctl", "start", "--experiment", str(experiment), "--duration", "1", "--in", soon,
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert again.returncode == 0, again.stdout + again.stderr
    for agent in agents.values():
        agent.until(lambda s: s["mode"] == "done", timeout=15, what="done after the reset")


@pytest.mark.parametrize(
    "command",
    [
        ("ctl", "abort"),
        ("ctl", "status"),
        ("ctl", "start", "--experiment", "deploy/experiments/attitude-tracking.toml"),
        ("monitor", "--once"),
        ("collect", "some-run", "--out", "{tmp}/out"),
    ],
)
def test_a_command_against_a_closed_port_fails_within_its_timeout(
    command: tuple[str, ...], tmp_path: Path
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    # The baseline, on this host now: the same command given 0.1 s, so the same start-up
    # with the same imports (`collect` imports the report's modules before it connects,
    # which its help does not) and the same closing.
    quick, start_up = fedlab(*args, "--timeout", "0.1", "-e", endpoint, timeout=30)
    assert quick.returncode == 1 and endpoint in quick.stderr, quick.stdout + quick.stderr
    done, took = fedlab(*args, "--timeout", "2", "-e", endpoint, timeout=30)
    assert done.returncode == 1, done.stdout + done.stderr
    assert endpoint in done.stderr and "connection refused" in done.stderr, done.stderr
    # The 1.9 s more of timeout over the baseline's, and 2 s for the probe.
    assert took < start_up + 1.9 + 2, (took, start_up)


def test_the_sdk_fails_fast_naming_the_endpoint() -> None:
    from federation.core.wire import Pose
    from federation.runtime.sdk import Agent
    from federation.runtime.session import ConnectError

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    start = time.monotonic()
    ghost = Agent("lab3/ghost", lambda t: Pose(), connect=[endpoint], timeout=1.0)
    with pytest.raises(ConnectError, match="connection refused") as error, ghost:
        pass
    assert endpoint in str(error.value)
    assert time.monotonic() - start < 1.0 + 3.0


@pytest.mark.scenario
def test_the_leader_restarted_mid_run_ends_the_run_for_its_follower(
    labs: Labs, tmp_path: Path
) -> None:
    """The leader's process is killed mid-run and started again at once (a new session,
    waiting): the follower aborts the run and holds, saying why, instead of flying on
    after a leader that flies no maneuver."""
    pair = labs.pair()
    experiment = write_experiment(tmp_path / "exp.toml", 60)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    follower, leader = agents[FOLLOWER], agents[LEADER]
    follower.until(locked, timeout=LOCKED, what="reference clock locked")
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "restart",
        "-e", pair.rome.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    follower.until(lambda s: s["mode"] == "running", timeout=10, what="running")
    leader.kill()
    leader.start()
    leader.until(lambda s: s["mode"] == "waiting", timeout=20, what="the leader back, waiting")
    line = follower.until(
        lambda s: s["mode"] == "aborted", timeout=10, what="the follower's run aborted"
    )
    assert line["hold"] == "aborted" and line["counters"]["reference_restarted"] == 1
    assert "kiruna/knatte restarted" in follower.log()
    # Nothing releases it but a reset and a new start: the pose flows again, still held
    # (four status lines more).
    seen = len(follower.lines())
    assert wait_for(lambda: len(follower.lines()) >= seen + 4, timeout=10), follower.latest()
    last = follower.lines()[-3:]
    assert all(s["hold"] == "aborted" and s["pose_age"] < 0.5 for s in last), last
    rec = read_messages(finalized(labs, FOLLOWER, "restart"))
    aborted = next(e for e in rec["/control"] if e["event"] == "aborted")
    assert "restarted" in aborted["detail"]
    after = [r for r in rec["/reference"] if r["host_monotonic"] > aborted["host_monotonic"]]
    assert all(r["valves_open"] == 0 for r in after)
