"""The monitor's table: the pure model (status and liveliness in, rows out), the renderer,
and the ``fedlab monitor`` command line; no processes (the live run is in
tests/integration/test_monitor.py)."""

from __future__ import annotations

import json
from typing import Any

import pytest
from pydantic import ValidationError
from rich.console import Console

from federation import cli
from federation.runtime.monitor import COLUMNS, MonitorModel, Row, fit, render, row_json
from schemas.messages import PeerStatus, Status

LEADER = "kiruna/knatte"
FOLLOWER = "rome/pinocchio"


def main(args: list[str]) -> int:
    """``fedlab monitor ARGS`` in this process."""
    return cli.main(["monitor", *args])


def key(agent: str, topic: str | None = None, federation: str = "default") -> str:
    base = f"fedlab/{federation}/{agent}"
    return f"{base}/{topic}" if topic else base


def peer(offset: float | None, delay: float | None, samples: int = 10, **extra: Any) -> PeerStatus:
    return PeerStatus(offset=offset, delay=delay, samples=samples, rejected=0, **extra)


def status(
    agent: str,
    role: str = "follower",
    reference: str = LEADER,
    peers: dict[str, PeerStatus] | None = None,
    **extra: Any,
) -> bytes:
    """A status as an agent publishes it (built from the schema, so the two stay in step)."""
    line = Status(
        agent=agent,
        federation="default",
        role=role,  # type: ignore[arg-type]
        reference=reference,
        t_exec=12.0,
        host_monotonic=100.0,
        t_sim=38.42,
        pose=[0.0] * 6,
        peers=peers or {},
        **extra,
    )
    return line.model_dump_json().encode()


def leader_status(**extra: Any) -> bytes:
    return status(
        LEADER,
        role="leader",
        peers={
            FOLLOWER: peer(26.42, 0.0005, samples=40),
            "rome/ada": peer(26.0, 0.0009, samples=5),
        },
        **extra,
    )


def follower_status(**extra: Any) -> bytes:
    peers = {LEADER: peer(-26.42, 0.0004, samples=30, rejected_by_reason={})}
    return status(FOLLOWER, peers=peers, **extra)


def by_agent(rows: list[Row]) -> dict[str, Row]:
    return {r.agent: r for r in rows}


# -- model ---------------------------------------------------------------------------
def test_status_in_rows_out() -> None:
    model = MonitorModel()
    model.on_status(
        key(FOLLOWER, "status"),
        follower_status(
            mode="running",
            platform="pinocchio",
            pose_age=0.0123,
            loop={"late_p99_ms": 1.5},
            counters={"pose_malformed": 2, "sync_requests_malformed": 1, "pose_received": 99},
        ),
        now=10.0,
    )
    model.on_status(key(LEADER, "status"), leader_status(), now=10.5)
    rows = model.rows(now=11.0)
    assert [r.agent for r in rows] == [LEADER, FOLLOWER]  # sorted by lab, then name
    leader, follower = rows
    assert follower.lab == "rome" and follower.name == "pinocchio"
    assert (follower.role, follower.mode, follower.platform) == ("follower", "running", "pinocchio")
    assert follower.offset_s == -26.42 and not follower.is_reference
    assert follower.delay_s == 0.0004
    assert follower.pose_age_s == 0.0123
    assert follower.samples == 30
    assert follower.rejected == 3  # sync rejected (0) + the *_malformed counters
    assert follower.late_p99_ms == 1.5
    assert follower.since_status_s == pytest.approx(1.0)
    assert follower.state == "ok"
    # The reference: offset "ref", delay to its farthest peer, samples over every peer.
    assert leader.is_reference and leader.offset_s is None
    assert leader.delay_s == 0.0009
    assert leader.samples == 45
    assert row_json(leader)["offset_s"] == "ref"
    assert row_json(follower)["offset_s"] == -26.42
    json.dumps([row_json(r) for r in rows])  # JSON-ready


def test_rejected_counts_sync_rejections_of_every_peer() -> None:
    model = MonitorModel()
    peers = {
        LEADER: PeerStatus(offset=1.0, delay=0.001, samples=3, rejected=4),
        "rome/ada": PeerStatus(offset=1.0, delay=0.001, samples=3, rejected=5),
    }
    model.on_status(key(FOLLOWER, "status"), status(FOLLOWER, peers=peers), now=0.0)
    (row,) = model.rows(0.0)
    assert row.rejected == 9
    assert row.samples == 3  # only the exchanges with its reference


