"""The UDP bridge's protocol logic (:mod:`federation.bridge.core`), time passed in.

Every exchange here is built by hand: the legacy agent's clock is ``CLOCK_OFFSET``
(26.42 s, the paper's) ahead of the bridge's, the leader's 3 s behind.
"""

from __future__ import annotations

import ast
import json
import math
import struct
from pathlib import Path
from typing import Any

import pytest

from federation.bridge import core as bridge_core
from federation.bridge.core import BridgeCore
from federation.core import keys, wire
from federation.core.keys import AgentId
from federation.core.paper import CLOCK_OFFSET
from federation.core.sync import SyncClient
from schemas.bridge import UdpBridgeConfig
from schemas.config import validate

LEADER = "kiruna/knatte"
LEGACY = "rome/legacy"
LEGACY_POSE = (1.25, -0.5, 0.3, 0.0, 0.0, 0.0)


def config(**overrides: Any) -> UdpBridgeConfig:
    settings: dict[str, Any] = {
        "agent": LEGACY,
        "listen": "127.0.0.1:9000",
        "peer": "127.0.0.1:9001",
        "follow": LEADER,
    }
    return validate(UdpBridgeConfig, settings | overrides, "test")


def exchange(client_request: bytes, server_offset: float, t_send: float, rtt: float) -> bytes:
    """The reply a server whose clock is ``server_offset`` ahead sends to a request."""
    t1 = wire.decode_request(client_request)
    return wire.encode_reply(t1, t_send + rtt / 2 + server_offset, wire.Pose(2.0, 3.0, 0.1))


def sync_core(core: BridgeCore, legacy: float, reference: float, n: int = 20) -> float:
    """Feed ``n`` exchanges on both links (bridge clock starts at 100 s); returns now."""
    now = 100.0
    for _ in range(n):
        request = core.legacy_request(now)
        reply = wire.decode_request(request)
        data = wire.encode_reply(reply, now + 0.0005 + legacy, wire.Pose(*LEGACY_POSE))
        assert core.on_datagram(data, now + 0.001).pose is not None
        ref_request = core.reference_request(now)
        assert ref_request is not None
        assert core.on_reference_reply(exchange(ref_request, reference, now, 0.002), now + 0.002)
        now += 0.1
    return now


def liveliness(agent: str) -> str:
    return keys.agent_key(keys.DEFAULT_FEDERATION, AgentId.parse(agent))


def status_line(agent: str, role: str) -> bytes:
    return json.dumps({"agent": agent, "role": role}).encode()


def test_legacy_request_before_reference_time_gets_no_reply() -> None:
    core = BridgeCore(config())
    outcome = core.on_datagram(wire.encode_request(5.0), 10.0)
    assert outcome.reply is None and outcome.rejected == "no reference time yet"
    assert outcome.kind == "unsynced"
    assert core.counters["udp_requests_unsynced"] == 1


def test_replies_carry_reference_time_and_queries_legacy_time() -> None:
    core = BridgeCore(config())
    now = sync_core(core, legacy=CLOCK_OFFSET, reference=-3.0)
    core.on_followed_pose(wire.encode_pose(50.0, wire.Pose(0.5, 0.25, 0.7)))
    # The legacy agent's request: t2 on the leader's clock, the leader's pose.
    outcome = core.on_datagram(wire.encode_request(1234.5), now)
    assert outcome.reply is not None
    reply = wire.decode_reply(outcome.reply)
    assert reply.t1 == 1234.5
    assert reply.t2 == pytest.approx(now - 3.0, abs=1e-9)
    assert reply.pose == wire.Pose(0.5, 0.25, 0.7)
    # A federation query: t2 on the legacy agent's clock, the legacy agent's pose.
    answer = core.on_sync_query(wire.encode_request(7.0), now)
    assert answer is not None
    reply = wire.decode_reply(answer[0])
    assert reply.t1 == 7.0
    assert reply.t2 == pytest.approx(now + CLOCK_OFFSET, abs=1e-9)
    assert answer[1] == pytest.approx(CLOCK_OFFSET, abs=1e-9)
    assert reply.pose == wire.Pose(*LEGACY_POSE)
    # Status is on the legacy agent's clock; the leader's offset relative to it.
    status = core.status(now, host=500.0)
    assert status.t_exec == pytest.approx(now + CLOCK_OFFSET, abs=1e-9)
    assert status.peers[LEADER].offset == pytest.approx(-3.0 - CLOCK_OFFSET, abs=1e-9)
    assert status.t_sim == pytest.approx(now - 3.0, abs=1e-9)
    extra = status.model_dump()
    assert extra["clock"] == "legacy" and extra["legacy"]["offset"] == pytest.approx(CLOCK_OFFSET)
    assert status.role == "follower" and status.reference == LEADER
    assert status.pose == list(LEGACY_POSE)
    assert status.mode == "unmanaged" and status.platform == "udp:127.0.0.1:9001"
    assert status.pose_age == pytest.approx(now - 3.0 - 50.0, abs=1e-9)


