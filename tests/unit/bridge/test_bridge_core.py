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
from federation.bridge.core import BridgeCore, TokenBucket
from federation.core import keys, wire
from federation.core.keys import AgentId
from federation.core.paper import CLOCK_OFFSET
from federation.core.sync import SyncClient
from schemas.bridge import UdpBridgeConfig
from schemas.config import validate

LEADER = "kiruna/knatte"
LEGACY = "rome/legacy"
LEGACY_POSE = (1.25, -0.5, 0.3, 0.0, 0.0, 0.0)
PEER = ("127.0.0.1", 9001)  # --peer: the legacy agent's requests and replies come from it


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
    for i in range(n):
        request = core.legacy_request(now)
        reply = wire.decode_request(request)
        data = wire.encode_reply(reply, now + 0.0005 + legacy, wire.Pose(*LEGACY_POSE))
        # Published once the warm-up has fed the estimate (the third exchange on).
        assert (core.on_datagram(data, PEER, now + 0.001).pose is not None) == (i >= 2)
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
    outcome = core.on_datagram(wire.encode_request(5.0), PEER, 10.0)
    assert outcome.reply is None and outcome.rejected == "no reference time yet"
    assert outcome.kind == "unsynced"
    assert core.counters["udp_requests_unsynced"] == 1


def test_replies_carry_reference_time_and_queries_legacy_time() -> None:
    core = BridgeCore(config())
    now = sync_core(core, legacy=CLOCK_OFFSET, reference=-3.0)
    core.on_liveliness(liveliness(LEADER), alive=True)
    core.on_followed_pose(wire.encode_pose(now - 3.01, wire.Pose(0.5, 0.25, 0.7)), now)
    # The legacy agent's request: t2 on the leader's clock, the leader's pose.
    outcome = core.on_datagram(wire.encode_request(1234.5), PEER, now)
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
    assert status.pose_age == pytest.approx(0.01, abs=1e-9)


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
        core.on_datagram(wire.encode_reply(t1, now + 0.0005 + 7.0, wire.Pose()), PEER, now + 0.001)
        now += 0.1
    outcome = core.on_datagram(wire.encode_request(1.0), PEER, now)
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
    outcome = core.on_datagram(data, PEER, 200.0)
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
        core.on_followed_pose(b"\x00" * 3, 10.0)
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
    first = core.on_datagram(data, PEER, 10.001)
    assert first.pose is None and first.rejected == "not yet confirmed by the estimate"
    again = core.on_datagram(data, PEER, 10.002)
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
    core.on_status(status_line("oslo/ghost", "leader"))  # says it leads, never alive
    core.on_liveliness(liveliness(LEADER), alive=True)
    core.on_liveliness(liveliness("lund/lasse"), alive=True)
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
    held = core.on_datagram(wire.encode_request(1.0), PEER, now)
    assert held.reply is None and held.pose is None and held.kind == "held"
    assert "2 processes answer" in (held.rejected or "")
    # Its reply to the bridge: not published.
    reply = wire.encode_reply(wire.decode_request(core.legacy_request(now)), now, wire.Pose())
    assert core.on_datagram(reply, PEER, now + 0.001).pose is None
    # The federation's sync queries on its behalf: unanswered; its token stays away.
    assert core.on_sync_query(wire.encode_request(5.0), now) is None
    assert not core.maintain(now + 0.1).legacy_alive
    status = core.status(now, now)
    assert status.hold == "name_taken"
    assert status.counters["udp_held_for_name"] == 2
    assert status.counters["sync_requests_held"] == 1


# -- nothing to steer by: no reply (the legacy agent's own design fails closed on it) ---
def _serving(**overrides: Any) -> tuple[BridgeCore, float]:
    """A follower bridge synced on both links, its leader alive with a fresh pose."""
    core = BridgeCore(config(**overrides))
    now = sync_core(core, legacy=CLOCK_OFFSET, reference=-3.0)
    core.on_liveliness(liveliness(LEADER), alive=True)
    core.on_followed_pose(wire.encode_pose(now - 3.01, wire.Pose(0.5)), now, source="aaaa")
    source = (PEER[0], core.config.request_port or PEER[1])
    assert core.on_datagram(wire.encode_request(1.0), source, now).reply is not None
    return core, now


