"""fedlab demo's progress (federation/fleet/progress.py): a line per phase and the run's
time with what is left, plain where there is no terminal; and the run.json identity
that names a demo run in its summary."""

from __future__ import annotations

import io

from rich.console import Console

from federation.fleet.demo import run_identity
from federation.fleet.progress import DemoProgress, run_line


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_the_run_line_says_run_time_total_and_what_is_left() -> None:
    assert run_line(20.4, 77.0) == "run 20 / 77 s, about 57 s left"
    assert run_line(80.0, 77.0) == "run 80 / 77 s, about 0 s left"


def test_off_a_terminal_each_phase_and_the_run_every_10_s_are_plain_lines() -> None:
    out, clock = io.StringIO(), FakeClock()
    progress = DemoProgress(Console(file=out, width=200), clock=clock)
    assert not progress.live
    progress.phase("starting routers [and] the lab link")  # never read as markup
    clock.now += 6.5
    for elapsed in (0.0, 0.5, 9.9, 10.0, 12.0, 20.1):
        progress.run(elapsed, 77.0)
    clock.now += 70.0
    progress.phase("writing the report")
    assert out.getvalue().splitlines() == [
        "[   0.0 s] starting routers [and] the lab link",
        "[   6.5 s] run 0 / 77 s, about 77 s left",
        "[   6.5 s] run 10 / 77 s, about 67 s left",
        "[   6.5 s] run 20 / 77 s, about 57 s left",
        "[  76.5 s] writing the report",
    ]
    assert "\x1b" not in out.getvalue()


def test_on_a_terminal_a_live_display_shows_the_run_instead() -> None:
    out = io.StringIO()
    progress = DemoProgress(Console(file=out, width=200, force_terminal=True), clock=FakeClock())
    assert progress.live
    progress.run(0.0, 77.0, shown_live=True)
    assert out.getvalue() == ""
    progress.run(0.0, 77.0)  # no live display (the scenario demos): lines still
    progress.phase("stopping")
    text = out.getvalue()
    assert "run 0 / 77 s, about 77 s left" in text and "stopping" in text
    assert "\x1b[" in text  # styled by rich


def test_a_demo_run_is_named_in_its_run_json() -> None:
    identity = run_identity("attitude-tracking-demo", seconds_ahead=2.0)
    assert identity["run_id"].startswith("attitude-tracking-demo-")
    assert identity["run_id"].endswith("Z")
    assert identity["experiment"] == "attitude-tracking-demo"
    assert identity["utc_start"].endswith("+00:00")
    versions = identity["versions"]
    assert versions["fedlab_version"] and versions["zenoh_version"]
    assert versions["python_version"].count(".") == 2
