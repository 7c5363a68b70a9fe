"""One run's recording on an agent's host: ``<runs_dir>/<run-id>/<lab>-<name>.*``.

An agent in an experiment opens a :class:`RunRecording` when a start arms a run:
an MCAP file (every channel, with the run's metadata inside: experiment file,
agent configuration, fedlab and Zenoh versions, git commit, host, UTC start,
command line) and its status lines (``.jsonl``). When the run is done or
aborted (or the agent stops) :meth:`RunRecording.finish` closes both and writes
the manifest :mod:`federation.runtime.collect` serves, on a thread of its own so
the agent's loop never waits for the disk.

Nothing a peer sends can fill the disk: a run's MCAP stops at ``record_max_mb``, or
at half the space its filesystem had free when the run was armed, whichever is
less (then it is finished as usual, marked truncated: ``<lab>-<name>.incomplete.json``
beside it). What was already promised to the recordings still open on that filesystem,
by this process or any other of the host's (:class:`_Promises`' ledger), counts as
taken: agents hosted together (``fedlab host``), or each in a process of its own, are
not each given half of the same free space. A filesystem with less than
``record_min_free_mb`` free fails preflight (:func:`low_space`: ``ready.recording``
false, so ``fedlab ctl start`` starts nothing unless ``--force``); a run armed all the
same is recorded, with an error logged and ``low_space`` in its metadata: a run flown
unrecorded would be worse, and the start was given for every lab, not only this one.
"""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import logging
import os
import platform as host_platform
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import IO, Any

from federation.core.channels import Channel, segment_stem
from federation.runtime.collect import finalize, free_bytes, write_incomplete
from federation.runtime.recorder import Message, Recorder, is_finished
from schemas.config import AgentConfig

__all__ = ["RunRecording", "free_bytes", "low_space", "software_versions", "space_problem"]

log = logging.getLogger("fedlab.runs")

METADATA = "fedlab.run"
"""Name of the MCAP metadata record holding a run's description."""
MIB = 1 << 20
SPACE_CHECK_PERIOD = 5.0
"""s a free-space look is reused for: status asks every period, the disk need not answer."""
_space_checks: dict[tuple[Path, int], tuple[float, str | None]] = {}


def space_problem(where: Path, free: int | None, min_free_mb: int) -> str | None:
    """Why ``where`` is too full to record a run (``free`` bytes, under the
    ``min_free_mb`` MiB floor), or None."""
    if free is None or free >= min_free_mb * MIB:
        return None
    return (
        f"{where}: {free / MIB:.0f} MiB free, under record_min_free_mb ({min_free_mb} MiB): "
        "free some space or lower the floor"
    )


def low_space(config: AgentConfig, now: float | None = None) -> str | None:
    """Why the agent's runs_dir is too full to record its next run, or None (no runs_dir,
    or room enough); looked at once per ``SPACE_CHECK_PERIOD`` at most (host monotonic
    ``now``, default: the clock)."""
    if config.runs_dir is None or config.record_min_free_mb == 0:
        return None
    now = time.monotonic() if now is None else now
    key = (Path(config.runs_dir), config.record_min_free_mb)
    seen = _space_checks.get(key)
    if seen is not None and now - seen[0] < SPACE_CHECK_PERIOD:
        return seen[1]
    problem = space_problem(key[0], free_bytes(key[0]), key[1])
    _space_checks[key] = (now, problem)
    return problem


def _version(package: str) -> str:
    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"