def test_no_reply_without_a_pose_of_the_followed_agent() -> None:
    # A zero pose had been sent: the legacy platform steered to the origin, heading 0.
    core = BridgeCore(config())
    now = sync_core(core, legacy=CLOCK_OFFSET, reference=-3.0)
    core.on_liveliness(liveliness(LEADER), alive=True)
    outcome = core.on_datagram(wire.encode_request(1.0), PEER, now)
    assert outcome.reply is None and outcome.kind == "held"
    assert core.counters["udp_requests_no_pose"] == 1


@pytest.mark.parametrize("later", [0.3, 60.0, 3600.0])
def test_no_reply_once_the_followed_pose_is_stale(later: float) -> None:
    # The leader's poses stopped: its last pose (and its rates) had been sent for ever.
    core, now = _serving()
    outcome = core.on_datagram(wire.encode_request(1.0), PEER, now + later)
    assert outcome.reply is None and "old" in (outcome.rejected or "")
    assert core.counters["udp_requests_stale"] == 1
    # A pose old on arrival (stamped 1 s back on the leader's clock) is stale too.
    core.on_followed_pose(wire.encode_pose(now - 4.0 + later, wire.Pose()), now + later)
    assert core.on_datagram(wire.encode_request(1.0), PEER, now + later).reply is None


def test_no_reply_once_the_reference_left() -> None:
    core, now = _serving()
    core.on_liveliness(liveliness(LEADER), alive=False)
    outcome = core.on_datagram(wire.encode_request(1.0), PEER, now + 0.01)
    assert outcome.reply is None and core.counters["udp_requests_reference_gone"] == 1


def test_a_contested_reference_is_not_relayed_and_its_link_restarts() -> None:
    # A second session publishing the leader's pose had its poses relayed straight on.
    core, now = _serving()
    forged = wire.encode_pose(now - 3.0, wire.Pose(9.0))
    core.on_followed_pose(forged, now + 0.01, source="bbbb")
    assert core.counters["contested"] == 1 and core.followed_pose is None
    assert core.reference_offset(now + 0.01) is None  # its estimate starts again
    assert core.on_datagram(wire.encode_request(1.0), PEER, now + 0.02).reply is None
    # Replies from another session contest it on the sync channel too.
    core2, now2 = _serving()
    ref_request = core2.reference_request(now2)
    assert ref_request is not None
    assert core2.on_reference_reply(
        exchange(ref_request, -3.0, now2, 0.002), now2 + 0.002, replier="cccc"
    )
    ref_request = core2.reference_request(now2 + 0.1)
    assert ref_request is not None
    reply = exchange(ref_request, -3.0, now2 + 0.1, 0.002)
    assert not core2.on_reference_reply(reply, now2 + 0.102, replier="dddd")
    assert core2.counters["contested"] == 1


def test_an_older_or_foreign_pose_never_replaces_the_followed_one() -> None:
    core, now = _serving()
    core.on_followed_pose(wire.encode_pose(now - 3.05, wire.Pose(7.0)), now, source="aaaa")
    assert core.counters["pose_out_of_order"] == 1 and core.followed_pose is not None
    assert core.followed_pose.pose.x == 0.5
    other = AgentId.parse("lund/lasse")  # a former reference's pose, still arriving
    core.on_followed_pose(wire.encode_pose(now, wire.Pose(8.0)), now, agent=other)
    assert core.counters["pose_other_agent"] == 1 and core.followed_pose.pose.x == 0.5


