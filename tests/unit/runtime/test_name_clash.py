"""Two processes under one name: the agent's later looks at its name (2 s and 10 s
after start), and the hold they lead to, for good (on a real Zenoh session)."""

from __future__ import annotations

import time

import zenoh
from cohosted import LEAD, cohosted, follower_config, leader_config, run_for

from federation.core.holds import Trigger
from federation.runtime.names import NAME_CHECKS_AFTER


def test_alone_on_its_name_an_agent_finds_no_clash(session: zenoh.Session) -> None:
    # Its own session answers its sync key; nobody else does.
    with cohosted(session, leader_config()) as (_, _, (lead,)):
        checks = list(lead.watches.name_checks)
        assert len(checks) == len(NAME_CHECKS_AFTER)
        for due in checks:
            lead.watches.check_name_again(due)
        assert lead.watches.name_checks == []  # each look once
        time.sleep(1.5)  # the looks' queries end by their 1 s timeout: a clash is said by then
        assert lead.name_clash is None
        served = lead.counters["sync_requests_served"]
        assert served == 2, lead.counters  # its own two looks, answered by itself
        run_for([lead], 0.5)
        assert lead.hold is None and not lead.platform.held  # type: ignore[attr-defined]


def test_the_looks_are_due_after_start_and_not_before(session: zenoh.Session) -> None:
    before = time.monotonic()
    with cohosted(session, leader_config()) as (_, _, (lead,)):
        after = time.monotonic()
        for due, wait in zip(lead.watches.name_checks, NAME_CHECKS_AFTER, strict=True):
            assert before + wait <= due <= after + wait
        first = lead.watches.name_checks[0]
        lead.watches.check_name_again(first - 0.1)  # not yet: nothing asked
        assert lead.watches.name_checks[0] == first


def test_a_clash_holds_for_good_through_runs(session: zenoh.Session) -> None:
    with cohosted(session, leader_config(), follower_config("f1")) as (_, _, (lead, f1)):
        run_for([lead, f1], 1.0)
        for agent in (lead, f1):
            agent.watches.name_clash = f"2 processes answer for {agent.me} in federation default"
            t_exec = agent.clock.now()
            agent.control_step()
            assert agent.hold == "name_taken", agent.me
            assert agent.platform.held  # type: ignore[attr-defined]
            assert agent.counters["name_taken_holds"] == 1
            ready = agent.readiness(t_exec)
            assert not ready.platform and "name_taken" in ready.platform_detail
            # An abort, the run's end and a new start: still held, for the name's sake.
            for trigger in (
                Trigger.RUN_ABORTED, Trigger.OPERATOR_RESET, Trigger.RUN_ARMED, Trigger.RUN_DONE
            ):  # fmt: skip
                agent.safety.apply(trigger)
                assert agent.hold == "name_taken"
                assert agent.platform.held  # type: ignore[attr-defined]
            assert agent.status().hold == "name_taken"


def test_a_clash_over_a_stale_hold_outlasts_the_link_coming_back(session: zenoh.Session) -> None:
    """A follower held for a stale link, then found under a taken name: the leader's
    poses and sync flowing again (which release a stale hold) release nothing."""
    with cohosted(session, leader_config(), follower_config("f1")) as (_, _, (lead, f1)):
        run_for([lead, f1], 1.5)  # synced, the leader's pose flowing
        t_exec, host = f1.clock.read()
        f1.pose_received_at[LEAD] = t_exec - 1.0  # as if the link had gone quiet
        f1.intake.link_watch.holding = False  # a loaded host may have held it a moment
        holds = f1.counters["stale_holds"]
        f1.watches.watch_link(t_exec, host)
        assert f1.hold == "stale" and f1.counters["stale_holds"] == holds + 1
        f1.watches.name_clash = "2 processes answer for lab1/f1 in federation default"
        f1.control_step()
        assert f1.hold == "name_taken"
        run_for([lead, f1], 2.0)  # poses and sync exchanges again: a stale hold would end
        assert f1.pose_received_at[LEAD] > t_exec  # the link did come back
        assert f1.hold == "name_taken" and f1.platform.held  # type: ignore[attr-defined]
        assert f1.counters["name_taken_holds"] == 1  # never released, so never held again


class _LeftItsArea:
    """A scenario whose platform has just left its area (what control_step reads)."""

    workspace_held = True
    area_detail = "left its area"

    def reference(self, *args: object) -> None:
        return None


def test_a_workspace_hold_after_the_clash_keeps_the_name_as_the_reason(
    session: zenoh.Session,
) -> None:
    with cohosted(session, leader_config()) as (_, _, (lead,)):
        run_for([lead], 0.5)
        lead.watches.name_clash = "2 processes answer for lab0/lead in federation default"
        lead.control_step()
        assert lead.hold == "name_taken"
        lead.scenario = _LeftItsArea()  # type: ignore[assignment]
        try:
            lead.control_step()  # the workspace hold comes after: held, reason kept
        finally:
            lead.scenario = None
        assert lead.watches.left_area and lead.hold == "name_taken"
        assert lead.platform.held  # type: ignore[attr-defined]
        lead.control_step()
        assert lead.counters["name_taken_holds"] == 1  # the reason never changed
