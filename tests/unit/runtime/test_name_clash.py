"""Two processes under one name: the agent's second look at its name, two seconds
after start, and the hold it leads to, for good (on a real Zenoh session)."""

from __future__ import annotations

import time

import zenoh
from cohosted import LEAD, cohosted, follower_config, leader_config, run_for

from federation.core.runstate import Event
from federation.runtime import agent as agent_module


def test_the_second_look_alone_on_its_name_finds_no_clash(session: zenoh.Session) -> None:
    # Its own session answers its sync key; nobody else does.
    with cohosted(session, leader_config()) as (_, _, (lead,)):
        assert lead._name_check_at < float("inf")  # due once, after start
        lead._check_name_again(lead._name_check_at)
        assert lead._name_check_at == float("inf")  # looked once: never again
        time.sleep(1.5)  # the query's 1 s timeout, and its end
        assert lead.name_clash is None
        run_for([lead], 0.5)
        assert lead.hold_reason is None and not lead.platform.held  # type: ignore[attr-defined]


def test_a_clash_holds_for_good_through_runs_and_link(session: zenoh.Session) -> None:
    with cohosted(session, leader_config(), follower_config("f1")) as (_, _, (lead, f1)):
        run_for([lead, f1], 1.0)
        for agent in (lead, f1):
            agent.name_clash = f"2 processes answer for {agent.me} in federation default"
            t_exec, host = agent.clock.read()
            agent.control_step()
            assert agent.hold_reason == "name_taken", agent.me
            assert agent.platform.held  # type: ignore[attr-defined]
            assert agent.counters["name_taken_holds"] == 1
            ready = agent.readiness(t_exec)
            assert not ready.platform and "name_taken" in ready.platform_detail
            # An abort, the run's end and a new start: still held, for the name's sake.
            for kind in ("aborted", "reset", "armed", "done"):
                agent._apply([Event(kind, None)], t_exec, host)  # type: ignore[arg-type]
                assert agent.hold_reason == "name_taken"
                assert agent.platform.held  # type: ignore[attr-defined]
        # The followed pose flowing and sync fresh release no one held for the name.
        t_exec, host = f1.clock.read()
        f1.pose_received_at[LEAD] = t_exec
        f1._watch_link(t_exec, host)
        assert f1.hold_reason == "name_taken"
        run_for([lead, f1], 1.0)  # still held after more steps, counted once
        for agent in (lead, f1):
            assert agent.hold_reason == "name_taken" and agent.counters["name_taken_holds"] == 1
            assert agent.status().hold == "name_taken"


def test_the_look_is_due_two_seconds_after_start(session: zenoh.Session) -> None:
    before = time.monotonic()
    with cohosted(session, leader_config()) as (_, _, (lead,)):
        after = time.monotonic()
        due = lead._name_check_at
        assert (
            before + agent_module.NAME_CHECK_AFTER <= due <= after + agent_module.NAME_CHECK_AFTER
        )
        lead._check_name_again(due - 0.1)  # not yet: nothing asked
        assert lead._name_check_at == due
