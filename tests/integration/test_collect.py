"""``fedlab collect`` with real processes: a two-lab run's recordings gathered over two
routers (and through the link emulator with 40 ms delay) give the same report as the
original files, read from the merged file collect writes beside them; a merge that
fails is reported and leaves the recordings as fetched; a corrupted or truncated chunk
is fetched again; a partial download resumes; a 60 MB file is collected with bounded
memory; the run of an agent killed mid-run is recovered when it starts again and
collected, marked incomplete."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from lifecycle import QUICK_LOCK, fedlab, participants, runs_dir, write_experiment
from loopback import LEADER, Labs, client_config

from federation.core.chunking import resume_offset
from federation.fleet.launch import wait_for
from federation.report import write_report
from federation.runtime.collect import collect, finalize, sha256_file, zenoh_fetch
from federation.runtime.recorder import read_messages, read_metadata
from schemas.messages import CHUNK_SIZE

# In make test's lane, beside the parallel workers (pyproject.toml's markers).
pytestmark = [pytest.mark.integration, pytest.mark.lane]

MB = 1 << 20


def summary(run: Path, command: bool = False, source: str = "recordings") -> dict[str, object]:
    """The summary.json of ``run``'s report: with ``command`` as ``fedlab report`` writes it,
    else written in this process (:func:`write_report`, what the command runs); read
    from ``source`` (``merged``: the merged file, ``recordings``: the per-agent files)."""
    if command:
        done, _ = fedlab("report", str(run), "--out", str(run / "report"))
        assert done.returncode == 0, done.stdout + done.stderr
    else:
        write_report(run, run / "report")
    data: dict[str, object] = json.loads((run / "report" / "summary.json").read_text())
    assert data.pop("run_dir") == str(run)  # the things that may differ
    assert data.pop("source")["kind"] == source  # type: ignore[index]
    return data


@pytest.mark.parametrize(
    "link",
    [
        pytest.param(False, id="two-routers"),
        pytest.param(True, id="link-40ms", marks=pytest.mark.scenario),
    ],
)
def test_collect_gathers_a_two_lab_run_and_the_report_matches(
    labs: Labs, tmp_path: Path, link: bool
) -> None:
    pair = labs.pair(
        link=["--delay-ms", "40", "--jitter-ms", "1", "--seed", "1"] if link else False
    )
    experiment = write_experiment(tmp_path / "exp.toml", 4)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    follower = agents["rome/pinocchio"]
    follower.until(lambda s: (s.get("ready") or {}).get("reference_locked"), timeout=25)
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "gather",
        "--max-bound", "0.05", "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    for agent in agents.values():
        agent.until(lambda s: s["mode"] == "done", timeout=20, what="done")

    original = tmp_path / "original"  # what copying by hand from both hosts would give
    original.mkdir()
    for who in agents:
        folder = runs_dir(labs, who) / "gather"
        stem = who.replace("/", "-")
        manifest = folder / f"{stem}.manifest.json"
        assert wait_for(manifest.exists, timeout=10), f"{who}: the run never finalized"
        for name in (f"{stem}.mcap", f"{stem}.jsonl"):
            shutil.copy(folder / name, original / name)

    out = tmp_path / "collected"
    done, took = fedlab(
        "collect", "gather", "--out", str(out), "--experiment", str(experiment), "--json",
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(done.stdout)
    print(f"collected {result['bytes_fetched']} bytes in {took:.2f} s (link: {link})")
    assert set(result["files"]) == set(agents) and not result["missing"]
    for path in original.iterdir():
        assert sha256_file(out / path.name) == sha256_file(path), path.name
    merged = result["merged"]  # collect merged what it gathered
    assert merged["file"] == str(out / "merged.mcap") and sorted(merged["agents"]) == sorted(agents)
    assert (out / "merged.layout.json").exists()
    collected = summary(out, command=True, source="merged")
    assert collected == summary(original)
    assert collected["agents"] and collected["sync"]  # a report with something in it


def _served_run(labs: Labs, run: str, sizes: dict[str, int]) -> Path:
    """A finished run of ``sizes`` (name: bytes of random data) under a runs folder."""
    folder = runs_dir(labs, LEADER) / run
    folder.mkdir(parents=True)
    paths = []
    for name, size in sizes.items():
        path = folder / name
        with path.open("wb") as f:
            for start in range(0, size, MB):
                f.write(os.urandom(min(MB, size - start)))
        paths.append(path)
    finalize(folder, LEADER, run, paths)
    return folder


def test_a_corrupted_or_truncated_chunk_is_fetched_again_and_a_download_resumes(
    labs: Labs, tmp_path: Path
) -> None:
    import zenoh

    folder = _served_run(labs, "faulty", {"kiruna-knatte.mcap": 3 * MB + 123})
    original = folder / "kiruna-knatte.mcap"
    router = labs.router("kiruna")
    leader = labs.leader(router, "--runs-dir", str(runs_dir(labs, LEADER)))
    leader.wait_status(timeout=20)
    faults = {MB: "corrupt", 2 * MB: "truncate"}  # chunk offset -> what happens to it once

    with zenoh.open(client_config(router.endpoint)) as session:
        real = zenoh_fetch(session)

        def faulty(key: str, parameters: str, timeout: float):  # type: ignore[no-untyped-def]
            replies = real(key, parameters, timeout)
            for offset, fault in list(faults.items()):
                if f"offset={offset};" in parameters:
                    del faults[offset]
                    data = replies[0].payload
                    if fault == "corrupt":
                        data = data[:100] + bytes([data[100] ^ 0xFF]) + data[101:]
                    else:
                        data = data[: len(data) // 2]
                    replies[0] = replies[0]._replace(payload=data)
            return replies

        out = tmp_path / "out"
        result = collect(None, "default", "faulty", out, fetch=faulty)
        assert result.ok, result.errors
        assert result.refetched == {"corrupted": 1, "truncated": 1}
        assert sha256_file(out / original.name) == sha256_file(original)

        # Interrupted after a chunk and a half: resumes at the whole chunk.
        resumed = tmp_path / "resumed"
        resumed.mkdir()
        (resumed / f"{original.name}.part").write_bytes(original.read_bytes()[: MB + MB // 2])
        again = collect(session, "default", "faulty", resumed)
        assert again.ok and again.resumed == [original.name]
        kept = resume_offset(MB + MB // 2, original.stat().st_size, CHUNK_SIZE)
        assert 0 < kept <= MB + MB // 2
        assert again.bytes_fetched == original.stat().st_size - kept
        assert hashlib.sha256((resumed / original.name).read_bytes()).hexdigest() == (
            sha256_file(original)
        )
        # Run again: nothing fetched, the complete file is kept.
        third = collect(session, "default", "faulty", resumed)
        assert third.skipped == [original.name] and third.bytes_fetched == 0


def _peak_rss(argv: list[str]) -> tuple[int, int]:
    """Run ``argv`` to its end; (exit code, peak resident set in bytes, from VmHWM)."""
    proc = subprocess.Popen(
        argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    peak = 0
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            for line in Path(f"/proc/{proc.pid}/status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    peak = max(peak, int(line.split()[1]) * 1024)
        except (FileNotFoundError, ProcessLookupError):
            break
        time.sleep(0.02)
    if proc.poll() is None:
        proc.kill()
    output = proc.communicate(timeout=10)[0]
    assert proc.returncode == 0, output.decode()
    return proc.returncode, peak


def test_a_recording_over_50_mb_is_collected_with_bounded_memory(
    labs: Labs, tmp_path: Path
) -> None:
    _served_run(labs, "small", {"kiruna-knatte.mcap": 1 * MB})
    big = _served_run(labs, "big", {"kiruna-knatte.mcap": 60 * MB})
    router = labs.router("kiruna")
    leader = labs.leader(router, "--runs-dir", str(runs_dir(labs, LEADER)))
    leader.wait_status(timeout=20)
    base = [sys.executable, "-m", "federation", "collect"]
    flags = ["-e", router.endpoint, "--timeout", "10", "--no-merge"]  # collect's memory only
    _, small = _peak_rss([*base, "small", "--out", str(tmp_path / "small"), *flags])
    _, large = _peak_rss([*base, "big", "--out", str(tmp_path / "big"), *flags])
    print(f"collect peak RSS: 1 MB run {small / MB:.1f} MB, 60 MB run {large / MB:.1f} MB")
    assert sha256_file(tmp_path / "big" / "kiruna-knatte.mcap") == sha256_file(
        big / "kiruna-knatte.mcap"
    )
    assert large - small < 20 * MB  # one chunk at a time, not the file (60 MB)
    assert not (tmp_path / "small" / "merged.mcap").exists()  # --no-merge

    # Merged by default: random bytes are no recording, so the merge fails, says why,
    # exits 1, and the file fetched stays as it was.
    failed, _ = fedlab("collect", "small", "--out", str(tmp_path / "merge"), *flags[:-1])
    assert failed.returncode == 1, failed.stdout + failed.stderr
    assert "merge failed: ConfigError: no recording's status names the reference agent" in (
        " ".join(failed.stdout.split())
    ), failed.stdout
    assert "the recordings are kept as fetched (kiruna-knatte.mcap)" in failed.stdout
    assert sha256_file(tmp_path / "merge" / "kiruna-knatte.mcap") == sha256_file(
        runs_dir(labs, LEADER) / "small" / "kiruna-knatte.mcap"
    )
    assert sorted(p.name for p in (tmp_path / "merge").iterdir() if "merged" in p.name) == []


def test_a_killed_agents_run_is_recovered_when_it_starts_again_and_collected(
    labs: Labs, tmp_path: Path
) -> None:
    """SIGKILL mid-run: no summary, no manifest; the crashed run had been the one run a
    lab could not collect. Started again, the agent recovers it (and a run whose file is
    empty, which does not stop it starting), and collect fetches it, saying what it
    misses."""
    experiment = tmp_path / "alone.toml"
    experiment.write_text(
        'name = "alone"\nduration = 60\nstart_delay = 1.0\n'
        f'[[participants]]\nagent = "{LEADER}"\nrole = "leader"\nplatform = "knatte"\n',
        encoding="utf-8",
    )
    runs = runs_dir(labs, LEADER)
    stem = LEADER.replace("/", "-")
    (runs / "junk").mkdir(parents=True)
    (runs / "junk" / f"{stem}.mcap").write_bytes(b"")  # killed before a byte reached the disk
    router = labs.router("kiruna")
    leader = labs.agent(
        LEADER, router, "--experiment", str(experiment), "--runs-dir", str(runs)
    )  # fmt: skip
    leader.until(lambda s: s["mode"] == "waiting", timeout=20, what="waiting")
    assert wait_for((runs / "junk" / f"{stem}.manifest.json").exists, timeout=10)
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "crash",
        "-e", router.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    leader.until(lambda s: s["mode"] == "running", timeout=15, what="running")
    mcap = runs / "crash" / f"{stem}.mcap"
    # Records on disk past the header: complete chunks to recover, more than one to fetch.
    assert wait_for(lambda: mcap.exists() and mcap.stat().st_size > 2 * CHUNK_SIZE, timeout=30)
    leader.kill()
    assert not leader.alive()
    killed_at = mcap.stat().st_size
    manifest = runs / "crash" / f"{stem}.manifest.json"
    assert not manifest.exists()

    leader.start()  # the same command line, as systemd would
    leader.until(lambda s: s["mode"] == "waiting", timeout=20, what="up again")
    assert wait_for(manifest.exists, timeout=20), leader.log()[-3000:]
    assert (runs / "crash" / f"{stem}.mcap.partial").stat().st_size == killed_at  # kept

    out = tmp_path / "collected"
    done, _ = fedlab("collect", "crash", "--out", str(out), "--json", "-e", router.endpoint)
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(done.stdout)
    assert sorted(result["files"][LEADER]) == sorted(
        [f"{stem}.mcap", f"{stem}.jsonl", f"{stem}.incomplete.json"]
    )
    assert "recovered after its agent stopped mid-run" in result["incomplete"][LEADER]
    note = json.loads((out / f"{stem}.incomplete.json").read_text())
    assert note["recovered"] and note["end_missing"] and note["messages"] > 0
    recovered = read_messages(out / f"{stem}.mcap")  # finished: summary and index read
    assert recovered["/pose/sent"] and recovered["/reference"]
    assert sum(len(v) for v in recovered.values()) <= note["messages"]  # + Foxglove's
    meta = read_metadata(out / f"{stem}.mcap")
    assert meta["fedlab.run"]["run_id"] == "crash"
    assert meta["fedlab.recovery"]["messages"] == str(note["messages"])
    assert any(e["event"] == "started" for e in recovered["/control"])
