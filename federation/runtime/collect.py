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

A run its agent never finalized is recovered when the agent starts again, on a
thread of the :class:`RecordingServer` (:mod:`federation.runtime.runfolder`, which
writes manifests and recovers runs; its names are importable from here too). A
recording that is not whole (recovered, or truncated at its size limit) has
``<lab>-<name>.incomplete.json`` beside it, listed in its manifest: what is missing
and why; :func:`collect` reports it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

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
from federation.runtime.runfolder import (
    Deferred,
    Recovery,
    describe_incomplete,
    finalize,
    free_bytes,
    incomplete_name,
    manifest_name,
    recover_run,
    recover_runs,
    sha256_file,
    unfinished_runs,
    write_incomplete,
)
from federation.runtime.session import ConnectError
from schemas.config import AgentConfig
from schemas.messages import FileEntry, Manifest

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
DEFAULT_MIN_FREE_MB: int = AgentConfig.model_fields["record_min_free_mb"].default
RECOVERY_RETRY = 1.0
"""s between looks at whether the agent's run is over, recoveries waiting for it."""


class CollectError(ConnectionError):
    """A file that could not be collected: which, from whom, and why."""


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
    declined: list[str] = []
    started = time.monotonic()
    manifests = _manifests(fetch, federation, run_id, timeout, result, declined)
    waited = time.monotonic() - started
    result.missing = sorted((expected or set()) - set(manifests))
    if not manifests:
        raise ConnectError(
            nothing_to_collect(federation, run_id, timeout, waited, declined, len(result.errors))
        )
    for agent in sorted(manifests):
        _collect_agent(fetch, federation, manifests[agent], timeout, retries, result, progress)
    return result


def nothing_to_collect(
    federation: str,
    run_id: str,
    timeout: float,
    waited: float,
    declined: list[str],
    not_taken: int = 0,
) -> str:
    """Why a collection found no manifest of ``run_id``: what it asked, how long it
    waited (a query ends as soon as every agent reachable has answered), and what the
    agents that answered said (``declined``: their error replies)."""
    asked = keys.all_of(federation, TOPIC)
    head = f"no agent of federation {federation!r} has a finished run {run_id!r}"
    if not_taken:
        head += f" that could be taken ({not_taken} manifest(s) refused, printed above)"
    if declined:
        # What agents sent: shown, never run by the terminal, and short.
        said = ["".join(c if c.isprintable() else "\ufffd" for c in d[:200]) for d in declined]
        shown = "; ".join(said[:10]) + ("; ..." if len(said) > 10 else "")
        return (
            f"{head}: asked {asked}; {len(declined)} agent(s) answered in {waited:.3f} s, "
            f"none has it ({shown})"
        )
    if waited < timeout:
        return (
            f"{head}: asked {asked}; no agent answered, and the query ended after "
            f"{waited:.3f} s: no agent that records runs (--experiment or --runs-dir) "
            "is reachable"
        )
    return f"{head}: asked {asked}; no answer within {timeout:g} s"


def _manifests(
    fetch: Fetch,
    federation: str,
    run_id: str,
    timeout: float,
    result: CollectResult,
    declined: list[str],
) -> dict[str, Manifest]:
    """Every agent's manifest of ``run_id``, by agent, from one query to all of them;
    the replies not taken are ``result``'s errors (:func:`_manifest_problem`), the
    error replies (no such run, busy) are appended to ``declined``."""
    manifests: dict[str, Manifest] = {}
    for reply in fetch(
        keys.all_of(federation, TOPIC), format_request(ChunkRequest(run_id)), timeout
    ):
        if reply.error is not None:
            log.debug("manifest query: %s", reply.error)
            declined.append(reply.error)
            continue
        problem = _manifest_problem(reply, federation, run_id, manifests)
        if problem is not None:
            result.errors.append(problem)
            continue
        manifest = Manifest.model_validate_json(reply.payload)
        if manifest.run_id == run_id:
            manifests[manifest.agent] = manifest
    return manifests


def _collect_agent(
    fetch: Fetch,
    federation: str,
    manifest: Manifest,
    timeout: float,
    retries: int,
    result: CollectResult,
    progress: Callable[[str], None],
) -> None:
    """Fetch the files of one agent's ``manifest`` into ``result.out`` (a file that
    fails is ``result``'s error, and the next is fetched), then write the manifest."""
    agent, out = manifest.agent, result.out
    key = keys.agent_key(federation, keys.AgentId.parse(agent), TOPIC)
    result.files[agent] = []
    for entry in manifest.files:
        try:
            _fetch_file(
                fetch, key, result.run_id, entry, manifest.chunk_size, out, timeout, retries,
                result,
            )  # fmt: skip
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
