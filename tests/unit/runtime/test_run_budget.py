"""Nothing a peer sends fills an agent's disk (federation/runtime/recorder.py,
federation/runtime/runs.py): a run's recording stops at its size limit (record_max_mb,
or half the space free when armed) and is still finished, marked truncated; a runs
folder with less free space than record_min_free_mb fails preflight, and a run armed
all the same is recorded, said loudly."""

from __future__ import annotations

import fcntl
import json
import os
import tempfile
from pathlib import Path

import pytest
from test_run_holds import Follower

from federation.core.preflight import preflight
from federation.runtime import runs as runs_module
from federation.runtime.collect import describe_incomplete, manifest_name
from federation.runtime.recorder import (
    CHUNK_SIZE,
    RESERVE_BYTES,
    Recorder,
    read_messages,
    read_metadata,
)
from federation.runtime.runs import MIB, RunRecording, low_space, space_problem
from schemas.config import AgentConfig, ConfigError, validate
from schemas.messages import Manifest

AGENT = "kiruna/knatte"
STEM = "kiruna-knatte"


def _flood(record: object, n: int, start: int = 0) -> None:
    """``n`` received poses, as fast as a peer publishing far too fast sends them."""
    for k in range(start, start + n):
        pad = os.urandom(60).hex()  # compressible, but not to nothing
        record("/pose/received", {"agent": "rome/p", "t": float(k), "pad": pad})  # type: ignore[operator]


def _past_its_limit(rec: Recorder) -> None:
    """Flood a recorder of 1 MiB past its limit (15 000 poses), flushed as the writer does."""
    for batch in range(30):
        _flood(rec.record, 500, batch * 500)
        rec.flush()
    assert rec.truncated


def test_a_recording_stops_at_its_limit_and_is_still_finished(tmp_path: Path) -> None:
    limit = 1 * MIB
    path = tmp_path / "a.mcap"
    rec = Recorder(path, AGENT, max_bytes=limit)
    for batch in range(40):  # the writer thread writes between the batches
        _flood(rec.record, 500, batch * 500)
        rec.flush()
    assert rec.truncated
    pending = len(rec._pending)
    _flood(rec.record, 1000, 10**6)  # after it: dropped at once, never queued
    assert len(rec._pending) == pending
    rec.close()
    size = path.stat().st_size
    # Within the limit but for the summary (the index: well under 1 % of it), and not
    # far under it either (the bound is refreshed from the file's size).
    assert limit - 3 * CHUNK_SIZE < size <= limit * 1.01 + 8192, size
    assert rec.written + rec.over_budget == 21_000 and rec.over_budget > 10_000
    assert rec.dropped == 0
    messages = read_messages(path)  # a finished file: summary and index read
    ts = [m["t"] for m in messages["/pose/received"]]
    assert ts == [float(k) for k in range(len(ts))] and len(ts) == rec.written
    events = [m for m in messages["/control"] if m["event"] == "recording_truncated"]
    assert len(events) == 1 and str(limit) in events[0]["detail"]
    summary = read_metadata(path)["fedlab.recording"]
    assert summary["truncated"] == "true" and summary["complete"] == "false"
    assert summary["dropped_over_budget"] == str(rec.over_budget)
    assert summary["messages"] == str(rec.written) and summary["max_bytes"] == str(limit)


