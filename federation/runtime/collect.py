"""A run's recordings, fetched from every lab over the federation (``fedlab collect``).

Each agent records a run into ``<runs_dir>/<run-id>/`` on its own host and, once
the run is finalized, writes ``<lab>-<name>.manifest.json`` there (its files,
their sizes and SHA-256; :func:`finalize`). :class:`RecordingServer` answers
queries on ``fedlab/<fed>/<lab>/<name>/recordings`` with that manifest or with a
chunk of a listed file (the protocol is in :mod:`federation.core.chunking`); it
reads from disk on its own thread, never on Zenoh's.

:func:`collect` asks every agent for the run's manifest, then fetches each file
chunk by chunk into ``<out>/<name>.part``: each chunk's length and digest are
checked and a bad one fetched again (``retries`` times); the whole file's SHA-256
is checked before the ``.part`` is renamed. An interrupted collection resumes
where its ``.part`` files end; files already complete are not fetched again.
Memory holds one chunk at a time, whatever the file's size.

A run its agent never finalized (the agent killed, its host's power lost: an MCAP
with no summary, no manifest) is recovered when the agent starts again
(:func:`recover_runs`, on a thread of the :class:`RecordingServer`): the original
is renamed ``<lab>-<name>.mcap.partial`` and kept, every complete record it holds
is written into a finished ``<lab>-<name>.mcap``, and the manifest is written, so
the crashed run is collected like any other. A recording its agent had finished
(killed while the manifest's SHA-256 was computed) is only finalized: nothing
copied, not marked recovered. A copy waits while the agent records a run, and
for free space (the original's size and ``record_min_free_mb``); a file whose lock
cannot be told is left alone. A recording that is not whole (recovered, or
truncated at its size limit) has ``<lab>-<name>.incomplete.json`` beside it,
listed in its manifest: what is missing and why; :func:`collect` reports it.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import hashlib
import json
import logging
import os
import queue
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple

import zenoh
from pydantic import ValidationError

from federation.core import keys
from federation.core.channels import recording_stem
from federation.core.chunking import (
    ChunkRequest,
    RequestError,
    check_chunk,
    chunk_attachment,
    format_request,
    parse_request,
    resume_offset,
)
from federation.runtime.recorder import (
    RECORDING_METADATA,
    RECOVERY_METADATA,
    Salvage,
    from_metadata,
    hold,
    is_finished,
    read_metadata,
    salvage,
)
from federation.runtime.session import ConnectError
from schemas.config import AgentConfig
from schemas.messages import CHUNK_SIZE, FileEntry, Manifest

__all__ = [
    "CollectError",
    "CollectResult",
    "Deferred",
    "Fetch",
    "Fetched",
    "RecordingServer",
    "Recovery",
    "collect",
    "describe",
    "describe_incomplete",
    "finalize",
    "free_bytes",
    "incomplete_name",
    "manifest_name",
    "recover_run",
    "recover_runs",
    "sha256_file",
    "unfinished_runs",
    "write_incomplete",
    "zenoh_fetch",
]

log = logging.getLogger("fedlab.collect")

TOPIC = "recordings"
QUEUE_SIZE = 64  # queries waiting for the reader thread; more are refused (busy)
WINDOW = 16  # chunk requests a collector keeps in flight
MIB = 1 << 20
DEFAULT_MIN_FREE_MB: int = AgentConfig.model_fields["record_min_free_mb"].default
RECOVERY_RETRY = 1.0
"""s between looks at whether the agent's run is over, recoveries waiting for it."""


class CollectError(ConnectionError):
    """A file that could not be collected: which, from whom, and why."""


def manifest_name(stem: str) -> str:
    """``kiruna-knatte`` -> ``kiruna-knatte.manifest.json``."""
    return f"{stem}.manifest.json"


def incomplete_name(stem: str) -> str:
    """``kiruna-knatte`` -> ``kiruna-knatte.incomplete.json``."""
    return f"{stem}.incomplete.json"


