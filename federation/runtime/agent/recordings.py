"""An agent's recordings: the ``--record`` file, each run's recording under
``runs_dir``, and the set of channels recorded now (read on every message, so that
callbacks build no message for a channel nobody records)."""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from federation.core.channels import Channel, segment_stem
from federation.core.counters import Count
from federation.runtime.collect import manifest_name
from federation.runtime.recorder import Message, Recorder
from federation.runtime.runs import PROMISES, RunRecording, recording_budget
from schemas.config import AgentConfig

__all__ = ["Recordings"]

log = logging.getLogger("fedlab.agent")


class Recordings:
    """The recordings of one agent (``me``, ``LAB/NAME``) configured by ``config``.

    ``--record FILE`` records everything the agent sees for as long as it runs, within
    a budget of the disk it writes (a symlinked file's target's), promised in the
    host's ledger (:data:`~federation.runtime.runs.PROMISES`) so that agents in other
    processes share the free space; ``runs_dir`` records each run started by ctl into
    ``runs_dir/<run-id>/``, unless ``--record`` records everything.
    """

    def __init__(self, config: AgentConfig, me: str):
        self.config = config
        self.me = me
        self.recorder: Recorder | None = None
        if config.record:  # a peer publishing far too fast fills no disk here either
            config.record.parent.mkdir(parents=True, exist_ok=True)
            where = config.record.resolve().parent  # the disk written: the target's
            where.mkdir(parents=True, exist_ok=True)  # a link to a folder not yet made
            _, budget = recording_budget(where, config.record_max_mb, self)
            try:
                self.recorder = Recorder(
                    config.record, me, config.record_channels, max_bytes=budget
                )
            except BaseException:  # no recording: nothing promised (to any process)
                PROMISES.give_back(where, self)
                raise
        self.run: RunRecording | None = None  # this run's, under runs_dir
        self.finishing: list[threading.Thread] = []  # recordings finishing after a close
        self._recorded: frozenset[str] = frozenset()
        self._update_recorded()

    def recording(self, topic: Channel) -> bool:
        """Whether ``topic`` is recorded: callbacks build no message otherwise."""
        return topic in self._recorded

    @property
    def recorded(self) -> frozenset[str]:
        """The channels recorded now (the file's and the run's)."""
        return self._recorded

    def _update_recorded(self) -> None:
        channels: set[str] = set()
        if self.recorder is not None:
            channels |= self.recorder.channels
        if self.run is not None:
            channels |= self.run.recorder.channels
        self._recorded = frozenset(channels)

    def record(self, topic: Channel, message: Message) -> None:
        """Record ``message`` (a dict, its JSON encoded, or one shared by several
        recordings) on every recording open."""
        recorder = self.recorder  # read once: close() may clear it on another thread
        if recorder is not None:
            recorder.record(topic, message)
        run = self.run
        if run is not None:
            run.record(topic, message)

    def begin_run(self, run_id: str | None, settings: dict[str, object]) -> None:
        """A recording of the run just armed under runs_dir (unless --record records
        all); the same run armed again keeps its recording."""
        cfg = self.config
        if cfg.runs_dir is None or self.recorder is not None or run_id is None:
            return
        current = self.run
        if current is not None and current.run_id == run_id:
            return
        self.end_run()
        try:
            self.run = RunRecording(
                cfg.runs_dir, run_id, self.me, cfg.record_channels, cfg.model_dump_json(),
                cfg.experiment, settings, cfg.record_max_mb, cfg.record_min_free_mb,
            )  # fmt: skip
            self._update_recorded()
        except OSError as error:
            log.error("cannot record run %s under %s: %s", run_id, cfg.runs_dir, error)

    def begin_segment(self, run_id: str | None, settings: dict[str, object]) -> None:
        """A recording of the run just rejoined under runs_dir, as its next segment (the
        files of the segments before it, this agent's before a restart, are kept)."""
        cfg = self.config
        if cfg.runs_dir is None or self.recorder is not None or run_id is None:
            return
        self.end_run()
        folder = Path(cfg.runs_dir) / run_id
        segment = 2
        while any(
            (folder / f"{segment_stem(self.me, segment)}{ext}").exists()
            for ext in (".mcap", ".mcap.partial", ".jsonl")
        ):
            segment += 1
        try:
            self.run = RunRecording(
                cfg.runs_dir, run_id, self.me, cfg.record_channels, cfg.model_dump_json(),
                cfg.experiment, settings | {"segment": segment}, cfg.record_max_mb,
                cfg.record_min_free_mb, segment=segment,
            )  # fmt: skip
            self._update_recorded()
        except OSError as error:
            log.error("cannot record run %s under %s: %s", run_id, cfg.runs_dir, error)

    def end_run(self, wait: bool = False) -> threading.Thread | None:
        """Finish this run's recording (on a thread; ``wait``: joined); the thread."""
        run, self.run = self.run, None
        self._update_recorded()
        return None if run is None else run.finish(wait=wait)

    def recorded_before(self, run_id: str | None) -> str | None:
        """Why a start of ``run_id`` must be refused: its run is recorded on this host
        already (a run id used again would truncate a finished recording its manifest
        still lists)."""
        runs_dir = self.config.runs_dir
        if runs_dir is None or run_id is None:
            return None
        current = self.run
        if current is not None and current.run_id == run_id:
            return None  # this run, armed again
        folder = Path(runs_dir) / run_id
        lab, name = self.me.split("/", 1)
        stem = f"{lab}-{name}"
        recorded = (f"{stem}.mcap", f"{stem}.mcap.partial", manifest_name(stem))
        if any((folder / name).exists() for name in recorded):  # .partial: being recovered
            return f"run {run_id} is recorded here already ({folder}): start another run id"
        return None

    def counters(self) -> dict[Count, int]:
        """What this run's recording left out (its budget, a full queue, write errors)."""
        run = self.run
        if run is None:
            return {}
        report = run.recorder.report()
        return {
            Count.RECORDING_DROPPED_OVER_BUDGET: report["dropped_over_budget"],
            Count.RECORDING_DROPPED_QUEUE_FULL: report["dropped_queue_full"],
            Count.RECORDING_WRITE_ERRORS: report["write_errors"],
        }

    def status_line(self, line: str) -> bool:
        """Append a status line to the run's recording; False if it could not be."""
        run = self.run
        return run is None or run.status_line(line)

    def close(self, wait: bool = True) -> None:
        """Finish the run's recording (``wait``: here; else on :attr:`finishing`) and
        close the ``--record`` file, giving its promise back."""
        finishing = self.end_run(wait=wait)
        if finishing is not None:
            self.finishing.append(finishing)

    def close_file(self) -> None:
        """Close the ``--record`` file, giving its promise back."""
        if self.recorder is not None:
            try:
                self.recorder.close()
            finally:
                PROMISES.give_back(self.recorder.path.parent, self)
            self.recorder = None
            self._update_recorded()