def test_follower_without_its_reference_yet_shows_nothing_for_it() -> None:
    model = MonitorModel()
    model.on_status(key(FOLLOWER, "status"), status(FOLLOWER), now=0.0)
    (row,) = model.rows(0.0)
    assert row.offset_s is None and row.delay_s is None and row.samples is None
    assert row.role == "follower" and row.state == "ok"


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"not json", "payload"),
        (b"[1, 2]", "payload"),
        (b"", "payload"),
        (b'{"agent": "rome/pinocchio"}', "federation"),
        (b"\xff\xfe\x00", ""),
    ],
)
def test_malformed_status_is_counted_never_raised(payload: bytes, reason: str) -> None:
    model = MonitorModel()
    model.on_status(key(FOLLOWER, "status"), payload, now=1.0)
    assert model.malformed == 1
    assert model.last_error is not None and model.last_error.startswith(key(FOLLOWER, "status"))
    assert reason in model.last_error
    assert model.rows(1.0) == []  # no row from garbage alone


def test_malformed_status_keeps_the_last_good_one() -> None:
    model = MonitorModel()
    model.on_status(key(FOLLOWER, "status"), follower_status(), now=1.0)
    model.on_status(key(FOLLOWER, "status"), b'{"agent": 3}', now=2.0)
    model.on_status(key(FOLLOWER, "status"), json.dumps({"peers": "x"}).encode(), now=2.5)
    (row,) = model.rows(3.0)
    assert model.malformed == 2
    assert row.offset_s == -26.42
    assert row.since_status_s == pytest.approx(2.0)


def test_status_for_another_agent_or_federation_is_malformed() -> None:
    model = MonitorModel()
    model.on_status(key("rome/ada", "status"), follower_status(), now=0.0)  # says pinocchio
    assert model.malformed == 1 and "does not match" in (model.last_error or "")
    other = key(FOLLOWER, "status", federation="other")
    model.on_status(other, follower_status(), now=0.0)
    model.on_status("fedlab/default/ROME/x/status", follower_status(), now=0.0)
    model.on_status("fedlab/default/rome/pinocchio/pose", follower_status(), now=0.0)
    assert model.malformed == 4
    assert model.rows(0.0) == []


def test_oversized_status_is_malformed_without_parsing() -> None:
    model = MonitorModel()
    model.on_status(key(FOLLOWER, "status"), b" " * (2 << 20), now=0.0)
    assert model.malformed == 1 and "bytes" in (model.last_error or "")


def test_liveliness_join_then_leave_marks_left_and_rejoin_revives() -> None:
    model = MonitorModel()
    model.on_liveliness(key(LEADER), alive=True, now=0.0)
    (row,) = model.rows(0.0)
    assert row.state == "waiting" and row.alive and row.role is None
    model.on_status(key(LEADER, "status"), leader_status(), now=1.0)
    assert model.rows(1.5)[0].state == "ok"
    model.on_liveliness(key(LEADER), alive=False, now=2.0)
    (row,) = model.rows(2.5)
    assert row.state == "left" and not row.alive
    assert row.role == "leader"  # its last status is still shown
    # A status that arrives after the token went (a final one in flight) does not revive it.
    model.on_status(key(LEADER, "status"), leader_status(), now=2.6)
    assert model.rows(2.7)[0].state == "left"
    model.on_liveliness(key(LEADER), alive=True, now=3.0)
    assert model.rows(3.0)[0].state == "ok"


def test_liveliness_ignores_other_keys() -> None:
    model = MonitorModel()
    model.on_liveliness(key(LEADER, "pose"), alive=True, now=0.0)
    model.on_liveliness("fedlab/other/kiruna/knatte", alive=True, now=0.0)
    model.on_liveliness("elsewhere", alive=True, now=0.0)
    assert model.rows(0.0) == []
    assert model.malformed == 0


def test_stale_after_injected_time() -> None:
    model = MonitorModel(stale_after=3.0)
    model.on_status(key(FOLLOWER, "status"), follower_status(), now=100.0)
    assert model.rows(103.0)[0].state == "ok"
    row = model.rows(103.5)[0]
    assert row.state == "stale" and row.since_status_s == pytest.approx(3.5)
    model.on_status(key(FOLLOWER, "status"), follower_status(), now=104.0)
    assert model.rows(104.2)[0].state == "ok"


def test_non_finite_numbers_become_unknown() -> None:
    model = MonitorModel()
    payload = json.loads(follower_status())
    payload["pose_age"] = "NaN"
    payload["peers"][LEADER]["offset"] = "Infinity"
    payload["loop"] = {"late_p99_ms": "NaN"}
    model.on_status(key(FOLLOWER, "status"), json.dumps(payload).encode(), now=0.0)
    assert model.malformed == 0
    (row,) = model.rows(0.0)
    assert row.offset_s is None and row.pose_age_s is None and row.late_p99_ms is None
    json.dumps(row_json(row), allow_nan=False)