def test_an_abort_holds_the_legacy_agent_until_a_reset() -> None:
    core, now = _serving()
    assert core.on_control(b'{"command": "abort", "seq": 1, "issuer": "ctl@x"}') is not None
    outcome = core.on_datagram(wire.encode_request(1.0), PEER, now + 0.01)
    assert outcome.reply is None and core.counters["udp_requests_held"] == 1
    status = core.status(now, 0.0)
    assert status.mode == "aborted" and status.hold == "aborted"
    assert status.commands[-1].outcome == "applied"
    # Other commands are not its business; a malformed abort is still an abort.
    core.on_control(b'{"command": "start", "seq": 2, "issuer": "ctl@x", "at": 1.0}')
    assert core.status(now, 0.0).commands[-1].outcome == "ignored"
    # A reset for another experiment's participants leaves it held.
    core.on_control(b'{"command": "reset", "seq": 3, "issuer": "ctl@x", "experiment": "dock",'
                    b' "participants": ["lab3/a"]}')  # fmt: skip
    assert core.aborted and "not a participant of dock" in core.status(now, 0.0).commands[-1].detail
    core.on_control(b'{"command": "reset", "seq": 4, "issuer": "ctl@x"}')
    assert core.status(now, 0.0).mode == "unmanaged"
    core.on_followed_pose(wire.encode_pose(now - 2.99, wire.Pose(0.5)), now + 0.02, source="aaaa")
    assert core.on_datagram(wire.encode_request(1.0), PEER, now + 0.02).reply is not None
    core.on_control(b'{"command": "abort", "seq": "not a number"}')
    assert core.aborted and core.counters["control_malformed"] == 1
    # A malformed command naming its issuer and seq is reported, so ctl can say why.
    core.on_control(b'{"command": "reset", "seq": 9, "issuer": "ctl@x", "colour": "red"}')
    last = core.status(now, 0.0).commands[-1]
    assert (last.seq, last.outcome) == (9, "malformed") and "colour" in last.detail


def test_the_bridges_own_request_coming_back_is_dropped() -> None:
    # --peer the bridge itself: its own request was answered, its own reply accepted,
    # and a legacy agent that does not exist was published.
    core, now = _serving()
    request = core.legacy_request(now)
    outcome = core.on_datagram(request, PEER, now + 0.0001)
    assert outcome.reply is None and outcome.kind == "self"
    assert core.counters["udp_self"] == 1


def test_a_wild_first_reply_is_not_published() -> None:
    # The first reply, 1000 s off, had been published; followers then dropped every
    # genuine pose as out of order for 1000 s.
    core = BridgeCore(config())
    now = 100.0
    published = []
    for i in range(8):
        request = wire.decode_request(core.legacy_request(now))
        offset = CLOCK_OFFSET + (1000.0 if i == 0 else 0.0)
        data = wire.encode_reply(request, now + 0.0005 + offset, wire.Pose(*LEGACY_POSE))
        outcome = core.on_datagram(data, PEER, now + 0.001)
        if outcome.pose is not None:
            published.append(wire.decode_pose(outcome.pose).t)
        now += 0.1
    assert published and all(abs(t - (100.0 + CLOCK_OFFSET)) < 1.0 for t in published)
    assert published == sorted(published)


def test_a_legacy_agent_that_restarts_is_counted_and_its_new_poses_published() -> None:
    # Its clock jumped back within legacy_timeout: the step is the agents' to see too
    # (their own sync with it; a reference's ends a ctl run), the bridge publishes on.
    core = BridgeCore(config())
    now = sync_core(core, legacy=CLOCK_OFFSET, reference=-3.0)
    published, restart = [], now
    for _ in range(6):  # its clock restarts near 0
        request = wire.decode_request(core.legacy_request(now))
        t2 = 1.0 + (now - restart) + 0.0005
        outcome = core.on_datagram(wire.encode_reply(request, t2, wire.Pose()), PEER, now + 0.001)
        if outcome.pose is not None:
            published.append(wire.decode_pose(outcome.pose).t)
        now += 0.1
    assert core.counters["legacy_restarted"] == 1
    assert published and all(t < 2.0 for t in published)  # on its new clock
    assert core.maintain(now).legacy_alive  # its token stays: one session, as before


def test_with_the_papers_estimator_the_legacy_pose_is_published_as_clocks_drift() -> None:
    # The gate compared each reply with the frozen mean: at 30 ppm it stopped publishing
    # after about a minute, and the agents following the legacy leader held.
    core = BridgeCore(config(estimator="mean"))
    now, drift, silent = 100.0, 30e-6, 0
    for _ in range(3000):  # 300 s
        request = wire.decode_request(core.legacy_request(now))
        legacy_clock = now + CLOCK_OFFSET + drift * (now - 100.0)
        data = wire.encode_reply(request, legacy_clock + 0.0005, wire.Pose(*LEGACY_POSE))
        silent = 0 if core.on_datagram(data, PEER, now + 0.001).pose is not None else silent + 1
        now += 0.1
    assert silent == 0


