"""A run its agent never finalized (killed, power lost) is recovered when it starts again
(federation/runtime/recorder.py ``salvage``, federation/runtime/collect.py
``recover_runs``): every complete record of the cut file in a finished one, the original
kept as ``.mcap.partial``, the run marked recovered and its manifest written, so
``fedlab collect`` serves it. Real files cut at many places, a chunk failing its CRC,
empty and garbage files, a file still being written, a process killed mid-run."""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import NamedTuple

import pytest
import zenoh
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk

from federation.core.keys import AgentId
from federation.fleet.launch import wait_for
from federation.runtime import collect as collect_module
from federation.runtime import recorder as recorder_module
from federation.runtime import runfolder as runfolder_module
from federation.runtime.collect import (
    RecordingServer,
    collect,
    manifest_name,
    recover_run,
    recover_runs,
    sha256_file,
    unfinished_runs,
    write_incomplete,
    zenoh_fetch,
)
from federation.runtime.recorder import (
    Recorder,
    is_finished,
    read_messages,
    read_metadata,
    salvage,
)
from federation.runtime.runs import RunRecording
from schemas.messages import Manifest

AGENT = "kiruna/knatte"
STEM = "kiruna-knatte"
POSES = 3000  # about ten chunks


def _record(runs: Path, run_id: str = "r1", finish: bool = True) -> RunRecording:
    """A run of ``POSES`` received poses (and a few status lines) as an agent records it."""
    run = RunRecording(runs, run_id, AGENT, None, '{"lab": "kiruna"}', None, {"role": "leader"})
    for k in range(POSES):
        # Some noise: the chunks compress, but not to nothing.
        pad = os.urandom(40).hex()
        run.record("/pose/received", {"agent": "rome/p", "t": float(k), "x": 0.5, "pad": pad})
        if k % 500 == 0:
            run.record("/status", {"agent": AGENT, "t_exec": float(k)})
    run.status_line('{"agent": "kiruna/knatte"}')
    if finish:
        run.finish(wait=True)
    return run


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One finished recording (read only: each test cuts a copy)."""
    runs = tmp_path_factory.mktemp("original")
    return _record(runs).mcap


class _Chunk(NamedTuple):
    start: int  # its first byte
    end: int  # the byte after it
    messages: int
    poses: list[float]  # the received poses' t


def _chunks(path: Path) -> list[_Chunk]:
    """Each chunk of a finished recording, read through its index."""
    out = []
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            records = breakup_chunk(Chunk.read(ReadDataStream(f)))
            messages = [r for r in records if isinstance(r, McapMessage)]
            poses = [json.loads(m.data)["t"] for m in messages if b'"pad"' in m.data]
            start = index.chunk_start_offset
            out.append(_Chunk(start, start + index.chunk_length, len(messages), poses))
    return out


def _ts(path: Path) -> list[float]:
    return [m["t"] for m in read_messages(path, ["/pose/received"])["/pose/received"]]


def _cuts(finished: Path) -> dict[str, int]:
    chunks = _chunks(finished)
    assert len(chunks) >= 5, chunks  # enough for the cuts below
    first, third, last = chunks[0], chunks[2], chunks[-1]
    return {
        "empty": 0,
        "inside the magic": 4,
        "the magic only": 8,
        "its metadata only": first.start,
        "inside the first chunk": first.start + 100,
        "after the first chunk": first.end,
        "inside the third chunk": (third.start + third.end) // 2,
        "inside a message index": third.end + 30,
        "after the last chunk": last.end,
        "inside the summary": finished.stat().st_size - 40,
    }


CUTS = [
    "empty", "inside the magic", "the magic only", "its metadata only",
    "inside the first chunk", "after the first chunk", "inside the third chunk",
    "inside a message index", "after the last chunk", "inside the summary",
]  # fmt: skip


@pytest.mark.parametrize("where", CUTS)
def test_a_cut_recording_gives_every_complete_chunk_in_a_finished_file(
    finished: Path, tmp_path: Path, where: str
) -> None:
    cut = _cuts(finished)[where]
    chunks = _chunks(finished)
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(finished.read_bytes()[:cut])
    out = tmp_path / "out.mcap"
    got = salvage(damaged, out, {"original": "cut.mcap"})

    complete = [c for c in chunks if c.end <= cut]
    assert got.messages == sum(c.messages for c in complete)
    # A finished file (its summary and index read): every pose of those chunks, in order.
    assert _ts(out) == [t for c in complete for t in c.poses]
    assert got.chunks_lost == 0 and got.records_lost == 0
    meta = read_metadata(out)
    recovery = meta["fedlab.recovery"]
    assert recovery["messages"] == str(got.messages) and recovery["original"] == "cut.mcap"
    whole = where == "inside the summary"  # its data section had ended
    assert got.whole is whole and recovery["end_missing"] == json.dumps(not whole)
    assert bool(got.problem) is not whole
    if cut >= chunks[0].start:  # the run's metadata came before the first chunk: kept
        assert meta["fedlab.run"] == read_metadata(finished)["fedlab.run"]
        assert meta["fedlab.run"]["run_id"] == "r1"
    else:
        assert "fedlab.run" not in meta
    assert damaged.read_bytes() == finished.read_bytes()[:cut]  # read, never changed


def test_a_chunk_failing_its_crc_is_left_out_and_the_rest_kept(
    finished: Path, tmp_path: Path
) -> None:
    chunks = _chunks(finished)
    data = bytearray(finished.read_bytes())
    # The second chunk's uncompressed CRC: after opcode, length and three 8-byte fields.
    data[chunks[1].start + 9 + 24] ^= 0xFF
    damaged = tmp_path / "crc.mcap"
    damaged.write_bytes(bytes(data[: chunks[-2].end]))  # and cut after the last but one
    out = tmp_path / "out.mcap"
    got = salvage(damaged, out)
    assert got.chunks_lost == 1 and not got.whole
    kept = [chunks[0], *chunks[2:-1]]  # reading went on after the bad chunk
    assert got.messages == sum(c.messages for c in kept)
    assert _ts(out) == [t for c in kept for t in c.poses]
    assert read_metadata(out)["fedlab.recovery"]["chunks_lost"] == "1"


@pytest.mark.parametrize(
    "content",
    [
        pytest.param(b"", id="zero-length"),
        pytest.param(os.urandom(10_000), id="garbage"),
        pytest.param(b"\x89MCAP0\r\n" + bytes(50_000), id="magic-then-zeros"),
    ],
)
def test_an_empty_or_garbage_file_gives_a_finished_file_without_messages(
    tmp_path: Path, content: bytes
) -> None:
    damaged = tmp_path / "bad.mcap"
    damaged.write_bytes(content)
    out = tmp_path / "out.mcap"
    got = salvage(damaged, out)
    assert got.messages == 0 and got.problem and not got.whole
    assert read_messages(out) == {str(c): [] for c in read_messages(out)}
    assert read_metadata(out)["fedlab.recovery"]["end_missing"] == "true"


def test_zeros_after_the_last_record_end_the_reading_there(finished: Path, tmp_path: Path) -> None:
    """A host losing power can leave the file longer than what reached the disk: zeros."""
    chunks = _chunks(finished)
    damaged = tmp_path / "zeros.mcap"
    damaged.write_bytes(finished.read_bytes()[: chunks[1].end] + bytes(100_000))
    got = salvage(damaged, tmp_path / "out.mcap")
    assert got.messages == chunks[0].messages + chunks[1].messages
    assert "zeros or garbage" in got.problem and got.readable >= chunks[1].end


def _unfinished(runs: Path, run_id: str, content: bytes) -> Path:
    folder = runs / run_id
    folder.mkdir(parents=True)
    (folder / f"{STEM}.mcap").write_bytes(content)
    (folder / f"{STEM}.jsonl").write_text('{"agent": "kiruna/knatte"}\n{"age', encoding="utf-8")
    return folder


def test_an_agents_unfinished_runs_are_recovered_and_served(finished: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    chunks = _chunks(finished)
    original = finished.read_bytes()[: (chunks[3].start + chunks[3].end) // 2]
    killed = _unfinished(runs, "killed", original)
    junk = _unfinished(runs, "junk", b"")  # a kill before anything reached the disk
    done = runs / "done"  # finished: left alone
    _record(runs, "done")
    before = {p.name: p.read_bytes() for p in done.iterdir()}
    other = runs / "theirs"  # another agent's (it shares the folder): left alone
    other.mkdir()
    (other / "rome-p.mcap").write_bytes(original)

    assert unfinished_runs(runs, AGENT) == [junk, killed]
    result = recover_runs(runs, AGENT)

    assert set(result.recovered) == {"junk", "killed"} and not result.failed
    assert {p.name: p.read_bytes() for p in done.iterdir()} == before
    assert sorted(p.name for p in other.iterdir()) == ["rome-p.mcap"]
    partial = killed / f"{STEM}.mcap.partial"
    assert partial.read_bytes() == original  # the original bytes, kept
    mcap = killed / f"{STEM}.mcap"
    got = result.recovered["killed"]
    assert got.messages == sum(c.messages for c in chunks[:3]) > 0
    assert read_metadata(mcap)["fedlab.run"]["run_id"] == "r1"  # as the original said
    assert read_metadata(mcap)["fedlab.recovery"]["end_missing"] == "true"
    note = json.loads((killed / f"{STEM}.incomplete.json").read_text())
    assert note["recovered"] is True and note["end_missing"] is True
    assert note["messages"] == got.messages and note["agent"] == AGENT
    assert note["original"] == partial.name and note["original_bytes"] == len(original)
    manifest = Manifest.model_validate_json((killed / manifest_name(STEM)).read_text())
    assert manifest.run_id == "killed" and manifest.agent == AGENT
    listed = {f.name: f for f in manifest.files}
    assert set(listed) == {f"{STEM}.mcap", f"{STEM}.jsonl", f"{STEM}.incomplete.json"}
    for name, entry in listed.items():
        assert entry.sha256 == sha256_file(killed / name) and entry.size > 0
    assert (junk / manifest_name(STEM)).exists()
    assert result.recovered["junk"].messages == 0
    # Nothing is left to recover: a second start does nothing.
    assert unfinished_runs(runs, AGENT) == []
    again = recover_runs(runs, AGENT)
    assert not again.recovered and not again.failed
    assert partial.read_bytes() == original


def test_a_recovery_cut_short_is_done_again_from_the_original(
    finished: Path, tmp_path: Path
) -> None:
    """Stopped after the original was renamed aside (the recovered file half written)."""
    runs = tmp_path / "runs"
    original = finished.read_bytes()[: _chunks(finished)[2].end + 10]
    folder = _unfinished(runs, "r1", b"half a recovered file")
    (folder / f"{STEM}.mcap.partial").write_bytes(original)
    result = recover_runs(runs, AGENT)
    assert set(result.recovered) == {"r1"}
    assert (folder / f"{STEM}.mcap.partial").read_bytes() == original
    assert _ts(folder / f"{STEM}.mcap") == _ts(finished)[: len(_ts(folder / f"{STEM}.mcap"))]
    assert result.recovered["r1"].messages > 0


def test_a_run_that_cannot_be_recovered_is_counted_and_the_others_are(
    finished: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    runs = tmp_path / "runs"
    content = finished.read_bytes()[: _chunks(finished)[1].end]
    for run in ("a", "b", "c"):
        _unfinished(runs, run, content)
    real = runfolder_module.salvage

    def failing(damaged: Path, out: Path, *args, **kwargs):  # type: ignore[no-untyped-def]
        if damaged.parent.name == "b":
            raise OSError(5, "Input/output error")
        return real(damaged, out, *args, **kwargs)

    monkeypatch.setattr(runfolder_module, "salvage", failing)
    result = recover_runs(runs, AGENT)
    assert set(result.recovered) == {"a", "c"}
    assert list(result.failed) == ["b"] and "Input/output error" in result.failed["b"]
    # Its original kept, no manifest: tried again at the next start.
    assert (runs / "b" / f"{STEM}.mcap.partial").read_bytes() == content
    assert unfinished_runs(runs, AGENT) == [runs / "b"]


def test_a_recording_still_being_written_is_left_alone(tmp_path: Path) -> None:
    """A recorder holds its file's lock: the recovery of a second process with the agent's
    name (or of one started while a run armed) would have renamed it under the writer."""
    runs = tmp_path / "runs"
    rec = Recorder(runs / "live" / f"{STEM}.mcap", AGENT)
    try:
        rec.record("/status", {"agent": AGENT, "t_exec": 0.0})
        result = recover_runs(runs, AGENT)
        assert result.in_use == ["live"] and not result.recovered
        assert not (runs / "live" / f"{STEM}.mcap.partial").exists()
    finally:
        rec.close()


_KILLED = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from federation.runtime.runs import RunRecording
    run = RunRecording(Path(sys.argv[1]), "crash", "kiruna/knatte", None, "{}", None)
    k = 0
    while True:
        for _ in range(200):
            run.record("/pose/received", {"agent": "rome/p", "t": float(k), "pad": "x" * 99})
            k += 1
        time.sleep(0.01)
        if k == 4000:
            print("recording", flush=True)
    """
)