def test_unknown_fields_are_ignored() -> None:
    model = MonitorModel()
    payload = json.loads(follower_status())
    payload["something_new"] = {"nested": [1, 2]}
    payload["peers"][LEADER]["also_new"] = 1
    model.on_status(key(FOLLOWER, "status"), json.dumps(payload).encode(), now=0.0)
    assert model.malformed == 0 and model.rows(0.0)[0].offset_s == -26.42


def test_other_federation_name() -> None:
    model = MonitorModel("lab-test")
    payload = json.loads(follower_status())
    payload["federation"] = "lab-test"
    model.on_status(key(FOLLOWER, "status", "lab-test"), json.dumps(payload).encode(), now=0.0)
    assert [r.agent for r in model.rows(0.0)] == [FOLLOWER]
    with pytest.raises(ValueError):
        MonitorModel("Bad/Name")


# -- rendering -----------------------------------------------------------------------
def snapshot_text() -> str:
    model = MonitorModel()
    model.on_liveliness(key(LEADER), alive=True, now=0.0)
    model.on_liveliness(key(FOLLOWER), alive=True, now=0.0)
    model.on_liveliness(key("rome/ada"), alive=True, now=0.0)
    model.on_liveliness(key("kiruna/ghost"), alive=True, now=0.0)
    model.on_status(key(LEADER, "status"), leader_status(mode="running"), now=9.8)
    model.on_status(
        key(FOLLOWER, "status"),
        follower_status(
            mode="running", pose_age=0.0412, loop={"late_p99_ms": 0.84}, platform="pinocchio"
        ),
        now=9.5,
    )
    model.on_status(key("rome/ada", "status"), status("rome/ada"), now=2.0)
    model.on_liveliness(key("rome/ada"), alive=False, now=5.0)
    model.on_status(key("kiruna/ghost", "status"), status("kiruna/ghost"), now=5.0)
    model.on_status(key(FOLLOWER, "status"), b"{oops", now=9.9)
    table = render(
        model.rows(10.0),
        federation="default",
        malformed=model.malformed,
        last_error=model.last_error,
    )
    console = Console(record=True, width=200, color_system=None)
    console.print(table)
    return console.export_text()


def test_render_reads_well() -> None:
    text = snapshot_text()
    print(text)
    lab_names = [["kiruna"], ["rome"]]
    assert "fedlab monitor · federation default" in text
    lines = {line.split()[1]: line for line in text.splitlines() if line.split()[:1] in lab_names}
    assert "ref" in lines["knatte"] and "leader" in lines["knatte"]
    assert "-26.420000" in lines["pinocchio"] and "0.40" in lines["pinocchio"]
    assert "41.2" in lines["pinocchio"] and "0.84" in lines["pinocchio"]
    assert "0.5 s" in lines["pinocchio"]
    assert "left" in lines["ada"]
    assert "5.0 s stale" in lines["ghost"]  # marked, and dimmed in colour
    assert "4 agents, 3 present · malformed status: 1" in text
    assert "fedlab/default/rome/pinocchio/status" in text


def test_render_empty_table() -> None:
    console = Console(record=True, width=120, color_system=None)
    console.print(render([], federation="x"))
    assert "0 agents, 0 present · malformed status: 0" in console.export_text()


def test_the_table_says_why_offsets_of_tens_of_seconds_are_expected() -> None:
    console = Console(record=True, width=400, color_system=None)
    console.print(render([], federation="x"))
    text = " ".join(console.export_text().split())
    assert (
        "offset: the reference's clock minus this agent's; each agent's clock starts at an "
        "arbitrary origin, so offsets of tens of seconds, even on one host, are expected"
    ) in text


def test_render_dims_stale_and_left_rows() -> None:
    rows = [
        Row(agent="a/b", lab="a", name="b", state="stale", alive=True, since_status_s=9.0),
        Row(agent="a/c", lab="a", name="c", state="left", alive=False),
        Row(agent="a/d", lab="a", name="d", state="ok", alive=True, since_status_s=0.1),
    ]
    table = render(rows)
    assert [table.rows[i].style for i in range(3)] == ["dim", "dim", None]