def test_a_followed_agent_that_restarts_is_not_a_contest_for_a_leader_bridge() -> None:
    core = BridgeCore(config(role="leader"))
    core.on_liveliness(liveliness(LEADER), alive=True)
    core.on_followed_pose(wire.encode_pose(1.0, wire.Pose()), 10.0, source="aaaa")
    core.on_liveliness(liveliness(LEADER), alive=False)
    core.on_liveliness(liveliness(LEADER), alive=True)
    core.on_followed_pose(wire.encode_pose(0.5, wire.Pose()), 10.5, source="bbbb")
    assert core.counters["contested"] == 0 and core.followed_pose is not None


def test_a_status_naming_another_agent_is_not_taken() -> None:
    core = BridgeCore(config(follow=None))
    ghost = status_line("aaa/ghost", "leader")
    core.on_status(ghost, agent=AgentId.parse("oslo/olle"))  # an insider's forgery
    core.on_liveliness(liveliness("aaa/ghost"), alive=True)
    core.on_liveliness(liveliness(LEADER), alive=True)
    core.on_status(status_line(LEADER, "leader"), agent=AgentId.parse(LEADER))
    assert core.maintain(0.1).follow == AgentId.parse(LEADER)
    assert core.counters["status_not_its_own"] == 1
    core.on_status(b"[" * 100_000 + b"]" * 100_000, agent=AgentId.parse(LEADER))
    assert core.counters["status_malformed"] == 1


# -- who is heard, and how many requests are answered ------------------------------------
def test_the_token_bucket_allows_a_burst_then_its_rate() -> None:
    bucket = TokenBucket(rate=10.0, burst=3)
    assert [bucket.take(5.0) for _ in range(4)] == [True, True, True, False]
    assert not bucket.take(5.05)  # half a token
    assert bucket.take(5.1) and not bucket.take(5.1)  # one period: one more
    assert [bucket.take(105.0) for _ in range(4)] == [True, True, True, False]  # full, no more
    assert not bucket.take(100.0) and not bucket.take(105.0)  # a clock gone back mints none
    assert bucket.take(105.1)
    steady = TokenBucket(rate=10.0, burst=1)  # exactly at its rate: every one allowed
    assert all(steady.take(200.0 + i * 0.1) for i in range(100))


def test_requests_over_the_rate_limit_get_no_reply_and_are_counted() -> None:
    # A forged 8-byte request drew a 64-byte reply (and the followed pose) every time:
    # an amplifier aimed at the legacy agent's host, as fast as the forger sent.
    core, now = _serving(request_rate_limit=10.0, request_burst=3)  # one token taken
    outcomes = [core.on_datagram(wire.encode_request(1.0), PEER, now + 0.01) for _ in range(5)]
    assert [o.reply is not None for o in outcomes] == [True, True, False, False, False]
    dropped = outcomes[-1]
    assert dropped.kind == "rate limited" and dropped.pose is None
    assert "--request-rate-limit 10/s (--request-burst 3)" in (dropped.rejected or "")
    assert core.counters["udp_rate_limited"] == 3
    # A tenth of a second later, one more is answered.
    later = [core.on_datagram(wire.encode_request(1.0), PEER, now + 0.12) for _ in range(2)]
    assert [o.reply is not None for o in later] == [True, False]
    status = core.status(now + 0.12, 0.0)
    assert status.counters["udp_rate_limited"] == 4
    assert status.counters["udp_requests_served"] == 4


def test_the_legacy_agents_own_rate_and_catch_up_are_answered_by_default() -> None:
    # The paper's agents request every 100 ms; one two seconds late sends 20 at once.
    cfg = config()
    assert (cfg.request_rate_limit, cfg.request_burst) == (50.0, 20)
    core, now = _serving()
    for i in range(600):  # a minute at 10 Hz
        t = now + 0.1 * i
        core.on_followed_pose(wire.encode_pose(t - 3.0, wire.Pose(0.5)), t, source="aaaa")
        assert core.on_datagram(wire.encode_request(t), PEER, t).reply is not None
    t = now + 62.0
    core.on_followed_pose(wire.encode_pose(t - 3.0, wire.Pose(0.5)), t, source="aaaa")
    answered = [core.on_datagram(wire.encode_request(t), PEER, t).reply for _ in range(21)]
    assert all(answered[:20]) and answered[20] is None
    assert core.counters["udp_rate_limited"] == 1


