"""One run's recording on an agent's host: ``<runs_dir>/<run-id>/<lab>-<name>.*``.

An agent in an experiment opens a :class:`RunRecording` when a start arms a run:
an MCAP file (every channel, with the run's metadata inside: experiment file,
agent configuration, fedlab and Zenoh versions, git commit, host, UTC start,
command line) and its status lines (``.jsonl``). When the run is done or
aborted (or the agent stops) :meth:`RunRecording.finish` closes both and writes
the manifest :mod:`federation.runtime.collect` serves, on a thread of its own so
the agent's loop never waits for the disk.
"""

from __future__ import annotations

import datetime
import json
import logging
import platform as host_platform
import socket
import subprocess
import sys
import threading
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import IO, Any

from federation.core.channels import Channel
from federation.runtime.collect import finalize
from federation.runtime.recorder import Message, Recorder

__all__ = ["RunRecording", "software_versions"]

log = logging.getLogger("fedlab.runs")

METADATA = "fedlab.run"
"""Name of the MCAP metadata record holding a run's description."""


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


class RunRecording:
    """An agent's recording of one run; ``record`` and ``status_line`` until ``finish``."""

    def __init__(
        self,
        runs_dir: Path,
        run_id: str,
        agent: str,
        channels: list[Channel] | None,
        config_json: str,
        experiment: Path | None,
        extra: dict[str, Any] | None = None,
    ):
        self.run_id = run_id
        self.agent = agent
        self.dir = Path(runs_dir) / run_id
        self.dir.mkdir(parents=True, exist_ok=True)
        stem = agent.replace("/", "-")
        self.mcap = self.dir / f"{stem}.mcap"
        self.status = self.dir / f"{stem}.jsonl"
        self.recorder = Recorder(self.mcap, agent, channels)
        self._status_file: IO[str] | None = self.status.open("a", encoding="utf-8")
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
            **software_versions(),
            **{k: json.dumps(v) if not isinstance(v, str) else v for k, v in (extra or {}).items()},
        }
        self.recorder.add_metadata(METADATA, self.metadata)
        self._finished = False

    def record(self, topic: str, message: Message) -> None:
        self.recorder.record(topic, message)

    def status_line(self, line: str) -> bool:
        """Append a status line; False if it could not be written (a full disk: counted,
        never raised into the agent's loop, where co-hosted agents had all stopped)."""
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
                self.recorder.close()
                if status_file is not None:
                    status_file.close()
                finalize(self.dir, self.agent, self.run_id, [self.mcap, self.status])
                log.info("run %s finalized in %s", self.run_id, self.dir)
            except Exception:
                log.exception("finalizing run %s in %s failed", self.run_id, self.dir)

        thread = threading.Thread(target=work, name="run-finish", daemon=False)
        thread.start()
        if wait:
            thread.join(30)
        return thread
