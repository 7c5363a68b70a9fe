"""``fedlab demo``'s progress: one line per phase (starting routers, agents, syncing,
the run, stopping, the report), each stamped with the seconds since the demo began,
and during the run its run time, its total and about how long is left.

On a terminal the lines are rich's (styled; the attitude demo's live table shows the
run); elsewhere (CI, a pipe) plain lines, the run's every :data:`PLAIN_EVERY` s, so a
log shows where a two-minute demo is.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from rich.console import Console
from rich.markup import escape

__all__ = ["PLAIN_EVERY", "DemoProgress", "run_line"]

PLAIN_EVERY = 10.0
"""s between the run's progress lines when not on a terminal."""


def run_line(elapsed: float, total: float) -> str:
    """The run's progress: ``run 20 / 77 s, about 57 s left``."""
    left = max(0.0, total - elapsed)
    return f"run {elapsed:.0f} / {total:.0f} s, about {left:.0f} s left"


class DemoProgress:
    """Prints the demo's phases to ``console`` (its own clock: ``clock``, monotonic s)."""

    def __init__(
        self,
        console: Console,
        clock: Callable[[], float] = time.monotonic,
        plain_every: float = PLAIN_EVERY,
    ):
        self.console = console
        self.clock = clock
        self.started = clock()
        self.plain_every = plain_every
        self._last_run_line: float | None = None

    @property
    def live(self) -> bool:
        """Whether a live display (redrawn in place) can be shown: on a terminal only."""
        return self.console.is_terminal

    def phase(self, text: str) -> None:
        """A phase begins: ``[  3.2 s] starting agents``."""
        stamp = f"[{self.clock() - self.started:6.1f} s]"
        if self.live:
            self.console.print(
                f"[dim]{escape(stamp)}[/dim] [bold]{escape(text)}[/bold]", highlight=False
            )
        else:
            self.console.print(f"{stamp} {text}", markup=False, highlight=False)

    def run(self, elapsed: float, total: float, shown_live: bool = False) -> None:
        """The run is ``elapsed`` of ``total`` s in: a line every :attr:`plain_every` s
        and at the start, unless a live display shows it (``shown_live``)."""
        if shown_live:
            return
        if self._last_run_line is None or elapsed - self._last_run_line >= self.plain_every:
            self._last_run_line = elapsed
            self.phase(run_line(elapsed, total))