def test_requests_that_get_no_reply_anyway_spend_no_token() -> None:
    core, now = _serving(request_burst=2)  # one token taken
    core.on_control(b'{"command": "abort", "seq": 1, "issuer": "ctl@x"}')
    for _ in range(10):
        assert core.on_datagram(wire.encode_request(1.0), PEER, now).kind == "held"
    core.on_control(b'{"command": "reset", "seq": 2, "issuer": "ctl@x"}')
    assert core.on_datagram(wire.encode_request(1.0), PEER, now).reply is not None
    assert core.counters["udp_rate_limited"] == 0 and core.counters["udp_requests_held"] == 10


def test_with_request_port_requests_from_another_port_are_dropped() -> None:
    # Any process on the legacy agent's host, from any port, was answered as the agent.
    core, now = _serving(request_port=9005, request_burst=2)  # one token taken
    other = core.on_datagram(wire.encode_request(1.0), ("127.0.0.1", 40000), now)
    assert other.reply is None and other.kind == "foreign"
    assert "port 40000" in (other.rejected or "") and "--request-port 9005" in (
        other.rejected or ""
    )
    assert core.counters["udp_requests_foreign_port"] == 1
    # Dropped before the rate limit: the legacy agent's own request still has its token.
    assert core.on_datagram(wire.encode_request(1.0), ("127.0.0.1", 9005), now).reply is not None
    assert core.counters["udp_rate_limited"] == 0


def test_without_request_port_requests_from_any_port_of_the_peer_host_are_answered() -> None:
    # The paper's two channels: the legacy agent may request from a port other than --peer.
    core, now = _serving()
    outcome = core.on_datagram(wire.encode_request(1.0), ("127.0.0.1", 40000), now)
    assert outcome.reply is not None


def test_replies_only_from_peer_address_and_port() -> None:
    # A reply from another port of the legacy agent's host fed the sync estimate and was
    # published as the legacy agent's pose; the bridge's requests only go to --peer.
    core = BridgeCore(config())
    t1 = wire.decode_request(core.legacy_request(10.0))
    data = wire.encode_reply(t1, 10.0 + CLOCK_OFFSET, wire.Pose())
    other = core.on_datagram(data, ("127.0.0.1", 9002), 10.001)
    assert other.kind == "foreign" and other.pose is None
    assert "port 9002" in (other.rejected or "") and "--peer 127.0.0.1:9001" in (
        other.rejected or ""
    )
    assert core.counters["udp_replies_foreign_port"] == 1
    # Not matched to the request: the genuine reply from --peer still is (not a duplicate).
    genuine = core.on_datagram(data, PEER, 10.002)
    assert genuine.rejected == "not yet confirmed by the estimate"
    assert core.legacy.client.accepted == 1


def test_with_reply_port_replies_are_taken_from_that_port_only() -> None:
    # A legacy agent answering from another socket than the one the requests reach was
    # never heard: --reply-port names it.
    core = BridgeCore(config(reply_port=9002))
    t1 = wire.decode_request(core.legacy_request(10.0))
    data = wire.encode_reply(t1, 10.0 + CLOCK_OFFSET, wire.Pose())
    from_peer = core.on_datagram(data, PEER, 10.001)
    assert from_peer.kind == "foreign" and "--reply-port 9002 only" in (from_peer.rejected or "")
    core.on_datagram(data, ("127.0.0.1", 9002), 10.002)
    assert core.legacy.client.accepted == 1


@pytest.mark.parametrize("size", [wire.REQUEST_SIZE, wire.REPLY_SIZE, 7])
def test_datagrams_from_another_host_are_dropped(size: int) -> None:
    core, now = _serving()
    outcome = core.on_datagram(b"\x00" * size, ("127.0.0.2", PEER[1]), now)
    assert outcome.reply is None and outcome.kind == "foreign"
    assert "not the legacy agent's host (--peer 127.0.0.1:9001)" in (outcome.rejected or "")
    assert core.counters["udp_foreign"] == 1 and core.counters["udp_malformed"] == 0


def test_a_peer_given_by_name_is_compared_as_resolved() -> None:
    core = BridgeCore(config(peer="legacy.example:9001"), peer=PEER)
    outcome = core.on_datagram(b"\x00" * 3, ("127.0.0.9", 9001), 1.0)
    assert "--peer legacy.example:9001 (127.0.0.1:9001)" in (outcome.rejected or "")
    assert core.on_datagram(b"\x00" * 3, PEER, 1.0).kind == "malformed"  # heard