def test_a_recording_within_its_limit_says_it_is_complete(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    rec = Recorder(path, AGENT, max_bytes=MIB)
    _flood(rec.record, 100)
    rec.close()
    assert not rec.truncated and rec.complete and rec.written == 100
    summary = read_metadata(path)["fedlab.recording"]
    assert summary["truncated"] == "false" and summary["complete"] == "true"
    assert not [m for m in read_messages(path)["/control"]]


def test_a_truncated_run_is_finalized_with_what_it_misses(tmp_path: Path) -> None:
    run = RunRecording(tmp_path, "r1", AGENT, None, "{}", None, max_mb=1)
    assert run.max_bytes == MIB  # far more free than that here
    for batch in range(30):
        _flood(run.record, 500, batch * 500)
        run.recorder.flush()
    run.status_line('{"agent": "kiruna/knatte"}')
    run.finish(wait=True)
    folder = tmp_path / "r1"
    manifest = Manifest.model_validate_json((folder / manifest_name(STEM)).read_text())
    names = {f.name for f in manifest.files}
    assert names == {f"{STEM}.mcap", f"{STEM}.jsonl", f"{STEM}.incomplete.json"}
    note = json.loads((folder / f"{STEM}.incomplete.json").read_text())
    assert note["truncated"] is True and note["max_bytes"] == MIB
    assert note["dropped_over_budget"] == run.recorder.over_budget > 0
    assert read_metadata(run.mcap)["fedlab.run"]["record_max_bytes"] == str(MIB)


def test_a_whole_run_lists_only_its_recording_and_status(tmp_path: Path) -> None:
    run = RunRecording(tmp_path, "r1", AGENT, None, "{}", None, max_mb=1)
    _flood(run.record, 50)
    run.finish(wait=True)
    manifest = Manifest.model_validate_json((tmp_path / "r1" / manifest_name(STEM)).read_text())
    assert {f.name for f in manifest.files} == {f"{STEM}.mcap", f"{STEM}.jsonl"}


def test_a_run_takes_at_most_half_the_space_free_and_a_low_disk_is_said(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(runs_module, "free_bytes", lambda path: 600 * MIB)
    roomy = RunRecording(tmp_path, "r1", AGENT, None, "{}", None, max_mb=2048, min_free_mb=512)
    roomy.finish(wait=True)
    assert roomy.max_bytes == 300 * MIB and roomy.low_space is None
    caplog.set_level("ERROR", logger="fedlab.runs")
    low = RunRecording(tmp_path, "r2", AGENT, None, "{}", None, max_mb=2048, min_free_mb=1024)
    low.finish(wait=True)
    assert low.max_bytes == 300 * MIB  # recorded all the same, within what is free
    assert low.low_space is not None and "600 MiB free" in low.low_space
    assert "record_min_free_mb (1024 MiB)" in low.low_space
    assert "recorded all the same" in caplog.text
    assert read_metadata(low.mcap)["fedlab.run"]["low_space"] == low.low_space


def test_runs_recording_together_share_the_free_space_not_each_take_half(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Agents hosted together, armed by one start: each had been given half of the same
    # 600 MiB, 1200 MiB in all for three of them.
    monkeypatch.setattr(runs_module, "free_bytes", lambda path: 600 * MIB)
    agents = ["lab/a", "lab/b", "lab/c"]
    runs = [RunRecording(tmp_path, "r1", a, None, "{}", None, max_mb=2048) for a in agents]
    try:
        budgets = [run.max_bytes for run in runs]
        assert budgets == [300 * MIB, 150 * MIB, 75 * MIB]
        assert sum(b or 0 for b in budgets) < 600 * MIB
    finally:
        for run in runs:
            run.finish(wait=True)
    # Finished, they give their share back: the next run may take half again.
    again = RunRecording(tmp_path, "r2", AGENT, None, "{}", None, max_mb=2048)
    again.finish(wait=True)
    assert again.max_bytes == 300 * MIB


def test_space_problem_names_the_place_the_space_and_the_setting() -> None:
    assert space_problem(Path("runs"), 2048 * MIB, 1024) is None
    assert space_problem(Path("runs"), None, 1024) is None  # not known: not refused
    text = space_problem(Path("runs"), 100 * MIB, 1024)
    assert text == (
        "runs: 100 MiB free, under record_min_free_mb (1024 MiB): free some space or lower "
        "the floor"
    )


def test_a_runs_folder_short_of_space_fails_preflight(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The free space as told, not this machine's (CI hosts had 287 MB free).
    monkeypatch.setattr(runs_module, "free_bytes", lambda path: 200 * MIB)
    f = Follower()
    f.agent.config = f.agent.config.model_copy(update={"runs_dir": tmp_path / "runs"})
    ready = f.agent.readiness(f.clock.now())
    assert not ready.recording and ready.recording_to is not None
    assert "200 MiB free, under record_min_free_mb (256 MiB)" in ready.recording_to
    status = {"agent": "kiruna/f", "mode": "waiting", "ready": ready.model_dump()}
    row = preflight(["kiruna/f"], {"kiruna/f": status}, {"kiruna/f": 0.5})[0]
    assert not row.checks["recording"].ok
    assert "record_min_free_mb" in row.checks["recording"].detail
    # Room enough: ready, the folder named as before.
    f.agent.config = f.agent.config.model_copy(update={"record_min_free_mb": 0})
    ready = f.agent.readiness(f.clock.now())
    assert ready.recording and ready.recording_to == str(tmp_path / "runs")


def test_the_free_space_is_looked_at_once_per_period(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    looks: list[Path] = []

    def free(path: Path) -> int:
        looks.append(path)
        return 10 * MIB

    monkeypatch.setattr(runs_module, "free_bytes", free)
    config = AgentConfig(lab="k", name="a", role="leader", runs_dir=tmp_path, record_min_free_mb=20)
    assert low_space(config, now=100.0) is not None
    assert low_space(config, now=104.0) is not None
    assert len(looks) == 1  # status asks every period: the disk is asked every 5 s
    low_space(config, now=105.5)
    assert len(looks) == 2
    assert low_space(config.model_copy(update={"runs_dir": None}), now=200.0) is None


def test_an_armed_run_records_within_the_configured_limit(tmp_path: Path) -> None:
    f = Follower()
    f.agent.config = f.agent.config.model_copy(
        update={"runs_dir": tmp_path, "record_max_mb": 3, "record_min_free_mb": 0}
    )
    f.synced()
    f.command("start", run_id="r1", duration=10.0)
    run = f.agent.recordings.run
    assert run is not None and run.max_bytes == 3 * MIB
    assert run.recorder.max_bytes == 3 * MIB
    # What the budget leaves out shows in status as it happens, not only in the file.
    for part in range(6):
        _flood(run.record, 10_000, start=part * 10_000)
        run.recorder.flush()  # as the writer thread does
    counters = f.agent.status().counters
    assert counters["recording_dropped_over_budget"] > 0, counters
    f.agent.recordings.end_run(wait=True)


def test_a_start_reusing_a_run_being_recovered_is_refused(tmp_path: Path) -> None:
    # A run id whose cut recording is being recovered (.mcap.partial) is recorded here.
    f = Follower()
    f.agent.config = f.agent.config.model_copy(
        update={"runs_dir": tmp_path, "record_min_free_mb": 0}
    )
    (tmp_path / "r1").mkdir()
    (tmp_path / "r1" / "kiruna-f.mcap.partial").write_bytes(b"")
    f.synced()
    f.command("start", run_id="r1", duration=10.0)
    (outcome,) = [c for c in f.agent.command_log if c.command == "start"]
    assert outcome.outcome == "ignored" and "recorded here already" in outcome.detail


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("record_max_mb", 0, "greater than or equal to 1"),
        ("record_max_mb", "lots", "valid integer"),
        ("record_min_free_mb", -1, "greater than or equal to 0"),
    ],
)
def test_a_bad_limit_fails_at_load_naming_the_field(field: str, value: object, reason: str) -> None:
    data = {"lab": "k", "name": "a", "role": "leader", field: value}
    with pytest.raises(ConfigError) as error:
        validate(AgentConfig, data, "agent.toml")
    assert f"field '{field}'" in str(error.value) and reason in str(error.value)
    assert "agent.toml" in str(error.value)


def test_the_defaults_bound_a_run_to_a_few_gib() -> None:
    config = AgentConfig(lab="k", name="a", role="leader")
    assert config.record_max_mb == 2048 and config.record_min_free_mb == 256


def test_a_host_with_a_few_hundred_mb_free_passes_preflight_by_default(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """CI hosts were seen with 287 MB free: a 1 GiB floor failed every preflight there,
    for runs of about a kB a second."""
    monkeypatch.setattr(runs_module, "free_bytes", lambda path: 287_000_000)
    f = Follower()
    f.agent.config = f.agent.config.model_copy(update={"runs_dir": tmp_path / "runs"})
    ready = f.agent.readiness(f.clock.now())
    assert ready.recording and ready.recording_to == str(tmp_path / "runs")


def _own(rec: Recorder, k: int) -> None:
    """What the agent itself records at ``k``: a control event and a status line."""
    rec.record("/control", {"event": f"event {k}", "t_exec": float(k)})
    rec.record("/status", json.dumps({"agent": AGENT, "t_exec": float(k)}).encode())


def test_a_truncated_recording_keeps_the_agents_control_events_and_last_status(
    tmp_path: Path,
) -> None:
    """fedlab report finds a run's start in its /control events and an agent's role and
    peers in its last /status: the budget had cut those too."""
    path = tmp_path / "a.mcap"
    rec = Recorder(path, AGENT, max_bytes=MIB)
    rec.record("/control", {"event": "started", "at": 5.0, "t_sim": 5.0})
    _past_its_limit(rec)
    for k in range(3):  # after the limit: the data cut, the agent's own kept
        _flood(rec.record, 100, 10**6 + k * 100)
        _own(rec, k)
        rec.flush()
    rec.record("/control", {"event": "done", "t_exec": 99.0})
    rec.record("/status", json.dumps({"agent": AGENT, "t_exec": 99.0}).encode())
    rec.close()
    messages = read_messages(path)
    events = [m["event"] for m in messages["/control"]]
    assert events == ["started", "recording_truncated", "event 0", "event 1", "event 2", "done"]
    assert [m["t_exec"] for m in messages["/status"]] == [0.0, 1.0, 2.0, 99.0]
    ts = [m["t"] for m in messages["/pose/received"]]
    assert ts == [float(k) for k in range(len(ts))] and ts[-1] < 10**6  # the data stays cut
    assert rec.written == len(ts) + 1 + 3 * 2 + 2  # the reserve's messages counted
    assert 0 < rec.reserve_used < RESERVE_BYTES
    summary = read_metadata(path)["fedlab.recording"]
    assert summary["truncated"] == "true" and summary["reserve_bytes"] == str(rec.reserve_used)


def test_the_reserve_is_bounded_and_still_ends_with_the_last_status(tmp_path: Path) -> None:
    """A status line a second for hours past the limit takes at most the reserve; the
    last one (the run's end) is there all the same."""
    path = tmp_path / "a.mcap"
    rec = Recorder(path, AGENT, max_bytes=MIB)
    _past_its_limit(rec)
    pad = "x" * 2000
    for k in range(2000):  # 4 MB of status lines: four times the reserve
        rec.record("/status", json.dumps({"agent": AGENT, "t_exec": float(k), "p": pad}).encode())
        if k % 100 == 0:
            rec.flush()
    rec.record("/control", {"event": "done", "t_exec": 1e4})
    rec.close()
    assert path.stat().st_size <= MIB + RESERVE_BYTES + 3 * CHUNK_SIZE
    assert rec.reserve_used <= RESERVE_BYTES
    messages = read_messages(path)
    status = [m["t_exec"] for m in messages["/status"]]
    assert status[-1] == 1999.0 and 200 < len(status) < 300  # half the reserve, then the last
    assert [m["event"] for m in messages["/control"]][-1] == "done"
    assert rec.over_budget > 1500


def test_commands_flooding_in_leave_the_reserve_for_the_agents_own_events(
    tmp_path: Path,
) -> None:
    # Any lab's operator may send commands, and each received is recorded: past the
    # limit, a flood of them had used up the reserve and the run's end was lost.
    path = tmp_path / "a.mcap"
    rec = Recorder(path, AGENT, max_bytes=MIB)
    _past_its_limit(rec)
    pad = "x" * 2000
    for k in range(1000):  # 4 MB of commands received, each ignored: four times the reserve
        command = {"command": "resume", "seq": k, "issuer": "elsewhere", "pad": pad}
        rec.record("/control", {"event": "command", "command": command, "t_exec": float(k)})
        rec.record("/control", {"event": "ignored", "detail": pad, "t_exec": float(k)})
        if k % 100 == 0:
            rec.flush()
    # The agent's own events after the flood still find room (an eighth for commands
    # received or ignored), and so does the run's end.
    for kind in ("frozen", "resumed", "stale_hold"):
        rec.record("/control", {"event": kind, "t_exec": 2e3})
    rec.record("/control", {"event": "done", "t_exec": 1e4})
    rec.close()
    assert 0 < rec.reserve_received <= RESERVE_BYTES // 8
    assert rec.reserve_events <= RESERVE_BYTES // 4 and rec.reserve_used <= RESERVE_BYTES
    events = [m["event"] for m in read_messages(path)["/control"]]
    assert events[-4:] == ["frozen", "resumed", "stale_hold", "done"]
    assert 25 < events.count("command") < 35


def test_a_record_file_has_a_budget_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # --record FILE recorded without limit: a peer publishing far too fast filled the disk.
    monkeypatch.setattr(runs_module, "free_bytes", lambda path: 600 * MIB)
    capped = Follower(record=tmp_path / "a.mcap", record_max_mb=100)
    roomy = Follower(record=tmp_path / "b.mcap", record_max_mb=2048)
    try:
        assert (
            capped.agent.recordings.recorder is not None
            and roomy.agent.recordings.recorder is not None
        )
        assert capped.agent.recordings.recorder.max_bytes == 100 * MIB
        assert (
            roomy.agent.recordings.recorder.max_bytes == 250 * MIB
        )  # half of 600 less the 100 promised
    finally:
        capped.agent.close()
        roomy.agent.close()
    again = Follower(record=tmp_path / "c.mcap", record_max_mb=2048)
    again.agent.close()
    assert again.agent.recordings.recorder is None
    assert runs_module.PROMISES.promised(tmp_path) == 0  # every promise given back


def test_a_recording_not_on_disk_makes_its_run_incomplete(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # fsync failing (EIO) had left a manifest calling the recording complete.
    import errno

    real = os.fsync

    def fsync(fd: int) -> None:
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".mcap"):
            raise OSError(errno.EIO, "Input/output error")
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    run = RunRecording(tmp_path, "r1", AGENT, None, "{}", None, max_mb=1)
    run.record("/pose/sent", {"t_exec": 1.0})
    run.finish(wait=True)
    assert run.recorder.write_errors == 1 and not run.recorder.complete
    assert (run.dir / "kiruna-knatte.incomplete.json").exists()

    # The status lines not on disk: said too.
    def status_fails(fd: int) -> None:
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".jsonl"):
            raise OSError(errno.EIO, "Input/output error")
        real(fd)

    monkeypatch.setattr(os, "fsync", status_fails)
    other = RunRecording(tmp_path, "r2", AGENT, None, "{}", None, max_mb=1)
    other.status_line("{}")
    other.finish(wait=True)
    said = json.loads((other.dir / "kiruna-knatte.incomplete.json").read_text())
    assert said["status_write_errors"] == 1 and other.recorder.complete

    # A file that cannot be synced at all (a pipe, /dev/null: EINVAL) loses nothing.
    def unsyncable(fd: int) -> None:
        raise OSError(errno.EINVAL, "Invalid argument")

    monkeypatch.setattr(os, "fsync", unsyncable)
    rec = Recorder(tmp_path / "null.mcap", AGENT)
    rec.close()
    assert rec.write_errors == 0 and rec.complete


def test_a_run_that_cannot_start_gives_its_space_back(tmp_path: Path) -> None:
    # Its status file could not be opened (EMFILE, ENOSPC): the promise and the open
    # recorder had stayed for the whole process.
    (tmp_path / "r1" / "kiruna-knatte.jsonl").mkdir(parents=True)  # not a file to open
    with pytest.raises(IsADirectoryError):
        RunRecording(tmp_path, "r1", AGENT, None, "{}", None, max_mb=1)
    assert runs_module.PROMISES.promised(tmp_path) == 0
    # Its finished, empty MCAP is said not to be the run's recording: the next start's
    # recovery had collected it as the run's, complete.
    said = json.loads((tmp_path / "r1" / "kiruna-knatte.incomplete.json").read_text())
    assert "could not start" in said["not_recorded"]
    assert "could not start" in describe_incomplete(said)


def test_a_symlinked_record_file_is_budgeted_on_its_target_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # --record pointing at a symlink: the link's folder's disk had been budgeted, and the
    # file written on the target's, which may be nearly full.
    shm = Path("/dev/shm")
    if not shm.is_dir() or shm.stat().st_dev == tmp_path.stat().st_dev:
        pytest.skip("needs /dev/shm on a filesystem of its own")
    with tempfile.TemporaryDirectory(dir=shm) as target_dir:
        target = Path(target_dir) / "run.mcap"
        link = tmp_path / "run.mcap"
        link.symlink_to(target)
        free = {shm.stat().st_dev: 600 * MIB, tmp_path.stat().st_dev: 100_000 * MIB}
        monkeypatch.setattr(runs_module, "free_bytes", lambda path: free[Path(path).stat().st_dev])
        follower = Follower(record=link, record_max_mb=2048)
        try:
            assert follower.agent.recordings.recorder is not None
            assert (
                follower.agent.recordings.recorder.max_bytes == 300 * MIB
            )  # half of the target's 600
        finally:
            follower.agent.close()
        assert target.stat().st_size > 0 and link.is_symlink()


_PROMISER = """
import sys
from pathlib import Path
from federation.runtime.runs import MIB, PROMISES
budget = PROMISES.take(Path(sys.argv[1]), 600 * MIB, None, object())
print(budget // MIB, flush=True)
sys.stdin.read()  # held until the test closes stdin or kills it
"""


def test_agents_in_processes_of_their_own_share_the_free_space(tmp_path: Path) -> None:
    # Promises had been per process: two fedlab agents on one host, each in its own
    # process, were each given half of the same free space (all of it together).
    import subprocess
    import sys

    other = subprocess.Popen(
        [sys.executable, "-c", _PROMISER, str(tmp_path)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    first, second = object(), object()
    try:
        assert other.stdout is not None
        assert other.stdout.readline().strip() == "300"  # half of 600
        assert runs_module.PROMISES.take(tmp_path, 600 * MIB, None, first) == 150 * MIB
        # The other process dies without giving its promise back (killed): its promise
        # is its file's lock, gone with it, so the next promise takes that space again.
        other.kill()
        other.wait(timeout=10)
        assert runs_module.PROMISES.take(tmp_path, 600 * MIB, None, second) == 225 * MIB
        ledger = runs_module.ledger_dir() / str(tmp_path.stat().st_dev)
        assert len([p for p in ledger.iterdir() if not p.name.startswith(".")]) == 2  # ours
    finally:
        if other.poll() is None:
            other.kill()
            other.wait(timeout=10)
        runs_module.PROMISES.give_back(tmp_path, first)
        runs_module.PROMISES.give_back(tmp_path, second)
    assert [p for p in ledger.iterdir() if not p.name.startswith(".")] == []
    assert runs_module.PROMISES.take(tmp_path, 600 * MIB, None, first) == 300 * MIB
    runs_module.PROMISES.give_back(tmp_path, first)


def _promised_alone(tmp_path: Path) -> None:
    """A promise is taken as if no other process had promised any: half of 600 MiB."""
    who = object()
    try:
        assert runs_module.PROMISES.take(tmp_path, 600 * MIB, None, who) == 300 * MIB
    finally:
        runs_module.PROMISES.give_back(tmp_path, who)


def test_a_ledger_that_cannot_be_written_leaves_the_process_on_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    monkeypatch.setenv(runs_module.LEDGER_ENV, str(blocker))
    monkeypatch.setattr(runs_module.PROMISES, "_warned", False)
    _promised_alone(tmp_path)
    assert "not shared with other processes" in caplog.text


@pytest.mark.parametrize(
    "kind", ["made by another user", "a link to a folder", "written by others"]
)
def test_a_ledger_folder_others_could_have_planted_is_not_trusted(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # Another user of the host could make the ledger's folder first, or link it to a
    # folder of theirs (under a root-owned sticky folder: the owner check followed the
    # link), and plant huge promises: every recording of this user would get no space.
    real = tmp_path / "real"
    planted = real / str(tmp_path.stat().st_dev) / "1-1"
    planted.parent.mkdir(parents=True)
    planted.write_text(str(10**15))
    ledger = real
    if kind == "a link to a folder":
        ledger = tmp_path / "ledger"
        ledger.symlink_to(real)
    elif kind == "written by others":
        real.chmod(0o777)
    else:
        real_getuid = os.getuid
        monkeypatch.setattr(runs_module.os, "getuid", lambda: real_getuid() + 1)
    monkeypatch.setenv(runs_module.LEDGER_ENV, str(ledger))
    monkeypatch.setattr(runs_module.PROMISES, "_warned", False)
    with planted.open() as held:  # its "process" alive: the promise locked
        fcntl.flock(held, fcntl.LOCK_SH)
        _promised_alone(tmp_path)
    assert "not shared with other processes" in caplog.text


def test_a_filesystem_without_locks_leaves_the_process_on_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # flock failing (NFS without lockd) had raised out of take: no run recorded at all,
    # and an agent given --record did not start.
    import errno

    def no_locks(fd: object, op: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(runs_module.fcntl, "flock", no_locks)
    monkeypatch.setattr(runs_module.PROMISES, "_warned", False)
    _promised_alone(tmp_path)
    assert "No locks available" in caplog.text


def test_an_agent_whose_record_file_cannot_be_opened_keeps_no_promise(
    tmp_path: Path, promises_ledger: Path
) -> None:
    # --record naming a folder: the agent did not start, but its promise stayed, in the
    # ledger too (every process on the host then had less space for as long as it ran).
    folder = tmp_path / "a-folder.mcap"
    folder.mkdir()
    for _ in range(3):  # a program retrying
        with pytest.raises(IsADirectoryError):
            Follower(record=folder, record_max_mb=2048)
    assert runs_module.PROMISES.promised(tmp_path) == 0
    assert [p.name for p in promises_ledger.rglob("*") if p.is_file() and p.name != ".lock"] == []
