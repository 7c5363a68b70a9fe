"""A run's folder on its agent's host: finished with a manifest, and recovered when
its agent never finished it.

Each agent records a run into ``<runs_dir>/<run-id>/`` and, once the run is over,
writes ``<lab>-<name>.manifest.json`` there (its files, their sizes and SHA-256;
:func:`finalize`), durably (:func:`write_durably`): the manifest is what
:mod:`federation.runtime.collect` serves and fetches by.

A run its agent never finalized (the agent killed, its host's power lost: an MCAP
with no summary, no manifest) is recovered when the agent starts again
(:func:`recover_runs`, on a thread of the
:class:`~federation.runtime.collect.RecordingServer`): the original is renamed
``<lab>-<name>.mcap.partial`` and kept, every complete record it holds is written into
a finished ``<lab>-<name>.mcap``, and the manifest is written, so the crashed run is
collected like any other. A recording its agent finished (killed while the
manifest's SHA-256 was computed) is only finalized: nothing copied, not marked
recovered. A copy waits while the agent records a run, and for free space (the
original's size and ``record_min_free_mb``); a file whose lock cannot be told is left
alone. A recording that is not whole (recovered, or truncated at its size limit) has
``<lab>-<name>.incomplete.json`` beside it, listed in its manifest: what is missing
and why (:func:`describe_incomplete` says it in a line).
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import hashlib
import json
import logging
import os
import shutil
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from federation.core.channels import recording_stem
from federation.runtime.mcapfile import (
    RECORDING_METADATA,
    RECOVERY_METADATA,
    Salvage,
    from_metadata,
    is_finished,
    read_metadata,
    salvage,
)
from federation.runtime.recorder import hold
from schemas.messages import CHUNK_SIZE, FileEntry, Manifest

__all__ = [
    "Deferred",
    "Recovery",
    "describe_incomplete",
    "finalize",
    "free_bytes",
    "incomplete_name",
    "listed",
    "manifest_name",
    "recover_run",
    "recover_runs",
    "sha256_file",
    "sync_directory",
    "unfinished_runs",
    "write_durably",
    "write_incomplete",
]

# The recovery's messages go where the recordings' collection logs: one place to look.
log = logging.getLogger("fedlab.collect")

MIB = 1 << 20


def manifest_name(stem: str) -> str:
    """``kiruna-knatte`` -> ``kiruna-knatte.manifest.json``."""
    return f"{stem}.manifest.json"


def incomplete_name(stem: str) -> str:
    """``kiruna-knatte`` -> ``kiruna-knatte.incomplete.json``."""
    return f"{stem}.incomplete.json"


def write_incomplete(
    run_dir: Path, agent: str, run_id: str, what: dict[str, Any], stem: str | None = None
) -> Path:
    """Write ``<lab>-<name>.incomplete.json`` (what a recording misses and why; ``stem``:
    a later segment's, ``<lab>-<name>.seg2``) into ``run_dir``; returns its path, for the
    manifest."""
    path = run_dir / incomplete_name(stem or recording_stem(agent))
    data = {"agent": agent, "run_id": run_id, **what}
    write_durably(path, json.dumps(data, indent=1) + "\n")
    return path


def write_durably(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole: to a temporary name, on disk, then renamed (and
    the rename on disk): never seen half-written, nor lost after a power cut once this
    returns."""
    tmp = path.with_suffix(".tmp")
    try:
        with tmp.open("w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            try:
                os.fsync(f.fileno())
            except OSError as error:
                if error.errno != errno.EINVAL:  # EINVAL: a file with nothing to sync
                    raise
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    sync_directory(path.parent)


def sync_directory(directory: Path) -> None:
    """The directory's entries (a rename, a new file) on disk; best effort: a filesystem
    that cannot say so is left as it is."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def free_bytes(path: Path) -> int | None:
    """Bytes free for this user on the filesystem of ``path`` (or of its nearest existing
    parent: a runs folder is made at the first run); None if it cannot be told."""
    where = Path(path).absolute()
    while not where.exists() and where != where.parent:
        where = where.parent
    try:
        return shutil.disk_usage(where).free
    except OSError:
        return None


def describe_incomplete(data: object) -> str:
    """One line on what an ``incomplete.json`` says (sent by an agent: any JSON)."""
    if not isinstance(data, dict):
        return "its recording is incomplete (no details)"
    parts = []
    if data.get("recovered"):
        parts.append(
            f"recovered after its agent stopped mid-run: {data.get('messages', '?')} messages"
            + (", its end missing" if data.get("end_missing") else "")
        )
        if data.get("chunks_lost"):
            parts.append(f"{data['chunks_lost']} unreadable chunk(s) left out")
    if data.get("truncated"):
        parts.append(
            f"truncated at its limit of {data.get('max_bytes', '?')} bytes: "
            f"{data.get('dropped_over_budget', '?')} messages dropped"
        )
    if data.get("dropped_queue_full"):
        parts.append(f"{data['dropped_queue_full']} messages dropped (buffer full)")
    if data.get("write_errors"):
        parts.append(f"{data['write_errors']} write(s) failed: messages lost")
    if data.get("status_write_errors"):
        parts.append(f"{data['status_write_errors']} status line write(s) failed")
    if data.get("not_recorded"):
        parts.append(str(data["not_recorded"]))
    return ("; ".join(parts) or "its recording is incomplete")[:500]  # an agent's text


def sha256_file(path: Path, block: int = CHUNK_SIZE) -> str:
    """A file's SHA-256 (hex), read a block at a time."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while data := f.read(block):
            digest.update(data)
    return digest.hexdigest()


def listed(run_dir: Path, agent: str) -> set[str] | None:
    """The file names ``agent``'s manifest in ``run_dir`` lists; None without a manifest
    (or with one that cannot be read)."""
    try:
        text = (run_dir / manifest_name(recording_stem(agent))).read_text(encoding="utf-8")
        return {f.name for f in Manifest.model_validate_json(text).files}
    except (OSError, ValueError):
        return None


def finalize(run_dir: Path, agent: str, run_id: str, files: list[Path]) -> Path:
    """Write the manifest of an agent's finished ``files`` of a run; returns its path.
    The files an earlier manifest of the run lists stay listed while they are there: a
    run flown in segments (rejoined) has one manifest of every segment, whichever
    segment is finalized last. Written durably (:func:`write_durably`): a manifest is
    never seen half-written."""
    names = {p.name for p in files}
    kept = [run_dir / name for name in sorted((listed(run_dir, agent) or set()) - names)]
    entries = [
        FileEntry(name=p.name, size=p.stat().st_size, sha256=sha256_file(p))
        for p in [*kept, *files]
        if p.exists()
    ]
    manifest = Manifest(agent=agent, run_id=run_id, files=entries)
    path = run_dir / manifest_name(recording_stem(agent))
    write_durably(path, manifest.model_dump_json(indent=1) + "\n")
    return path


@dataclass
class Recovery:
    """What :func:`recover_runs` did with an agent's unfinished runs, by run id."""

    recovered: dict[str, Salvage] = field(default_factory=dict)
    finalized: list[str] = field(default_factory=list)  # finished files: manifest written
    in_use: list[str] = field(default_factory=list)  # a running process writes it: left alone
    lock_unknown: list[str] = field(default_factory=list)  # cannot be told: left alone
    short_of_space: dict[str, str] = field(default_factory=dict)  # why: the next start
    waiting: list[str] = field(default_factory=list)  # this agent records a run: after it
    failed: dict[str, str] = field(default_factory=dict)  # why it could not be (logged)

    def add(self, other: Recovery) -> None:
        """What a later pass did (the runs that had waited for the agent's run)."""
        self.recovered |= other.recovered
        self.finalized += other.finalized
        self.in_use += other.in_use
        self.lock_unknown += other.lock_unknown
        self.short_of_space |= other.short_of_space
        self.waiting = list(other.waiting)
        self.failed |= other.failed


class Deferred(Exception):
    """Why a run's recovery is left for later; ``kind``: the :class:`Recovery` list it
    goes in (``in_use``, ``lock_unknown``, ``short_of_space``, ``waiting``)."""

    def __init__(self, kind: str, why: str):
        super().__init__(why)
        self.kind = kind


def unfinished_runs(runs_dir: Path, agent: str) -> list[Path]:
    """``agent``'s run folders under ``runs_dir`` that hold its recording (or the original
    a recovery kept aside) but no manifest: runs it never finalized, by name."""
    stem = recording_stem(agent)
    try:
        folders = sorted(p for p in Path(runs_dir).iterdir() if p.is_dir())
    except OSError:  # no runs yet (or unreadable: a recording there would fail too)
        return []
    return [folder for folder in folders if _unfinished(folder, agent, stem)]


def _unfinished(folder: Path, agent: str, stem: str) -> bool:
    """Whether ``folder`` holds ``agent``'s first recording of the run (or the original a
    recovery kept aside) and no manifest lists it (none at all, or only a later
    segment's: the agent killed, started again, rejoined and finished the run)."""
    if not ((folder / f"{stem}.mcap").exists() or (folder / f"{stem}.mcap.partial").exists()):
        return False
    if not (folder / manifest_name(stem)).exists():
        return True
    names = listed(folder, agent)
    return names is not None and f"{stem}.mcap" not in names


def recover_run(
    run_dir: Path,
    agent: str,
    stop: threading.Event | None = None,
    *,
    min_free_mb: int = 0,
    busy: Callable[[], str | None] | None = None,
) -> Salvage | None:
    """Finalize ``agent``'s unfinished recording in ``run_dir``.

    A finished recording (:func:`~federation.runtime.mcapfile.is_finished`: its agent
    killed after closing it, before the manifest was written) only gets its manifest:
    nothing copied, not marked recovered; its ``.incomplete.json`` is kept, or written
    from its ``fedlab.recording`` metadata if that says something was left out.
    Returns None.

    A cut one: the original renamed ``.mcap.partial`` (kept, never deleted), every
    complete record of it written into a finished ``.mcap``
    (:func:`~federation.runtime.mcapfile.salvage`, through ``.mcap.recovering``,
    deleted if the copy fails or stops), what is missing in ``.incomplete.json``, then
    the manifest. Returns what was read. Each step can be cut short and done again: a
    ``.partial`` is the original, the ``.mcap`` beside it only what a recovery wrote.

    Raises :class:`Deferred`: the file's lock is held by a process (``in_use``) or
    cannot be told (``lock_unknown``), ``busy()`` says this agent records a run
    (``waiting``; asked again during the copy, which then stops), or the filesystem
    has less free than the original's size and ``min_free_mb`` MiB
    (``short_of_space``). ``InterruptedError`` when ``stop`` is set during the copy.
    """
    stem = recording_stem(agent)
    mcap = run_dir / f"{stem}.mcap"
    partial = run_dir / f"{stem}.mcap.partial"
    recovering = run_dir / f"{stem}.mcap.recovering"
    original = partial if partial.exists() else mcap
    _not_busy(busy)
    with original.open("r+b") as held:  # r+b: NFS locks (flock) only what is open to write
        _held(held, original)
        if original == mcap and is_finished(mcap):
            _finalize_finished(run_dir, agent)
            return None
        size = os.fstat(held.fileno()).st_size
        free = free_bytes(run_dir)
        if free is not None and free < size + min_free_mb * MIB:
            raise Deferred(
                "short_of_space",
                f"{free / MIB:.0f} MiB free; its copy takes up to {size / MIB:.1f} MiB and "
                f"record_min_free_mb ({min_free_mb} MiB) must stay free",
            )
        if original == mcap:
            os.replace(mcap, partial)
        when = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
        note = {"original": partial.name, "recovered_utc": when}

        def stopped() -> bool:
            return (stop is not None and stop.is_set()) or (busy is not None and busy() is not None)

        try:
            salvaged = salvage(partial, recovering, note, stopped)
            if mcap.exists():  # a recovery's, cut short; or a recorder's, begun since: not ours
                with mcap.open("r+b") as other:
                    _held(other, mcap)
            os.replace(recovering, mcap)
        finally:  # cut short, failed or refused: nothing half-written left to take room
            with contextlib.suppress(OSError):
                recovering.unlink(missing_ok=True)
    sidecar = write_incomplete(run_dir, agent, run_dir.name, salvaged.report() | note)
    finalize(run_dir, agent, run_dir.name, [mcap, run_dir / f"{stem}.jsonl", sidecar])
    return salvaged


def _not_busy(busy: Callable[[], str | None] | None) -> None:
    why = None if busy is None else busy()
    if why is not None:
        raise Deferred("waiting", f"this agent records {why}: after it")


def _held(file: IO[bytes], path: Path) -> None:
    """Raise :class:`Deferred` unless this process now holds ``file``'s lock."""
    state = hold(file)
    if state is False:
        raise Deferred("in_use", f"a running process records {path.name}")
    if state is None:
        raise Deferred("lock_unknown", f"whether a process writes {path.name} cannot be told")


def _finalize_finished(run_dir: Path, agent: str) -> None:
    """The manifest of a finished recording whose agent stopped before writing it: its
    ``.incomplete.json`` kept, or written from what its metadata says it misses."""
    stem = recording_stem(agent)
    mcap = run_dir / f"{stem}.mcap"
    sidecar = run_dir / incomplete_name(stem)
    if not sidecar.exists():
        what = _left_out(mcap)
        if what is not None:
            write_incomplete(run_dir, agent, run_dir.name, what)
    files = [mcap, run_dir / f"{stem}.jsonl", sidecar]
    finalize(run_dir, agent, run_dir.name, files)  # the sidecar listed if it is there


def _left_out(mcap: Path) -> dict[str, Any] | None:
    """What a finished recording's metadata says it misses (its ``fedlab.recording``
    record not complete, or a ``fedlab.recovery`` record); None if nothing."""
    try:
        meta = read_metadata(mcap)
    except Exception:  # finished, yet its metadata index unreadable: nothing to say
        log.warning("%s: metadata unreadable", mcap, exc_info=True)
        return None
    recording = meta.get(RECORDING_METADATA)
    if recording is not None and recording.get("complete") == "false":
        return from_metadata(recording)
    recovery = meta.get(RECOVERY_METADATA)
    return None if recovery is None else from_metadata(recovery)


def recover_runs(
    runs_dir: Path,
    agent: str,
    stop: threading.Event | None = None,
    folders: list[Path] | None = None,
    *,
    min_free_mb: int = 0,
    busy: Callable[[], str | None] | None = None,
) -> Recovery:
    """Recover every run of ``agent`` under ``runs_dir`` that it never finalized
    (``folders``, default :func:`unfinished_runs`; :func:`recover_run`, given
    ``min_free_mb`` and ``busy``). Never raises: a run that cannot be recovered (a
    file unreadable, a disk full) or is left for later is logged, counted and left
    as it was found (but for its ``.partial`` name), and the next one is tried."""
    done = Recovery()
    for run_dir in unfinished_runs(runs_dir, agent) if folders is None else folders:
        if stop is not None and stop.is_set():
            break
        run = run_dir.name
        try:
            salvaged = recover_run(run_dir, agent, stop, min_free_mb=min_free_mb, busy=busy)
        except Deferred as later:
            _defer(done, run, run_dir, later)
            continue
        except InterruptedError:
            if stop is not None and stop.is_set():
                break
            _defer(done, run, run_dir, Deferred("waiting", "this agent began a run: after it"))
            continue
        except Exception as error:
            done.failed[run] = f"{type(error).__name__}: {error}"
            log.exception("run %s in %s: not recovered", run, run_dir)
            continue
        if salvaged is None:
            done.finalized.append(run)
            log.warning(
                "run %s in %s: its recording was finished but its agent stopped before "
                "writing the manifest: written now", run, run_dir,
            )  # fmt: skip
            continue
        done.recovered[run] = salvaged
        log.warning(
            "run %s in %s was never finalized (its agent stopped mid-run): recovered %d "
            "messages (%s; %d unreadable chunks left out); the original is kept as %s.mcap.partial",
            run, run_dir, salvaged.messages, salvaged.problem or "the file was whole",
            salvaged.chunks_lost, recording_stem(agent),
        )  # fmt: skip
    return done


def _defer(done: Recovery, run: str, run_dir: Path, later: Deferred) -> None:
    if later.kind == "short_of_space":
        done.short_of_space[run] = str(later)
        log.error(
            "run %s in %s: not recovered yet, %s; tried again at the next start",
            run, run_dir, later,
        )  # fmt: skip
        return
    getattr(done, later.kind).append(run)  # a lock that cannot be told: warned once
    log.info("run %s in %s: left for later (%s)", run, run_dir, later)
