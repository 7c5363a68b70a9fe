"""Integration: ``fedlab host`` runs several agents in one process, as real processes
on loopback (a router, a leader as its own ``fedlab agent``, the host)."""

from __future__ import annotations

import pytest
from loopback import LEADER, Labs

from federation.fleet.launch import wait_for

pytestmark = pytest.mark.integration

FOLLOWERS = ("rome/f1", "rome/f2", "rome/f3")


def _following(line: dict[str, object]) -> bool:
    counters = line["counters"]
    assert isinstance(counters, dict)
    age = line["pose_age"]
    return (
        line["hold"] is None
        and counters.get("pose_received", 0) > 20
        and isinstance(age, float)
        and age < 0.2
    )


def test_hosted_followers_follow_on_one_shared_exchange(labs: Labs) -> None:
    router = labs.router("rome")
    leader = labs.leader(router)
    follower = {"role": "follower", "follow": LEADER}
    host = labs.host(router, {who: follower for who in FOLLOWERS}, "--duration", "12")
    for who in FOLLOWERS:
        agent = host.agents[who]
        line = agent.until(_following, timeout=20, what="following the leader")
        view = line["peers"][LEADER]
        # One clock in the process: one exchange with the leader for the three.
        assert view["sharing"] == 3, view
        assert view["samples"] >= 5 and view["rejected"] == 0, view
        assert set(line["peers"]) == {LEADER}, line["peers"]  # no pairwise sync among them
    # The leader sees three agents alive and queries each (once a second, by default).
    assert wait_for(
        lambda: set(FOLLOWERS) <= set((leader.last() or {}).get("peers", {})), timeout=10
    ), leader.last()
    # The run ends at --duration: exit code 0, a last status from each agent.
    assert wait_for(lambda: not host.alive(), timeout=25), host.log()[-2000:]
    assert host.stop() == 0
    assert "host stopped: rome/f1, rome/f2, rome/f3" in host.log()


def test_hosted_followers_each_hold_when_the_leader_is_lost(labs: Labs) -> None:
    router = labs.router("rome")
    leader = labs.leader(router)
    follower = {"role": "follower", "follow": LEADER}
    host = labs.host(router, {who: follower for who in FOLLOWERS})
    for who in FOLLOWERS:
        host.agents[who].until(_following, timeout=20, what="following the leader")
    leader.kill()  # a crash: no goodbye
    for who in FOLLOWERS:
        line = host.agents[who].until(
            lambda line: line["hold"] == "stale", timeout=10, what="a stale hold"
        )
        assert line["counters"]["stale_holds"] >= 1, line["counters"]
    assert host.alive()  # holding, not crashed
    assert host.stop() == 0


def test_a_taken_name_stops_the_host_and_closes_every_agent(labs: Labs) -> None:
    router = labs.router("rome")
    taken = labs.agent("rome/f2", router, role="member")
    taken.wait_status(timeout=15)
    host = labs.host(router, {who: {"role": "member"} for who in FOLLOWERS})
    assert wait_for(lambda: not host.alive(), timeout=20), host.log()[-2000:]
    assert host.stop() == 2
    log = host.log()
    assert "rome/f2" in log and "every agent closed" in log, log[-2000:]
    # The agent that had the name first is unaffected.
    assert taken.alive()
    assert taken.stop() == 0
