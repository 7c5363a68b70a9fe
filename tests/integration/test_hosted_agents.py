"""Integration: ``fedlab host`` runs several agents in one process, as real processes
on loopback (a router, a leader as its own ``fedlab agent``, the host)."""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh
from loopback import LEADER, Labs, client_config

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
    leader.wait_status(timeout=20)  # up before the followers: the run is theirs to follow
    follower = {"role": "follower", "follow": LEADER}
    # 6 s of flight (from the agents' start), in which they follow within a second or two.
    host = labs.host(router, {who: follower for who in FOLLOWERS}, "--duration", "6")
    # The run ends at --duration: exit code 0, a last status from each agent.
    assert wait_for(lambda: not host.alive(), timeout=30), host.log()[-2000:]
    assert host.stop() == 0
    assert "host stopped: rome/f1, rome/f2, rome/f3" in host.log()
    for who in FOLLOWERS:
        lines = host.agents[who].lines()
        line = next((line for line in lines if _following(line)), None)
        assert line is not None, f"{who} never followed the leader; last status {lines[-1:]}"
        view = line["peers"][LEADER]
        # One clock in the process: one exchange with the leader for the three.
        assert view["sharing"] == 3, view
        assert view["samples"] >= 5 and view["rejected"] == 0, view
        assert set(line["peers"]) == {LEADER}, line["peers"]  # no pairwise sync among them
    # The leader saw the three agents alive and queried each (once a second, by default).
    assert wait_for(
        lambda: any(set(FOLLOWERS) <= set(line["peers"]) for line in leader.lines()), timeout=10
    ), leader.last()


def _alive(endpoint: str, who: str) -> bool:
    """Whether ``who``'s liveliness token is in the federation, as a client sees it."""
    with zenoh.open(client_config(endpoint)) as session:
        replies = session.liveliness().get(f"fedlab/default/{who}", timeout=1.0)
        return any(reply.ok is not None for reply in replies)


def test_a_hosted_agent_whose_duration_ends_leaves_while_the_others_fly_on(
    labs: Labs,
) -> None:
    """Its platform held, it leaves the federation as a process of its own would: the
    token goes (what follows it sees it gone), the other hosted agents stay."""
    router = labs.router("rome")
    labs.leader(router)
    short, long = "rome/f1", "rome/f2"
    follower = {"role": "follower", "follow": LEADER}
    host = labs.host(router, {short: {**follower, "duration": 4.0}, long: follower})
    host.agents[long].until(_following, timeout=20, what="following the leader")
    assert _alive(router.endpoint, short)
    last = host.agents[short].until(
        lambda line: line["hold"] == "ended", timeout=15, what="its duration's end"
    )
    assert last["hold"] == "ended"
    assert wait_for(lambda: not _alive(router.endpoint, short), timeout=5), "f1 still declared"
    assert _alive(router.endpoint, long) and host.alive()
    host.agents[long].until(_following, timeout=5, what="flying on")
    assert host.stop() == 0


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
    tokens: list[str] = []
    session = zenoh.open(client_config(router.endpoint))
    try:
        watch = session.liveliness().declare_subscriber(
            "fedlab/default/rome/*",
            lambda s: tokens.append(str(s.key_expr)) if s.kind == zenoh.SampleKind.PUT else None,
            history=True,
        )
        # The watch sees tokens: the name already taken is among them.
        assert wait_for(lambda: "fedlab/default/rome/f2" in tokens, timeout=5), tokens
        try:
            host = labs.host(router, {who: {"role": "member"} for who in FOLLOWERS})
            assert wait_for(lambda: not host.alive(), timeout=20), host.log()[-2000:]
            assert host.stop() == 2
        finally:
            watch.undeclare()
    finally:
        session.close()
    log = host.log()
    assert "rome/f2" in log and "every agent closed" in log, log[-2000:]
    # Refused before any of its agents was declared: no token of f1 or f3 ever appeared.
    assert not {"fedlab/default/rome/f1", "fedlab/default/rome/f3"} & set(tokens), tokens
    # The agent that had the name first is unaffected.
    assert taken.alive()
    assert taken.stop() == 0


def test_a_fault_in_one_hosted_agent_holds_and_closes_every_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """One agent's platform fails in its loop: the host stops with exit code 1 and every
    agent, the faulty one's neighbours too, ends held (all valves closed) and closed,
    though closing the first of them fails too. In this process, on a real Zenoh
    session (peer mode, no router, no scouting)."""
    from agents.platform import PlatformError
    from federation import cli
    from federation.runtime.agent import AgentRuntime

    files = []
    for name, platform in (("a1", "knatte"), ("a2", "pinocchio"), ("a3", "kinematic")):
        path = tmp_path / f"{name}.toml"
        fields = f'lab = "rome"\nname = "{name}"\nrole = "member"\nplatform = "{platform}"\n'
        path.write_text(fields)
        files.append(str(path))
    steps: dict[str, int] = {}
    ended: dict[str, tuple[bool, int]] = {}
    step, close = AgentRuntime.control_step, AgentRuntime.close

    def failing_step(self: AgentRuntime) -> None:
        who = str(self.me)
        steps[who] = steps.get(who, 0) + 1
        if who == "rome/a2" and steps[who] > 100:  # 1 s of pinocchio's 100 Hz steps
            raise PlatformError("rome/a2: avionics stopped answering (injected)")
        step(self)

    def recorded_close(self: AgentRuntime, wait: bool = True) -> None:
        close(self, wait)
        valves = getattr(self.platform, "valves", ())
        ended[str(self.me)] = (bool(getattr(self.platform, "held", False)), sum(valves))
        if str(self.me) == "rome/a1":  # a failure while closing must not stop the rest
            raise OSError("disk full while closing rome/a1's recording (injected)")

    monkeypatch.setattr(AgentRuntime, "control_step", failing_step)
    monkeypatch.setattr(AgentRuntime, "close", recorded_close)
    argv = ["host", *files, "-m", "peer", "-l", "tcp/127.0.0.1:0",
            "--cfg", "scouting/multicast/enabled:false"]  # fmt: skip
    code = cli.main([*argv, "--duration", "20"])  # bounded: the fault comes after 1 s
    assert code == 1
    assert "avionics stopped answering (injected); every agent's valves closed" in (
        capsys.readouterr().err
    )
    assert steps["rome/a1"] > 50 and steps["rome/a3"] > 10  # the others were flying
    # Every agent closed, the ones after a1's failing close too, each held, no valve open.
    assert ended == {who: (True, 0) for who in ("rome/a1", "rome/a2", "rome/a3")}