def test_a_killed_process_leaves_a_run_that_is_recovered(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED, str(runs)],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == b"recording\n", proc.stderr
        mcap = runs / "crash" / f"{STEM}.mcap"
        assert wait_for(lambda: mcap.stat().st_size > 20_000, timeout=10)
        # Alive, it holds its file: left alone.
        assert recover_runs(runs, AGENT).in_use == ["crash"]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        proc.communicate(timeout=10)
    time.sleep(0.05)
    size = mcap.stat().st_size
    result = recover_runs(runs, AGENT)
    got = result.recovered["crash"]
    assert got.messages > 0 and not got.whole
    ts = _ts(mcap)
    assert ts == [float(k) for k in range(len(ts))]  # from the first, in order, none missing
    assert (runs / "crash" / f"{STEM}.mcap.partial").stat().st_size == size


def test_the_recording_server_recovers_at_start_and_collect_says_so(
    session: zenoh.Session, finished: Path, tmp_path: Path
) -> None:
    runs = tmp_path / "runs"
    chunks = _chunks(finished)
    _unfinished(runs, "crashed", finished.read_bytes()[: chunks[2].end + 3])
    server = RecordingServer(session, "default", AgentId("kiruna", "knatte"), runs, min_free_mb=0)
    try:
        assert wait_for(lambda: server.recovery is not None, timeout=10)
        assert server.recovery is not None and set(server.recovery.recovered) == {"crashed"}
        fetch = zenoh_fetch(session)
        manifest = fetch("fedlab/default/kiruna/knatte/recordings", "run=crashed", 2.0)
        assert manifest and manifest[0].error is None
        out = tmp_path / "out"
        result = collect(session, "default", "crashed", out, timeout=2.0)
        assert result.ok, result.errors
        assert f"{STEM}.incomplete.json" in result.files[AGENT]
        assert "recovered after its agent stopped mid-run" in result.incomplete[AGENT]
        assert "its end missing" in result.incomplete[AGENT]
        assert _ts(out / f"{STEM}.mcap") == _ts(finished)[: len(_ts(out / f"{STEM}.mcap"))]
    finally:
        server.close()