def test_fit_leaves_out_optional_columns_on_a_narrow_terminal() -> None:
    model = MonitorModel()
    model.on_status(key(LEADER, "status"), leader_status(), now=0.0)
    model.on_status(key(FOLLOWER, "status"), follower_status(pose_age=0.01), now=0.0)
    rows = model.rows(0.5)
    wide = Console(record=True, width=220, color_system=None)
    assert len(fit(wide, rows).columns) == len(COLUMNS)
    narrow = Console(record=True, width=80, color_system=None)
    table = fit(narrow, rows)
    headers = [str(c.header) for c in table.columns]
    assert "platform" not in headers
    assert headers[:3] == ["lab", "name", "role"] and "offset\ns" in headers
    narrow.print(table)
    text = narrow.export_text()
    assert "pinocchio" in text and "-26.420000" in text and "ref" in text
    assert max(len(line.rstrip()) for line in text.splitlines()) <= 80


# -- command line --------------------------------------------------------------------
def test_help_has_an_example_and_zenoh_flags(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "fedlab monitor" in out
    for flag in ("--connect", "--listen", "--mode", "--cfg", "--federation", "--once", "--json"):
        assert flag in out


def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--federation", "Bad/Name"])
    assert exit_info.value.code == 2
    assert main(["--json"]) == 2
    assert "--json needs --once" in capsys.readouterr().err


def test_rows_show_the_run_its_progress_hold_and_error_bound() -> None:
    model = MonitorModel()
    follower = follower_status(mode="running")
    data = json.loads(follower)
    data |= {"run_id": "trial-1", "run_time": 5.0, "duration": 20.0, "hold": "stale"}
    data["peers"][LEADER]["bound"] = 0.00012
    model.on_status(key(FOLLOWER, "status"), json.dumps(data).encode(), now=0.0)
    (row,) = model.rows(0.5)
    assert (row.run_id, row.run_time_s, row.duration_s, row.hold) == ("trial-1", 5.0, 20.0, "stale")
    assert row.bound_s == 0.00012
    console = Console(record=True, width=220, color_system=None)
    console.print(render([row]))
    text = console.export_text()
    assert "trial-1" in text and "5.0/20 (25%)" in text and "stale" in text and "0.120" in text


def test_rows_silent_for_drop_after_are_dropped() -> None:
    model = MonitorModel(stale_after=3.0, drop_after=30.0)
    model.on_status(key(LEADER, "status"), leader_status(), now=0.0)
    model.on_status(key(FOLLOWER, "status"), follower_status(), now=20.0)
    assert [(r.agent, r.state) for r in model.rows(29.0)] == [
        (LEADER, "stale"),
        (FOLLOWER, "stale"),
    ]
    assert [r.agent for r in model.rows(31.0)] == [FOLLOWER]
    assert model.rows(51.0) == []


def test_a_peer_alive_but_silent_is_a_red_column_never_left_out() -> None:
    model = MonitorModel()
    peers = {
        LEADER: peer(-26.42, 0.0004, samples=30, silent=2.34),
        "lund/ada": peer(1.0, 0.001, samples=3, silent=None),
    }
    model.on_status(key(FOLLOWER, "status"), status(FOLLOWER, peers=peers), now=0.0)
    model.on_status(key(LEADER, "status"), leader_status(), now=0.0)
    leader, follower = model.rows(0.5)
    assert follower.silent == {LEADER: 2.34} and leader.silent is None
    assert row_json(follower)["silent"] == {LEADER: 2.34}
    narrow = Console(record=True, width=80, color_system=None)
    table = fit(narrow, [leader, follower])
    assert "silent\npeers" in [str(c.header) for c in table.columns]
    narrow.print(table)
    text = narrow.export_text()
    assert "2.3 s" in text  # the cell may wrap on 80 columns
    wide = Console(record=True, width=220)
    wide.print(render([follower]))
    styled = wide.export_text(styles=True)
    assert f"\x1b[1;31m{LEADER} 2.3 s" in styled  # bold red: an alarm


def test_a_status_never_reaches_the_terminal_as_markup_or_escapes() -> None:
    """An insider's status with mode ``[/]`` had stopped the monitor (MarkupError), and
    escape sequences in it reached the terminal (repainting other agents' rows)."""
    model = MonitorModel()
    model.on_liveliness(key(FOLLOWER), alive=True, now=0.0)
    forged = follower_status(
        mode="[/]", run_id="[/bold]", platform="x[/x]\x1b[2J", follow="\x1b]0;owned\x07l/x"
    )
    model.on_status(key(FOLLOWER, "status"), forged, now=1.0)
    console = Console(record=True, width=200, color_system=None)
    console.print(render(model.rows(1.0)))
    text = console.export_text()
    assert "[/]" in text and "[/bold]" in text  # shown as they are
    assert "\x1b" not in text and "\x07" not in text


def test_a_status_with_a_hold_outside_the_table_is_refused() -> None:
    # status.hold is one of the supervisor's holds: anything else is not a status.
    with pytest.raises(ValidationError, match="hold"):
        follower_status(hold="\x1b]0;owned\x07stale")