def test_status_is_on_the_bridge_clock_before_the_legacy_agent_answers() -> None:
    status = BridgeCore(config()).status(42.0, host=7.0)
    assert status.t_exec == 42.0 and status.host_monotonic == 7.0 and status.t_sim is None
    extra = status.model_dump()
    assert extra["clock"] == "bridge" and not extra["legacy"]["alive"]
    assert extra["legacy"]["bridge_t_exec"] == 42.0


def test_leader_bridge_serves_the_legacy_clock_as_reference_time() -> None:
    core = BridgeCore(config(role="leader", follow=None))
    assert core.reference_request(0.0) is None
    now = 100.0
    for _ in range(5):
        t1 = wire.decode_request(core.legacy_request(now))
        core.on_datagram(wire.encode_reply(t1, now + 0.0005 + 7.0, wire.Pose()), now + 0.001)
        now += 0.1
    outcome = core.on_datagram(wire.encode_request(1.0), now)
    assert outcome.reply is not None
    assert wire.decode_reply(outcome.reply).t2 == pytest.approx(now + 7.0, abs=1e-9)
    assert core.status(now, 0.0).reference == LEGACY


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\x00" * 7, "got 7"),
        (b"\x00" * 65, "got 65"),
        (b"", "got 0"),
        (struct.pack("<d", math.nan), "not a finite number"),
        (struct.pack("<d", math.inf), "not a finite number"),
        (struct.pack("<8d", 1.0, math.nan, 0, 0, 0, 0, 0, 0), "malformed"),
    ],
)
def test_malformed_datagrams_are_dropped_and_counted(data: bytes, reason: str) -> None:
    core = BridgeCore(config())
    sync_core(core, CLOCK_OFFSET, -3.0, n=3)
    outcome = core.on_datagram(data, 200.0)
    assert outcome.reply is None and outcome.pose is None
    assert outcome.rejected is not None and reason in outcome.rejected
    assert outcome.kind == "malformed"
    assert core.counters["udp_malformed"] == 1


def test_malformed_federation_query_raises_decode_error_and_is_counted() -> None:
    core = BridgeCore(config())
    with pytest.raises(wire.DecodeError):
        core.on_sync_query(b"\x00" * 7, 1.0)
    assert core.counters["sync_requests_malformed"] == 1


def test_malformed_followed_pose_raises_decode_error_and_is_counted() -> None:
    core = BridgeCore(config())
    with pytest.raises(wire.DecodeError):
        core.on_followed_pose(b"\x00" * 3)
    assert core.counters["pose_malformed"] == 1 and core.followed_pose is None


def test_legacy_agent_silent_is_lost_and_its_clock_forgotten() -> None:
    core = BridgeCore(config(legacy_timeout=2.0))
    assert core.on_sync_query(wire.encode_request(1.0), 50.0) is None  # never seen
    now = sync_core(core, CLOCK_OFFSET, -3.0)
    assert core.check_legacy(now)
    assert core.on_sync_query(wire.encode_request(1.0), now) is not None
    assert not core.check_legacy(now + 2.5)
    assert core.on_sync_query(wire.encode_request(1.0), now + 2.5) is None
    assert core.legacy_offset(now + 2.5) is None
    assert core.counters["legacy_lost"] == 1
    assert not core.maintain(now + 3.0).legacy_alive


def test_sync_client_accepts_the_bridges_legacy_replies_only_once() -> None:
    # The bridge never answers its own replies: a duplicate is rejected, not re-published.
    core = BridgeCore(config())
    t1 = wire.decode_request(core.legacy_request(10.0))
    data = wire.encode_reply(t1, 10.0 + CLOCK_OFFSET, wire.Pose())
    assert core.on_datagram(data, 10.001).pose is not None
    again = core.on_datagram(data, 10.002)
    assert again.pose is None and again.rejected == "sync reply (duplicate)"
    assert isinstance(core.legacy.client, SyncClient)