# -- a finished recording whose manifest was not written ---------------------------------
def _closed_not_finalized(runs: Path, max_mb: int | None) -> RunRecording:
    """A run whose agent was killed after its recorder closed the file, before the
    manifest was written (its SHA-256 takes a while on a large file)."""
    run = RunRecording(runs, "r1", AGENT, None, "{}", None, max_mb=max_mb)
    for k in range(15_000):
        run.record("/pose/received", {"agent": "rome/p", "t": float(k), "p": os.urandom(60).hex()})
        if k % 500 == 0:
            run.recorder.flush()
    run.status_line('{"agent": "kiruna/knatte"}')
    run.recorder.close()
    assert run._status_file is not None
    run._status_file.close()
    return run


@pytest.mark.parametrize("case", ["whole", "truncated", "truncated, its note written"])
def test_a_finished_recording_without_its_manifest_is_only_finalized(
    tmp_path: Path, case: str
) -> None:
    """Not renamed .partial, copied and said 'recovered after its agent stopped
    mid-run': that would lose its truncation details and double its disk use."""
    runs = tmp_path / "runs"
    run = _closed_not_finalized(runs, None if case == "whole" else 1)
    report = run.recorder.report()
    assert report["complete"] is (case == "whole")
    note = run.dir / f"{STEM}.incomplete.json"
    if case == "truncated, its note written":  # killed during the manifest's SHA-256
        write_incomplete(run.dir, AGENT, "r1", report)
        note_bytes = note.read_bytes()
    original = run.mcap.read_bytes()
    assert is_finished(run.mcap)

    result = recover_runs(runs, AGENT)

    assert result.finalized == ["r1"] and not result.recovered and not result.failed
    assert run.mcap.read_bytes() == original  # neither renamed nor copied
    assert sorted(p.name for p in run.dir.iterdir() if ".mcap" in p.name) == [f"{STEM}.mcap"]
    manifest = Manifest.model_validate_json((run.dir / manifest_name(STEM)).read_text())
    listed = {f.name: f for f in manifest.files}
    assert listed[f"{STEM}.mcap"].sha256 == sha256_file(run.mcap)
    assert "fedlab.recovery" not in read_metadata(run.mcap)
    if case == "whole":
        assert set(listed) == {f"{STEM}.mcap", f"{STEM}.jsonl"} and not note.exists()
        return
    assert set(listed) == {f"{STEM}.mcap", f"{STEM}.jsonl", f"{STEM}.incomplete.json"}
    said = json.loads(note.read_text())
    assert said == {"agent": AGENT, "run_id": "r1", **report}  # as finish() would have
    assert said["truncated"] is True and "recovered" not in said
    if case == "truncated, its note written":
        assert note.read_bytes() == note_bytes  # kept as it was
    assert unfinished_runs(runs, AGENT) == []


