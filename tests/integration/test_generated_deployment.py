"""A generated deployment records its runs: from ``fedlab deploy generate --local`` alone
(routers, agents and an operator with the generated files, TLS and access control on
loopback), ``fedlab ctl start`` without ``--force``, then collect and report.

Agents set up from the generated files showed ``not recording`` in preflight, and ctl
refused to start them: their settings named no runs folder. Each now records in its
service's state folder (``--local``: the lab folder's ``state/``).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lifecycle import QUICK_LOCK, as_json, fedlab
from loopback import FOLLOWER, LEADER, Labs
from test_trust import make_federation, start_agent, start_routers

pytestmark = pytest.mark.integration


def test_a_generated_federation_records_a_run_that_collect_gathers(
    labs: Labs, tmp_path: Path
) -> None:
    fed = make_federation(tmp_path)
    start_routers(labs, fed)
    agents = {
        LEADER: start_agent(labs, fed, LEADER, *QUICK_LOCK),
        FOLLOWER: start_agent(labs, fed, FOLLOWER, "--clock-offset", "26.42", *QUICK_LOCK),
    }
    for who, agent in agents.items():
        line = agent.until(
            lambda line: (
                (line.get("ready") or {}).get("reference_locked", True)
                and (line.get("ready") or {}).get("recording")
            ),
            timeout=30,
            what="locked on the reference clock and recording",
        )
        lab, name = who.split("/")
        assert line["ready"]["recording_to"] == str(fed.dir / lab / "state" / name / "runs")
    operator = str(fed.zenoh_config("kiruna/ctl", "operators"))
    started, _ = fedlab(
        "ctl", "start", "--duration", "2", "--in", "1.5", "--json", "-c", operator, timeout=60
    )
    assert started.returncode == 0, started.stdout + started.stderr  # no --force
    result = as_json(started)
    assert result["ok"] and not result["pending"], result
    run_id = result["command"]["run_id"]
    for agent in agents.values():
        agent.until(lambda line: line["mode"] == "done", timeout=20, what="the run done")

    out = tmp_path / "collected"
    collected, _ = fedlab("collect", run_id, "--out", str(out), "--json", "-c", operator)
    assert collected.returncode == 0, collected.stdout + collected.stderr
    assert {p.name for p in out.glob("*.mcap")} >= {"kiruna-knatte.mcap", "rome-pinocchio.mcap"}
    reported, _ = fedlab("report", str(out))
    assert reported.returncode == 0, reported.stdout + reported.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert [f["follower"] for f in summary["followers"]] == [FOLLOWER]