@cache
def software_versions() -> dict[str, str]:
    """fedlab's and Zenoh's versions, Python's, and the git commit of fedlab's source
    (empty when it is not a git checkout)."""
    source = Path(__file__).resolve().parents[2]
    commit = ""
    try:
        done = subprocess.run(
            ["git", "-C", str(source), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=2, check=False, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        if done.returncode == 0:
            commit = done.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return {
        "fedlab_version": _version("fedlab"),
        "zenoh_version": _version("eclipse-zenoh"),
        "python_version": host_platform.python_version(),
        "git_commit": commit,
    }


LEDGER_ENV = "FEDLAB_PROMISES"
"""Environment variable naming the folder of the promises ledger (default: a folder of
this user's in the system's temporary folder)."""


def ledger_dir() -> Path:
    """The folder where every fedlab process of this user on this host writes what it
    has promised recordings: one folder per filesystem (its device number) inside."""
    named = os.environ.get(LEDGER_ENV)
    if named:
        return Path(named)
    return Path(tempfile.gettempdir()) / f"fedlab-{os.getuid()}-promises"


class _Promises:
    """Bytes promised to the recordings still open, per filesystem: this process's in
    memory, and every process's (this one's too) in a ledger on the host
    (:func:`ledger_dir`), so that agents in processes of their own (one ``fedlab agent``
    per platform) do not each take half of the same free space.

    A promise in the ledger is a file holding its byte count, kept locked (``flock``,
    shared) by its process until given back: a file whose lock nobody holds is a dead
    process's, not counted and removed. Promises are made under the ledger's own lock,
    so two processes arming at once see each other's. A ledger that cannot be written
    (no temporary folder) leaves each process on its own, as before, with a warning."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_device: dict[int, dict[int, int]] = {}
        self._files: dict[int, IO[str]] = {}  # id(who) -> its open, locked ledger file
        self._warned = False

    def take(self, directory: Path, free: int, max_bytes: int | None, who: object) -> int:
        """At most half of what is free and not promised already (and ``max_bytes``);
        promised to ``who`` until :meth:`give_back`."""
        device = directory.stat().st_dev
        with self._lock, self._ledger(device) as ledger:
            promised = self._by_device.setdefault(device, {})
            others = 0 if ledger is None else _others(ledger, set(self._files.values()))
            budget = max(0, free - sum(promised.values()) - others) // 2
            if max_bytes is not None:
                budget = min(budget, max_bytes)
            promised[id(who)] = budget
            if ledger is not None:
                self._write(ledger, id(who), budget)
        return budget

    def promised(self, directory: Path) -> int:
        """Bytes promised to recordings on ``directory``'s filesystem, still open, by
        this process."""
        with self._lock:
            return sum(self._by_device.get(directory.stat().st_dev, {}).values())

    def give_back(self, directory: Path, who: object) -> None:
        with self._lock:
            for promised in self._by_device.values():
                promised.pop(id(who), None)
            entry = self._files.pop(id(who), None)
        if entry is not None:
            with contextlib.suppress(OSError):
                os.unlink(entry.name)
            entry.close()  # its lock goes with it

    @contextlib.contextmanager
    def _ledger(self, device: int) -> Iterator[Path | None]:
        """The ledger folder of filesystem ``device``, locked for this process (None:
        it cannot be used)."""
        top = ledger_dir()
        folder = top / str(device)
        try:
            for where in (top, folder):
                where.mkdir(exist_ok=True, mode=0o700, parents=where is top)
                _check_own_folder(where)
            lock = (folder / ".lock").open("a")
        except OSError as error:
            self._alone(folder, error)
            yield None
            return
        with lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX)
            except OSError as error:  # a filesystem without locks (NFS without lockd)
                self._alone(folder, error)
                yield None
                return
            yield folder

    def _alone(self, folder: Path, error: OSError) -> None:
        """The ledger cannot be used: this process promises on its own (said once)."""
        if not self._warned:
            self._warned = True
            log.warning(
                "recordings' promises not shared with other processes (%s): %s", folder, error
            )

    def _write(self, folder: Path, key: int, budget: int) -> None:
        """``key``'s promise in the ledger, its file kept open and locked."""
        old = self._files.pop(key, None)
        if old is not None:  # promised again (a second take for the same owner)
            with contextlib.suppress(OSError):
                os.unlink(old.name)
            old.close()
        path = folder / f"{os.getpid()}-{key}"
        try:
            entry = path.open("w")
            fcntl.flock(entry, fcntl.LOCK_SH)
            entry.write(str(budget))
            entry.flush()
        except OSError as error:
            log.warning("recording's promise not written to %s: %s", path, error)
            return
        self._files[key] = entry


def _check_own_folder(where: Path) -> None:
    """Raise unless ``where`` is a folder (not a link to one) of this user's that no one
    else may write: another user of the host could otherwise make it first, or link it
    to a folder of theirs, and plant promises that leave every recording no space."""
    seen = os.lstat(where)
    if not stat.S_ISDIR(seen.st_mode):
        raise NotADirectoryError(f"{where} is not a folder (a link, or a file)")
    if seen.st_uid != os.getuid():
        raise PermissionError(f"{where} belongs to another user")
    if seen.st_mode & 0o022:
        raise PermissionError(f"{where} may be written by other users")


def _others(folder: Path, mine: set[IO[str]]) -> int:
    """Bytes the live promises in ``folder`` hold, but for this process's files
    (``mine``, counted in memory); dead processes' files are removed."""
    held = {Path(entry.name).name for entry in mine}
    total = 0
    for path in folder.iterdir():
        if path.name.startswith(".") or path.name in held:
            continue
        try:
            with path.open("r") as entry:
                try:
                    fcntl.flock(entry, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:  # held: a live process's
                    text = entry.read()
                else:  # nobody holds it: its process ended without giving it back
                    path.unlink(missing_ok=True)
                    continue
        except OSError:
            continue
        try:
            total += max(0, int(text))
        except ValueError:  # being written as we read (it is locked first): counted next time
            continue
    return total


PROMISES = _Promises()


def recording_budget(
    directory: Path, max_mb: int | None, who: object
) -> tuple[int | None, int | None]:
    """The space free in ``directory`` (None if unknown) and the bytes a recording there
    may take: ``max_mb`` MiB at most, and half of what is free and not promised to
    other recordings of this process; promised to ``who`` until
    ``PROMISES.give_back(directory, who)``."""
    free = free_bytes(directory)
    max_bytes = None if max_mb is None else max_mb * MIB
    if free is not None:  # the rest for the host (its logs, the other agents' runs)
        max_bytes = PROMISES.take(directory, free, max_bytes, who)
    return free, max_bytes


class RunRecording:
    """An agent's recording of one run; ``record`` and ``status_line`` until ``finish``.
    Its MCAP takes at most ``max_mb`` MiB (None: no limit of its own) and at most half
    the space free when it starts; under ``min_free_mb`` MiB free, an error is logged.
    ``segment`` 2, 3...: the part of the run flown after a rejoin, in files of its own
    (``<lab>-<name>.seg2.mcap``) listed in the run's one manifest."""

    def __init__(
        self,
        runs_dir: Path,
        run_id: str,
        agent: str,
        channels: list[Channel] | None,
        config_json: str,
        experiment: Path | None,
        extra: dict[str, Any] | None = None,
        max_mb: int | None = None,
        min_free_mb: int = 0,
        segment: int = 1,
    ):
        self.run_id = run_id
        self.agent = agent
        self.dir = Path(runs_dir) / run_id
        self.dir.mkdir(parents=True, exist_ok=True)
        self.segment = segment
        self.stem = stem = segment_stem(agent, segment)
        self.mcap = self.dir / f"{stem}.mcap"
        self.status = self.dir / f"{stem}.jsonl"
        free, self.max_bytes = recording_budget(self.dir, max_mb, self)
        self.low_space = space_problem(self.dir, free, min_free_mb)
        if self.low_space is not None:
            log.error(
                "run %s: %s; recorded all the same, in at most %d MiB (half of what is free)",
                run_id, self.low_space, (self.max_bytes or 0) // MIB,
            )  # fmt: skip
        try:
            self.recorder = Recorder(self.mcap, agent, channels, max_bytes=self.max_bytes)
        except BaseException:
            PROMISES.give_back(self.dir, self)  # no recording: nothing promised
            raise
        self._status_file: IO[str] | None = None
        try:
            self._status_file = self.status.open("a", encoding="utf-8")
            self._start(run_id, agent, experiment, config_json, free, extra)
        except BaseException as error:  # no run after all: nothing open, nothing promised
            self._not_recorded(error)
            raise

    def _not_recorded(self, error: BaseException) -> None:
        """A start that failed: its files closed and said not to be the run's recording
        (else the next start's recovery would collect its finished, empty MCAP as the
        run's, complete), its space given back."""
        if self._status_file is not None:
            with contextlib.suppress(Exception):
                self._status_file.close()
        with contextlib.suppress(Exception):
            self.recorder.close()
        PROMISES.give_back(self.dir, self)
        try:
            what = {"not_recorded": f"the run's recording could not start: {error}"}
            write_incomplete(self.dir, self.agent, self.run_id, what, self.stem)
        except OSError:  # the disk said no: take away what would pass for a recording
            for path in (self.mcap, self.status):
                with contextlib.suppress(OSError):
                    path.unlink()

    def _start(
        self,
        run_id: str,
        agent: str,
        experiment: Path | None,
        config_json: str,
        free: int | None,
        extra: dict[str, Any] | None,
    ) -> None:
        self._status_lock = threading.Lock()
        self.status_write_errors = 0
        experiment_text = ""
        if experiment is not None:
            try:
                experiment_text = Path(experiment).read_text(encoding="utf-8")
            except OSError as error:
                experiment_text = f"unreadable: {error}"
        self.metadata = {
            "run_id": run_id,
            "agent": agent,
            "utc_start": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "host": socket.gethostname(),
            "experiment_file": "" if experiment is None else str(experiment),
            "experiment": experiment_text,
            "agent_config": config_json,
            "command_line": " ".join(["fedlab", *sys.argv[1:]]) if sys.argv else "",
            "record_max_bytes": "" if self.max_bytes is None else str(self.max_bytes),
            "free_bytes": "" if free is None else str(free),
            "low_space": self.low_space or "",
            **software_versions(),
            **{k: json.dumps(v) if not isinstance(v, str) else v for k, v in (extra or {}).items()},
        }
        self.recorder.add_metadata(METADATA, self.metadata)
        self._finished = False

    def record(self, topic: str, message: Message) -> None:
        self.recorder.record(topic, message)

    def status_line(self, line: str) -> bool:
        """Append a status line; False if it could not be written (a full disk: counted,
        never raised into the agent's loop, where it would stop every co-hosted agent)."""
        with self._status_lock:  # finish() closes the file on another thread
            status_file = self._status_file
            if status_file is None:
                return True
            try:
                status_file.write(line + "\n")
                status_file.flush()
            except (OSError, ValueError) as error:
                self.status_write_errors += 1
                if self.status_write_errors == 1:
                    log.error(
                        "run %s: status not written to %s: %s", self.run_id, self.status, error
                    )
                return False
        return True

    def finish(self, wait: bool = False) -> threading.Thread | None:
        """Close the files and write the manifest (on a thread; ``wait``: join it)."""
        if self._finished:
            return None
        self._finished = True
        with self._status_lock:
            status_file, self._status_file = self._status_file, None

        def work() -> None:
            try:
                recorder = self.recorder
                try:
                    recorder.close()
                except Exception:  # a write failed (counted in its report)
                    if not is_finished(self.mcap):  # cut: the next start recovers it
                        raise
                    log.exception("run %s: a write to %s failed", self.run_id, self.mcap)
                finally:
                    PROMISES.give_back(self.dir, self)
                    if status_file is not None:
                        try:  # on disk before the manifest names it
                            status_file.flush()
                            os.fsync(status_file.fileno())
                        except (OSError, ValueError) as error:
                            self.status_write_errors += 1
                            log.error("run %s: %s not on disk: %s", self.run_id, self.status, error)
                        status_file.close()
                files = [self.mcap, self.status]
                if not recorder.complete or self.status_write_errors:  # said beside it
                    what = recorder.report() | {"status_write_errors": self.status_write_errors}
                    files.append(
                        write_incomplete(self.dir, self.agent, self.run_id, what, self.stem)
                    )
                finalize(self.dir, self.agent, self.run_id, files)
                log.info("run %s finalized in %s", self.run_id, self.dir)
            except Exception:
                log.exception("finalizing run %s in %s failed", self.run_id, self.dir)

        thread = threading.Thread(target=work, name="run-finish", daemon=False)
        thread.start()
        if wait:
            thread.join(30)
        return thread