def test_a_cut_recording_is_not_taken_for_a_finished_one(finished: Path, tmp_path: Path) -> None:
    data = finished.read_bytes()
    for cut in (len(data) - 1, len(data) - 40, _chunks(finished)[-1].end, 8, 0):
        (tmp_path / "cut.mcap").write_bytes(data[:cut])
        assert not is_finished(tmp_path / "cut.mcap"), cut
    garbled = bytearray(data)
    garbled[_chunks(finished)[1].start] = 0  # an index pointing at no chunk (a torn write)
    (tmp_path / "torn.mcap").write_bytes(bytes(garbled))
    assert not is_finished(tmp_path / "torn.mcap")
    assert is_finished(finished)


# -- disk space, failures, a run under way -----------------------------------------------
def test_a_recovery_waits_for_the_space_its_copy_takes(
    finished: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    runs = tmp_path / "runs"
    content = finished.read_bytes()[: _chunks(finished)[2].end + 5]
    folder = _unfinished(runs, "r1", content)
    floor = 10  # MiB: record_min_free_mb
    free = len(content) + floor * (1 << 20) - 1
    monkeypatch.setattr(runfolder_module, "free_bytes", lambda path: free)
    result = recover_runs(runs, AGENT, min_free_mb=floor)
    assert list(result.short_of_space) == ["r1"] and not result.recovered
    assert "record_min_free_mb (10 MiB)" in result.short_of_space["r1"]
    assert sorted(p.name for p in folder.iterdir()) == [f"{STEM}.jsonl", f"{STEM}.mcap"]
    assert unfinished_runs(runs, AGENT) == [folder]  # tried again at the next start
    free += 1
    assert set(recover_runs(runs, AGENT, min_free_mb=floor).recovered) == {"r1"}


@pytest.mark.parametrize("how", ["disk full", "stopped"])
def test_a_copy_that_fails_or_stops_leaves_no_half_written_file(
    finished: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    """A .recovering left behind would take its room until the next start, and again
    then."""
    runs = tmp_path / "runs"
    content = finished.read_bytes()[: _chunks(finished)[3].end]
    folder = _unfinished(runs, "r1", content)
    recovering = folder / f"{STEM}.mcap.recovering"
    stop = None
    if how == "disk full":
        real = runfolder_module.salvage

        def full(damaged: Path, out: Path, note: object, stopped: object) -> object:
            def fails() -> bool:
                if out.exists() and out.stat().st_size > 0:
                    raise OSError(errno.ENOSPC, "No space left on device")
                return False

            return real(damaged, out, note, fails)  # type: ignore[arg-type]

        monkeypatch.setattr(runfolder_module, "salvage", full)
        result = recover_runs(runs, AGENT)
        assert list(result.failed) == ["r1"] and "No space" in result.failed["r1"]
    else:
        stop = __import__("threading").Event()
        stop.set()  # the agent stopping: its recovery stops between two records
        with pytest.raises(InterruptedError):
            recover_run(folder, AGENT, stop)
    assert not recovering.exists()
    assert (folder / f"{STEM}.mcap.partial").read_bytes() == content
    assert unfinished_runs(runs, AGENT) == [folder]


def test_no_copy_is_made_while_the_agent_records_a_run(finished: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    content = finished.read_bytes()[: _chunks(finished)[4].end]
    folder = _unfinished(runs, "r1", content)
    running = "run r9 running"
    result = recover_runs(runs, AGENT, busy=lambda: running)
    assert result.waiting == ["r1"] and not result.recovered
    assert sorted(p.name for p in folder.iterdir()) == [f"{STEM}.jsonl", f"{STEM}.mcap"]
    # A run armed during the copy stops it; it is done once the run is over.
    asked = 0

    def armed_meanwhile() -> str | None:
        nonlocal asked
        asked += 1
        return None if asked <= 3 else running

    result = recover_runs(runs, AGENT, busy=armed_meanwhile)
    assert result.waiting == ["r1"] and asked > 3
    assert not (folder / f"{STEM}.mcap.recovering").exists()
    assert not (folder / manifest_name(STEM)).exists()
    assert set(recover_runs(runs, AGENT, busy=lambda: None).recovered) == {"r1"}


def test_the_recording_server_recovers_once_the_agents_run_is_over(
    session: zenoh.Session, finished: Path, tmp_path: Path
) -> None:
    runs = tmp_path / "runs"
    folder = _unfinished(runs, "r1", finished.read_bytes()[: _chunks(finished)[2].end])
    state = {"busy": "run r9 running"}
    asked: list[float] = []  # when the server asked whether the run is over

    def busy() -> str | None:
        asked.append(time.monotonic())
        return state["busy"]

    server = RecordingServer(
        session, "default", AgentId("kiruna", "knatte"), runs, busy=busy, min_free_mb=0
    )
    try:
        # It asks again every RECOVERY_RETRY: twice more, and still waits for the run.
        retried = 2 * collect_module.RECOVERY_RETRY
        assert wait_for(lambda: len(asked) > 1 and asked[-1] - asked[0] >= retried, timeout=10)
        assert server.recovery is None  # waiting for the run
        assert sorted(p.name for p in folder.iterdir()) == [f"{STEM}.jsonl", f"{STEM}.mcap"]
        state["busy"] = None  # type: ignore[assignment]
        assert wait_for(lambda: server.recovery is not None, timeout=10)
        assert server.recovery is not None and set(server.recovery.recovered) == {"r1"}
        assert not server.recovery.waiting
        assert (folder / manifest_name(STEM)).exists()
    finally:
        server.close()


# -- a lock that cannot be told -----------------------------------------------------------
def test_a_live_recording_on_nfs_is_left_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """NFS emulates flock with a write lock: on a read-only descriptor it fails (EBADF),
    which is not 'no locks here': the live file must not be renamed."""
    real = fcntl.flock

    def nfs(fd: int, operation: int) -> None:
        if fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_RDONLY:
            raise OSError(errno.EBADF, "Bad file descriptor")
        real(fd, operation)

    monkeypatch.setattr(fcntl, "flock", nfs)
    runs = tmp_path / "runs"
    rec = Recorder(runs / "live" / f"{STEM}.mcap", AGENT)
    try:
        rec.record("/status", {"agent": AGENT, "t_exec": 0.0})
        rec.flush()
        result = recover_runs(runs, AGENT)
        assert result.in_use == ["live"] and not result.recovered
        assert sorted(p.name for p in (runs / "live").iterdir()) == [f"{STEM}.mcap"]
    finally:
        rec.close()


def test_a_recording_whose_lock_cannot_be_told_is_left_alone_said_once(
    finished: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:  # fmt: skip
    def no_locks(fd: int, operation: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    monkeypatch.setattr(recorder_module, "_lock_unknown_said", False)
    caplog.set_level(logging.WARNING, logger="fedlab.recorder")
    runs = tmp_path / "runs"
    content = finished.read_bytes()[: _chunks(finished)[1].end]
    for run in ("a", "b"):
        _unfinished(runs, run, content)
    result = recover_runs(runs, AGENT)
    assert result.lock_unknown == ["a", "b"] and not result.recovered
    for run in ("a", "b"):
        assert (runs / run / f"{STEM}.mcap").read_bytes() == content  # not renamed
    said = [
        r
        for r in caplog.records
        if r.levelno >= logging.WARNING and "cannot be told" in r.getMessage()
    ]
    assert len(said) == 1 and "ENOLCK" in said[0].getMessage()
