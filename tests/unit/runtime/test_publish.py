"""A follower's pose sample carries its reference time, the time it was published
plus the reference's offset as its estimate gives it then, and the estimate's bound;
without an estimate, a stamp that says it is not synchronized."""

from __future__ import annotations

from typing import Any

import zenoh
from cohosted import LEAD, cohosted, follower_config

from federation.core import wire


class Estimate:
    """The reference's clock 2.5 s ahead, or unknown (None), its spread 0.25 ms."""

    def __init__(self) -> None:
        self.offset: float | None = 2.5
        self.bound = 0.00025

    def offset_at(self, t: float) -> float | None:
        return self.offset


class Client:
    """What the agent reads of a sync client here."""

    def __init__(self) -> None:
        self.estimator = Estimate()
        self.delay = 0.001
        self.last = None

    def offset_at(self, t: float) -> float | None:
        return self.estimator.offset_at(t)


class Publisher:
    def __init__(self) -> None:
        self.sent: list[tuple[wire.PoseSample, wire.RefStamp]] = []

    def put(self, payload: bytes, *, source_info: Any, attachment: bytes) -> None:
        self.sent.append((wire.decode_pose(payload), wire.decode_stamp(attachment)))


def test_a_pose_carries_its_reference_time_or_says_it_has_none(session: zenoh.Session) -> None:
    with cohosted(session, follower_config("f")) as (_, _, (agent,)):
        agent.peer_seen(LEAD, alive=True)
        client = Client()
        agent.peers[LEAD].client = client  # type: ignore[assignment]
        agent._pose_pub = publisher = Publisher()
        agent.control_step()
        agent.publish_pose()
        sample, stamp = publisher.sent[-1]
        # Its bound: the one-way delay (1 ms) plus the estimate's own spread.
        assert stamp == wire.RefStamp(agent.ref_id, sample.t + 2.5, 0.00125)
        client.estimator.offset = None  # reset: a contest, a clock step, a restart
        agent.publish_pose()  # before the next control step: not the old offset
        assert publisher.sent[-1][1] == wire.RefStamp(agent.ref_id, None, None)