def write_incomplete(run_dir: Path, agent: str, run_id: str, what: dict[str, Any]) -> Path:
    """Write ``<lab>-<name>.incomplete.json`` (what a recording misses and why) into
    ``run_dir``; returns its path, for the manifest."""
    path = run_dir / incomplete_name(recording_stem(agent))
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


def finalize(run_dir: Path, agent: str, run_id: str, files: list[Path]) -> Path:
    """Write the manifest of an agent's finished ``files`` of a run; returns its path.
    Written durably (:func:`write_durably`): a manifest is never seen half-written."""
    entries = [
        FileEntry(name=p.name, size=p.stat().st_size, sha256=sha256_file(p))
        for p in files
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
    return [
        folder
        for folder in folders
        if not (folder / manifest_name(stem)).exists()
        and ((folder / f"{stem}.mcap").exists() or (folder / f"{stem}.mcap.partial").exists())
    ]


def recover_run(
    run_dir: Path,
    agent: str,
    stop: threading.Event | None = None,
    *,
    min_free_mb: int = 0,
    busy: Callable[[], str | None] | None = None,
) -> Salvage | None:
    """Finalize ``agent``'s unfinished recording in ``run_dir``.

    A finished recording (:func:`~federation.runtime.recorder.is_finished`: its agent
    killed after closing it, before the manifest was written) only gets its manifest:
    nothing copied, not marked recovered; its ``.incomplete.json`` is kept, or written
    from its ``fedlab.recording`` metadata if that says something was left out.
    Returns None.

    A cut one: the original renamed ``.mcap.partial`` (kept, never deleted), every
    complete record of it written into a finished ``.mcap``
    (:func:`~federation.runtime.recorder.salvage`, through ``.mcap.recovering``,
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


class RecordingServer:
    """Serves one agent's finished recordings under ``runs_dir`` to ``fedlab collect``;
    first, on a thread of its own, recovers the runs the agent never
    finalized (:func:`recover_runs`, each copy leaving ``min_free_mb`` MiB free, none
    while ``busy()`` says a run is under way: those once it is over): ``recovery``
    says what became of them, once every run was tried."""

    def __init__(
        self,
        session: zenoh.Session,
        federation: str,
        agent: keys.AgentId,
        runs_dir: Path,
        busy: Callable[[], str | None] = lambda: None,
        min_free_mb: int = DEFAULT_MIN_FREE_MB,
    ):
        self.runs_dir = Path(runs_dir)
        self.min_free_mb = min_free_mb
        self.agent = agent
        self.stem = f"{agent.lab}-{agent.name}"
        # Replies go on the agent's own key, never on the query's (a wildcard): the lab
        # router's access control lets an agent reply only under its own address.
        self.key = keys.agent_key(federation, agent, TOPIC)
        self.busy = busy  # why chunks are not served now (a run in progress), or None
        self.served = 0
        self.refused = 0
        self._stop = threading.Event()
        self._queue: queue.Queue[zenoh.Query | None] = queue.Queue(QUEUE_SIZE)
        self._thread = threading.Thread(target=self._run, name="recordings", daemon=True)
        self._thread.start()
        # Looked for now (a folder listing); recovered off the agent's loop and Zenoh's
        # threads, the finished runs served meanwhile. No thread when there is none (a
        # process of 256 agents).
        unfinished = unfinished_runs(self.runs_dir, str(agent))
        self.recovery: Recovery | None = None if unfinished else Recovery()  # once done
        self._recovering = threading.Thread(
            target=self._recover, args=(unfinished,), name="run-recovery", daemon=True
        )
        if unfinished:
            self._recovering.start()
        self._queryable = session.declare_queryable(
            self.key,
            zenoh.handlers.Callback(self._on_query, indirect=False),
        )

    def _recover(self, folders: list[Path]) -> None:
        done = Recovery()
        while True:
            got = recover_runs(
                self.runs_dir, str(self.agent), self._stop, folders,
                min_free_mb=self.min_free_mb, busy=self.busy,
            )  # fmt: skip
            done.add(got)
            if not got.waiting:
                break
            folders = [self.runs_dir / run for run in got.waiting]
            while self.busy() is not None:  # the run is over: those runs then
                if self._stop.wait(RECOVERY_RETRY):
                    break
            if self._stop.is_set():
                break  # the next start tries them
        self.recovery = done

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            self._queue.put_nowait(query)
        except queue.Full:
            self.refused += 1
            try:
                query.reply_err(b"busy: try again")
            finally:
                query.drop()  # type: ignore[no-untyped-call]

    def _run(self) -> None:
        while (query := self._queue.get()) is not None:
            try:
                self._serve(query)
            except Exception:
                log.exception("serving %s failed", query.selector)
            finally:
                query.drop()  # type: ignore[no-untyped-call]

    def _serve(self, query: zenoh.Query) -> None:
        try:
            request = parse_request(str(query.parameters))
        except RequestError as error:
            self.refused += 1
            query.reply_err(f"bad request: {error}".encode())
            return
        run_dir = self.runs_dir / request.run
        manifest_path = run_dir / manifest_name(self.stem)
        if not manifest_path.exists():
            query.reply_err(f"{self.agent}: no finished run {request.run}".encode())
            return
        if request.file is None:
            query.reply(self.key, manifest_path.read_bytes())
            self.served += 1
            return
        busy = self.busy()
        if busy is not None:  # its uplink carries the run's poses and sync first
            self.refused += 1
            query.reply_err(f"busy: {busy}".encode())
            return
        manifest = Manifest.model_validate_json(manifest_path.read_bytes())
        if request.file not in {f.name for f in manifest.files}:
            query.reply_err(f"{self.agent}: {request.file} is not in run {request.run}".encode())
            return
        with (run_dir / request.file).open("rb") as f:
            f.seek(request.offset)
            data = f.read(request.length)
        query.reply(self.key, data, attachment=chunk_attachment(request.offset, data))
        self.served += 1

    def close(self) -> None:
        self._stop.set()  # a recovery stops between records; done again at the next start
        self._queryable.undeclare()  # type: ignore[no-untyped-call]
        self._queue.put(None)
        self._thread.join(5)
        if self._recovering.is_alive():
            self._recovering.join(5)


class Fetched(NamedTuple):
    """One reply to a collector's query."""

    payload: bytes
    attachment: bytes | None
    error: str | None  # the error reply's text (payload empty), None for a good one
    key: str | None = None  # the key it was sent on (None: not known)


Fetch = Callable[[str, str, float], list[Fetched]]
"""``fetch(key, parameters, timeout)``: every reply to one query; the collector's one
network call (a test may wrap it)."""
BUSY_BACKOFF = 1.0
"""s a collector waits before asking again an agent that said it is busy."""


def zenoh_fetch(session: zenoh.Session) -> Fetch:
    """:data:`Fetch` over a Zenoh session."""

    def fetch(key: str, parameters: str, timeout: float) -> list[Fetched]:
        out: list[Fetched] = []
        # Background priority: the replies (which take the query's) yield to every
        # agent's pose and sync on the links they share.
        replies = session.get(
            f"{key}?{parameters}", timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE,
            priority=zenoh.Priority.BACKGROUND,
        )  # fmt: skip
        for reply in replies:
            if reply.ok is not None:
                attachment = reply.ok.attachment
                out.append(
                    Fetched(
                        reply.ok.payload.to_bytes(),
                        None if attachment is None else attachment.to_bytes(),
                        None,
                        str(reply.ok.key_expr),
                    )
                )
            elif reply.err is not None:
                out.append(Fetched(b"", None, reply.err.payload.to_string()))
        return out

    return fetch


@dataclass
class CollectResult:
    """What a collection got: per agent, the files written (or why not)."""

    run_id: str
    out: Path
    files: dict[str, list[str]] = field(default_factory=dict)  # agent -> file names
    refetched: dict[str, int] = field(default_factory=dict)  # why -> chunks fetched again
    resumed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # already complete
    missing: list[str] = field(default_factory=list)  # expected agents with no manifest
    errors: list[str] = field(default_factory=list)
    # agent -> what its recording misses (recovered after a crash, truncated at its limit)
    incomplete: dict[str, str] = field(default_factory=dict)
    bytes_fetched: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def count(self, why: str) -> None:
        """One more chunk fetched again because of ``why`` (from any fetching thread)."""
        with self._lock:
            self.refetched[why] = self.refetched.get(why, 0) + 1

    @property
    def ok(self) -> bool:
        return not self.missing and not self.errors


def collect(
    session: zenoh.Session | None,
    federation: str,
    run_id: str,
    out: Path,
    *,
    expected: set[str] | None = None,
    timeout: float = 5.0,
    retries: int = 5,
    fetch: Fetch | None = None,
    progress: Callable[[str], None] = lambda text: None,
) -> CollectResult:
    """Fetch every agent's finished files of ``run_id`` into ``out``.

    ``expected``: agents (``LAB/NAME``) that must answer (an experiment's
    participants); the others that answer are collected too. Raises
    :class:`~federation.runtime.session.ConnectError` when no agent has the run.
    """
    if fetch is None:
        if session is None:
            raise ValueError("collect needs a session or a fetch function")
        fetch = zenoh_fetch(session)
    out.mkdir(parents=True, exist_ok=True)
    result = CollectResult(run_id, out)
    manifests: dict[str, Manifest] = {}
    for reply in fetch(
        keys.all_of(federation, TOPIC), format_request(ChunkRequest(run_id)), timeout
    ):
        if reply.error is not None:
            log.debug("manifest query: %s", reply.error)
            continue
        problem = _manifest_problem(reply, federation, run_id, manifests)
        if problem is not None:
            result.errors.append(problem)
            continue
        manifest = Manifest.model_validate_json(reply.payload)
        if manifest.run_id == run_id:
            manifests[manifest.agent] = manifest
    result.missing = sorted((expected or set()) - set(manifests))
    if not manifests:
        raise ConnectError(
            f"no agent of federation {federation!r} has a finished run {run_id!r} "
            f"(asked {keys.all_of(federation, TOPIC)} for {timeout:g} s)"
        )
    for agent, manifest in sorted(manifests.items()):
        key = keys.agent_key(federation, keys.AgentId.parse(agent), TOPIC)
        result.files[agent] = []
        for entry in manifest.files:
            try:
                _fetch_file(
                    fetch, key, run_id, entry, manifest.chunk_size, out, timeout, retries, result
                )
                result.files[agent].append(entry.name)
                progress(f"{agent}: {entry.name} ({entry.size} bytes)")
            except CollectError as error:
                result.errors.append(str(error))
        stem = recording_stem(agent)
        if incomplete_name(stem) in result.files[agent]:
            result.incomplete[agent] = _incomplete(out / incomplete_name(stem))
        (out / manifest_name(stem)).write_text(
            manifest.model_dump_json(indent=1) + "\n", encoding="utf-8"
        )
    return result


def _incomplete(path: Path) -> str:
    """What an agent's ``incomplete.json`` says, as one line."""
    try:
        return describe_incomplete(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError) as error:
        return f"its recording is incomplete ({path.name} unreadable: {error})"


def _manifest_problem(
    reply: Fetched, federation: str, run_id: str, seen: dict[str, Manifest]
) -> str | None:
    """Why a manifest reply is not taken, or None: it must validate, name an agent, come
    from that agent's key (one lab's agent cannot speak for another's run), list only
    that agent's files (``<lab>-<name>.*``: they share one folder) and be the only one
    for that agent."""
    try:
        manifest = Manifest.model_validate_json(reply.payload)
        agent = keys.AgentId.parse(manifest.agent)
    except (ValidationError, ValueError) as problem:
        text = problem.errors()[0]["msg"] if isinstance(problem, ValidationError) else problem
        return f"a malformed manifest: {text}"
    if reply.key is not None:
        parsed = keys.parse_agent_key(federation, reply.key)
        if parsed is None or parsed[0] != agent:
            return f"a manifest for {agent} sent on {reply.key}: not taken"
    stem = f"{agent.lab}-{agent.name}."
    foreign = [f.name for f in manifest.files if not f.name.startswith(stem)]
    if foreign:
        return f"{agent}'s manifest lists files not its own ({', '.join(foreign)}): not taken"
    if manifest.run_id == run_id and str(agent) in seen:
        return f"two manifests for {agent}: neither is more genuine; the first was kept"
    return None


def _fetch_file(
    fetch: Fetch,
    key: str,
    run_id: str,
    entry: FileEntry,
    chunk: int,
    out: Path,
    timeout: float,
    retries: int,
    result: CollectResult,
    window: int = WINDOW,
) -> None:
    target = out / entry.name
    if (
        target.exists()
        and target.stat().st_size == entry.size
        and sha256_file(target) == entry.sha256
    ):
        result.skipped.append(entry.name)
        return
    part = out / f"{entry.name}.part"
    offset = resume_offset(part.stat().st_size if part.exists() else 0, entry.size, chunk)
    digest = hashlib.sha256()
    with part.open("r+b" if part.exists() else "w+b") as f:
        if offset:
            result.resumed.append(entry.name)
            f.seek(0)
            remaining = offset
            while remaining:  # the digest of what is already here
                data = f.read(min(chunk, remaining))
                digest.update(data)
                remaining -= len(data)
        f.seek(offset)
        f.truncate(offset)
        # A window of requests in flight (the path's round trip, not one per chunk), each
        # chunk written in order as it comes: at most ``window`` chunks in memory.
        offsets = iter(range(offset, entry.size, chunk))
        with ThreadPoolExecutor(max_workers=window, thread_name_prefix="collect") as pool:
            pending: deque[Future[bytes]] = deque()

            def submit() -> None:
                at = next(offsets, None)
                if at is not None:
                    length = min(chunk, entry.size - at)
                    pending.append(
                        pool.submit(
                            _fetch_chunk,
                            fetch,
                            key,
                            run_id,
                            entry.name,
                            at,
                            length,
                            timeout,
                            retries,
                            result,
                        )
                    )

            for _ in range(window):
                submit()
            try:
                while pending:
                    data = pending.popleft().result()
                    f.write(data)
                    digest.update(data)
                    result.bytes_fetched += len(data)
                    submit()
            finally:
                for future in pending:
                    future.cancel()
    if digest.hexdigest() != entry.sha256:
        part.unlink()
        raise CollectError(
            f"{key}: {entry.name}: SHA-256 of the whole file does not match the manifest; "
            "partial download removed, collect again"
        )
    os.replace(part, target)


def _fetch_chunk(
    fetch: Fetch,
    key: str,
    run_id: str,
    name: str,
    offset: int,
    length: int,
    timeout: float,
    retries: int,
    result: CollectResult,
) -> bytes:
    parameters = format_request(ChunkRequest(run_id, name, offset, length))
    problem = "no reply"
    for _ in range(retries + 1):
        replies = fetch(key, parameters, timeout)
        good = [(r.payload, r.attachment) for r in replies if r.error is None]
        errors = [r.error for r in replies if r.error is not None]
        if not good:
            problem = errors[0] if errors else f"no reply within {timeout:g} s"
            result.count("error reply" if errors else "no reply")
            if any(e.startswith("busy") for e in errors):
                time.sleep(BUSY_BACKOFF)  # not at once again: it said why
            continue
        data, attachment = good[0]
        problem_or_none = check_chunk(data, attachment, offset, length)
        if problem_or_none is None:
            return data
        problem = problem_or_none
        result.count(problem)
        log.warning("%s: %s at %d: %s; fetching it again", key, name, offset, problem)
    raise CollectError(
        f"{key}: {name}: chunk at byte {offset} failed {retries + 1} times (last: {problem})"
    )


def describe(result: CollectResult) -> dict[str, Any]:
    """A collection's result as JSON-ready data."""
    return {
        "run_id": result.run_id,
        "out": str(result.out),
        "files": result.files,
        "refetched": result.refetched,
        "resumed": result.resumed,
        "skipped": result.skipped,
        "missing": result.missing,
        "errors": result.errors,
        "incomplete": result.incomplete,
        "bytes_fetched": result.bytes_fetched,
        "ok": result.ok,
    }