# -- the reference: found by status, rejoined with a new clock ---------------------------
def test_a_follower_without_follow_follows_the_first_live_leader_by_name() -> None:
    core = BridgeCore(config(follow=None))
    assert core.reference_id is None and core.reference_request(0.0) is None
    assert core.maintain(0.0).follow is None  # no leader seen yet
    core.on_status(b"not json")
    core.on_status(status_line("oslo/olle", "follower"))
    core.on_status(status_line(LEGACY, "leader"))  # itself: never followed
    assert core.maintain(0.1).follow is None
    core.on_status(status_line(LEADER, "leader"))
    core.on_status(status_line("lund/lasse", "leader"))
    core.on_liveliness(liveliness(LEADER), alive=True)
    found = core.maintain(0.2)
    assert found.follow == AgentId.parse(LEADER) and core.reference_id == found.follow
    assert found.leaders == (AgentId.parse(LEADER), AgentId.parse("lund/lasse"))
    assert core.reference.alive
    # Followed and alive: nothing changes, and the several leaders are said once.
    assert core.maintain(0.3) == (False, None, None, ())
    # It leaves and stops saying it leads: the other leader is followed.
    core.on_liveliness(liveliness(LEADER), alive=False)
    found = core.maintain(0.4)
    assert found.follow == AgentId.parse("lund/lasse") and found.leaders == ()


def test_a_reference_that_rejoins_is_synced_afresh() -> None:
    core = BridgeCore(config())
    now = sync_core(core, CLOCK_OFFSET, -3.0)
    core.on_liveliness(liveliness(LEADER), alive=True)
    assert core.maintain(now).rejoined is None  # first seen: not a rejoin
    assert core.reference_offset(now) == pytest.approx(-3.0, abs=1e-9)
    core.on_liveliness(liveliness(LEADER), alive=False)
    assert not core.reference.alive
    core.on_liveliness(liveliness(LEADER), alive=True)
    found = core.maintain(now)
    assert found.rejoined == AgentId.parse(LEADER) and found.follow is None
    assert core.reference.alive and core.reference_offset(now) is None
    assert core.maintain(now).rejoined is None


def test_liveliness_of_other_keys_is_ignored() -> None:
    core = BridgeCore(config())
    core.on_liveliness("fedlab/other/kiruna/knatte", alive=True)
    core.on_liveliness(f"{liveliness(LEADER)}/pose", alive=True)
    core.on_liveliness("not/a/key", alive=True)
    assert not core.reference.alive


def test_a_leader_bridge_maintains_only_the_legacy_link() -> None:
    core = BridgeCore(config(role="leader", follow=None))
    core.on_status(status_line(LEADER, "leader"))
    assert core.maintain(0.0) == (False, None, None, ())
    assert core.reference_id == AgentId.parse(LEGACY)


def test_the_core_does_no_io() -> None:
    # Time and bytes come in as arguments: no clock, socket, thread or Zenoh here.
    tree = ast.parse(Path(bridge_core.__file__).read_text(encoding="utf-8"))
    imported = {
        name.split(".")[0]
        for node in ast.walk(tree)
        for name in (
            [a.name for a in node.names] if isinstance(node, ast.Import)
            else [node.module or ""] if isinstance(node, ast.ImportFrom)
            else []
        )
    }  # fmt: skip
    assert not imported & {"zenoh", "socket", "time", "threading", "asyncio", "argparse"}


def test_a_name_taken_elsewhere_stops_the_bridge_speaking_for_it_for_good() -> None:
    core = BridgeCore(config())
    now = sync_core(core, CLOCK_OFFSET, -3.0)
    assert core.maintain(now).legacy_alive
    assert not core.name_alive_elsewhere()
    core.on_liveliness(liveliness(LEGACY), True)  # another process's token (none is ours)
    assert core.name_alive_elsewhere()
    assert core.hold_for_name("2 processes answer for rome/legacy")
    assert not core.hold_for_name("again")  # said and counted once
    assert core.counters["name_taken_holds"] == 1
    # The legacy agent's request: no reply, so no reference time and no pose to steer by.
    held = core.on_datagram(wire.encode_request(1.0), now)
    assert held.reply is None and held.pose is None and held.kind == "held"
    assert "2 processes answer" in (held.rejected or "")
    # Its reply to the bridge: not published.
    reply = wire.encode_reply(wire.decode_request(core.legacy_request(now)), now, wire.Pose())
    assert core.on_datagram(reply, now + 0.001).pose is None
    # The federation's sync queries on its behalf: unanswered; its token stays away.
    assert core.on_sync_query(wire.encode_request(5.0), now) is None
    assert not core.maintain(now + 0.1).legacy_alive
    status = core.status(now, now)
    assert status.hold == "name_taken"
    assert status.counters["udp_held_for_name"] == 2
    assert status.counters["sync_requests_held"] == 1
