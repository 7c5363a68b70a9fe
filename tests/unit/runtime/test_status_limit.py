"""The largest status a real agent sends fits the size limit a generated router puts on
status keys (federation/deploy/limits.py)."""

from __future__ import annotations

import pytest
import zenoh
from cohosted import cohosted, follower_config

from federation.core.counters import Count
from federation.deploy import limits
from schemas.federation import FederationFile
from schemas.messages import CommandOutcome, PeerStatus


def federation_of(agents: int) -> FederationFile:
    """A two-lab federation with ``agents`` agents in all."""
    kiruna = {f"a{i}": {"role": "leader" if i == 0 else "follower"} for i in range(agents // 2)}
    rome = {f"b{i}": {"role": "follower"} for i in range(agents - agents // 2)}
    for entry in (*kiruna.values(), *rome.values()):
        if entry["role"] == "follower":
            entry["follow"] = "kiruna/a0"
    return FederationFile.model_validate(
        {
            "federation": "default",
            "labs": {
                "kiruna": {
                    "listen": ["tls/127.0.0.1:7447"],
                    "endpoint": "tls/127.0.0.1:7447",
                    "agents": kiruna,
                },
                "rome": {"listen": ["tls/127.0.0.1:7448"], "dial": ["kiruna"], "agents": rome},
            },
        }
    )


@pytest.mark.parametrize("agents", [2, 16, 64])
def test_the_largest_status_a_real_agent_sends_fits_its_limit(
    session: zenoh.Session, agents: int
) -> None:
    """A real agent's status, with every counter at a billion, a full log of commands
    and every other agent of the federation as a peer at its longest."""
    fed = federation_of(agents)
    with cohosted(session, follower_config("f")) as (_, _, (agent,)):
        for _ in range(20):
            agent.control_step()
        status = agent.status()
    worst_peer = PeerStatus(
        offset=-26.123456789012345, delay=0.04012345678901234, bound=0.000123456789012345,
        drift_ppm=12.345678901234567, error_bound=0.04012345678901234,
        last_offset=-26.12345678901234, last_delay=0.04012345678901234, locked=True,
        alive=True, samples=10**9, sent=10**9, timeouts=10**9, rejected=10**9,
        rejected_by_reason={"late": 10**9, "duplicate": 10**9, "unmatched": 10**9,
                            "malformed": 10**9, "oversized": 10**9},
        clock_steps=10**9, sharing=256,
    )  # fmt: skip
    status.peers = {f"lab-{i:07d}/agent-name-{i:09d}": worst_peer for i in range(agents - 1)}
    status.counters = {count: 10**9 for count in Count}
    command = CommandOutcome(
        command="resume", issuer="kiruna/operator-name", seq=10**9, outcome="ignored",
        detail="a resume at run time 1234.567 s came 1.234 s after its instant: ignored",
    )  # fmt: skip
    status.commands = [command] * 8
    size = len(status.model_dump_json().encode())
    print(f"{agents} agents: status {size} bytes, limit {limits.status_limit(fed)}")
    assert size <= limits.status_limit(fed)


def test_the_status_limit_grows_with_the_federation_and_the_message_limit_with_it() -> None:
    small, large = federation_of(2), federation_of(256)
    assert limits.status_limit(small) < limits.message_limit(small) == small.message_limit
    assert limits.status_limit(large) == limits.message_limit(large) > large.message_limit
