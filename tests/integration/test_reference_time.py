"""One reference time (issue 17): a third agent joining a running two-agent
federation places the leader's and the follower's poses on reference time from the
stamps they carry, within 1 ms of the truth, without syncing with the follower.

The truth: every agent here reads the same host monotonic clock, and each one's
execution clock is linear in it (offset and drift, :func:`clock_line` from its
status lines). A pose stamped ``t`` on the follower's clock was taken at host time
``(t - a_f) / b_f``, which is ``a_l + b_l * host`` on the leader's clock, the
reference.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
import zenoh
from loopback import FLOAT_SLACK, FOLLOWER, LEADER, Labs, client_config

from federation.core import wire
from federation.core.keys import AgentId
from federation.core.wire import Pose
from federation.fleet.launch import wait_for
from federation.report.status import clock_line
from federation.runtime.sdk import Agent

pytestmark = pytest.mark.integration

THIRD = "rome/third"


def test_a_third_agent_places_everyones_pose_on_reference_time_without_pairwise_sync(
    labs: Labs,
) -> None:
    pair = labs.pair()
    leader = labs.leader(pair.kiruna, "--clock-offset", "3.0")
    follower = labs.follower(pair.rome, "--clock-offset", "26.42", "--clock-drift-ppm", "40")
    follower.wait_samples(LEADER, 30, timeout=20)  # its estimate of the reference settled

    settings: dict[str, Any] = {"clock_offset": -7.5, "clock_drift_ppm": -25.0}
    with Agent(THIRD, lambda t: Pose(), connect=[pair.rome.endpoint], reference=LEADER,
               **settings) as third:  # fmt: skip
        runtime = third._running()
        leader_id, follower_id = AgentId.parse(LEADER), AgentId.parse(FOLLOWER)
        assert wait_for(lambda: {LEADER, FOLLOWER} <= set(third.others()), timeout=15), (
            third.others(),
            runtime.counter_snapshot(),
        )
        # A few seconds of samples from both, each scored against the truth.
        stamps: dict[AgentId, set[tuple[float, float, float]]] = {
            leader_id: set(),
            follower_id: set(),
        }
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            for agent, kept in stamps.items():
                latest = runtime.peer_table.latest_ref.get(agent)
                if latest is not None:
                    kept.add(latest)
            time.sleep(0.02)
        placed = third.others()
        # It never queried the follower, nor scheduled it for pairwise sync.
        peer = runtime.peers.get(follower_id)
        assert peer is not None and peer.link is None, peer  # nor has a link to it
        assert (
            follower_id not in runtime.peer_table.pairwise
            and leader_id not in runtime.peer_table.pairwise
        )
        assert runtime.counter_snapshot().get("pose_stamp_malformed", 0) == 0

    a_l, b_l = clock_line(leader.lines())
    a_f, b_f = clock_line(follower.lines())
    errors = {}
    for agent, kept in stamps.items():
        assert len(kept) >= 20, (agent, len(kept))  # 20 Hz for 3 s
        a, b = (a_l, b_l) if agent == leader_id else (a_f, b_f)
        worst = 0.0
        for t, t_ref, bound in kept:
            truth = a_l + b_l * (t - a) / b
            worst = max(worst, abs(t_ref - truth))
            # Within the bound the stamp states (measured in this run), which on loopback
            # is its sender's one-way delay plus its estimate's spread: under 5 ms.
            assert abs(t_ref - truth) <= bound + FLOAT_SLACK, (t_ref, truth, bound)
            assert bound < 0.005, bound
            if agent == leader_id:
                assert t_ref == t and bound == 0.0  # the reference stamps its own clock
        errors[str(agent)] = worst
    print(f"worst |t_ref - truth| per sender (ms): { {k: v * 1e3 for k, v in errors.items()} }")
    assert placed[FOLLOWER][0] > 0 and placed[LEADER][0] > 0


def test_unstamped_and_malformed_stamps_from_third_parties(labs: Labs) -> None:
    """A pose without a stamp (a legacy bridge, a raw third party) makes its sender a
    pairwise sync peer; a malformed stamp drops the sample and is counted."""
    router = labs.router("kiruna")
    leader = labs.leader(router)
    leader.wait_status(timeout=15)
    with Agent(THIRD, lambda t: Pose(), connect=[router.endpoint], reference=LEADER) as third:
        runtime = third._running()
        assert wait_for(lambda: LEADER in third.others(), timeout=15)
        rogue, legacy = AgentId("lab9", "rogue"), AgentId("lab9", "legacy")
        pose = wire.encode_pose(1.0, wire.Pose())
        with zenoh.open(client_config(router.endpoint)) as session:
            for _ in range(20):  # bounded: until both have arrived
                session.put(f"fedlab/default/{rogue}/pose", pose, attachment=b"\x01\x01junk")
                session.put(f"fedlab/default/{legacy}/pose", pose)
                time.sleep(0.1)
                counters = runtime.counter_snapshot()
                if (
                    counters.get("pose_stamp_malformed", 0)
                    and legacy in runtime.peer_table.pairwise
                ):
                    break
        counters = runtime.counter_snapshot()
        assert counters.get("pose_stamp_malformed", 0) >= 1, counters
        assert rogue not in runtime.latest_poses  # dropped, never used
        assert legacy in runtime.peer_table.pairwise and rogue not in runtime.peer_table.pairwise
        assert LEADER in third.others()  # still working
