"""``fedlab bench scale``'s arguments are checked before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.bench import scale
from federation.cli import main
from schemas.config import ConfigError


def test_a_group_of_no_agents_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="groups of 0"):
        scale.run_one(4, 1.0, tmp_path, group=0)


def test_the_cli_refuses_a_group_of_no_agents(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "scale", "--group", "0"])
    assert exit_.value.code == 2
    assert "--group" in capsys.readouterr().err


def test_repeats_interleave_counts_and_modes_and_report_progress(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ran: list[tuple[int, str, int, bool, float]] = []

    def fake_run_one(
        n: int, seconds: float, out: Path, mode: str, labs: int, group: int, pin_routers: bool,
        settle: float,
    ) -> dict[str, object]:  # fmt: skip
        ran.append((n, mode, group, pin_routers, settle))
        return {"n": n, "mode": mode}

    monkeypatch.setattr(scale, "run_one", fake_run_one)
    seen: list[tuple[int, int, str]] = []
    rows = scale.run([2, 4], 1.0, tmp_path, ("default", "bare"), runs=2, group=3,
                     progress=lambda k, n, mode: seen.append((k, n, mode)))  # fmt: skip
    order = [(k, n, m) for k in range(2) for n in (2, 4) for m in ("default", "bare")]
    assert seen == order  # each repeat runs every count and mode before the next
    assert [(r["run"], r["n"], r["mode"]) for r in rows] == order
    assert {(g, pin, settle) for _, _, g, pin, settle in ran} == {(3, False, scale.SETTLE)}
    ran.clear()
    scale.run([2], 1.0, tmp_path, ("default", "bare"), pin_routers=True, settle=1.5)
    # fedlab and the floor on the same hosting, settling alike
    assert [(pin, settle) for *_, pin, settle in ran] == [(True, 1.5), (True, 1.5)]


def test_routers_get_the_first_core_and_workers_the_others(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(scale, "usable_cpus", lambda: frozenset({5, 2, 7}))
    assert scale.hosting_cores() == ({2}, {5, 7})
    monkeypatch.setattr(scale, "usable_cpus", lambda: frozenset({3}))
    with pytest.raises(ConfigError, match=r"--pin-routers: .* may use only 3"):
        scale.hosting_cores()


def test_pinning_on_one_core_is_refused_before_anything_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(scale, "usable_cpus", lambda: frozenset({0}))
    with pytest.raises(ConfigError, match="--pin-routers"):
        scale.run_one(4, 1.0, tmp_path, pin_routers=True)
    assert not list(tmp_path.iterdir())  # no run folder, no process


def test_one_lab_is_a_lab_count_and_none_is_refused(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # One lab: one router and one worker hosting every agent (not "a leader and a follower").
    labs: list[int] = []

    def fake_run(
        counts: list[int],
        seconds: float,
        out: Path,
        modes: tuple[str, ...],
        labs_: int,
        *rest: object,
    ) -> list[dict[str, object]]:
        labs.append(labs_)
        return []

    monkeypatch.setattr(scale, "run", fake_run)
    main(["bench", "scale", "--agents", "4", "--labs", "1", "--json"])
    assert labs == [1]
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "scale", "--labs", "0"])
    assert exit_.value.code == 2
    assert "--labs: at least 1" in capsys.readouterr().err
