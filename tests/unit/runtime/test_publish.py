"""A pose sample's reference stamp takes the reference offset of the control step
just run: publishing evaluates no estimate again (issue 17: a lean agent)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import zenoh

from federation.core import wire
from federation.core.keys import AgentId
from federation.runtime.agent import AgentRuntime
from schemas.config import AgentConfig

LEAD = AgentId.parse("lab0/lead")


class Estimate:
    """The reference's clock 2.5 s ahead; counts how often it is evaluated."""

    def __init__(self) -> None:
        self.calls = 0

    def offset_at(self, t: float) -> float:
        self.calls += 1
        return 2.5


class Client:
    """What the agent reads of a sync client here."""

    def __init__(self) -> None:
        self.estimator = Estimate()
        self.delay = 0.001
        self.last = None


class Publisher:
    def __init__(self) -> None:
        self.sent: list[tuple[wire.PoseSample, wire.RefStamp]] = []

    def put(self, payload: bytes, *, source_info: Any, attachment: bytes) -> None:
        self.sent.append((wire.decode_pose(payload), wire.decode_stamp(attachment)))


@contextmanager
def follower(session: zenoh.Session) -> Iterator[tuple[AgentRuntime, Publisher, Estimate]]:
    """A follower of LEAD started on ``session``, its estimate of LEAD's clock and its
    pose publisher replaced."""
    agent = AgentRuntime(
        AgentConfig(lab="lab1", name="f", role="follower", follow=str(LEAD)), session
    )
    agent.start()
    try:
        agent.peer_seen(LEAD, alive=True)
        agent.peers[LEAD].client = client = Client()  # type: ignore[assignment]
        agent._pose_pub = publisher = Publisher()
        yield agent, publisher, client.estimator
    finally:
        agent.close()


def test_a_pose_is_stamped_with_the_control_steps_reference_offset(
    session: zenoh.Session,
) -> None:
    with follower(session) as (agent, publisher, estimate):
        agent.control_step()
        evaluated = estimate.calls
        agent.publish_pose()
        assert estimate.calls == evaluated  # not evaluated again
        sample, stamp = publisher.sent[-1]
        assert stamp == wire.RefStamp(agent.ref_id, sample.t + 2.5, 0.001)


def test_before_any_control_step_the_estimate_is_evaluated(session: zenoh.Session) -> None:
    with follower(session) as (agent, publisher, estimate):
        agent.publish_pose()
        assert estimate.calls == 1
        sample, stamp = publisher.sent[-1]
        assert stamp == wire.RefStamp(agent.ref_id, sample.t + 2.5, 0.001)


def test_without_a_reference_estimate_the_stamp_says_not_synchronized(
    session: zenoh.Session,
) -> None:
    with follower(session) as (agent, publisher, _):
        agent.control_step()  # an offset known at this step
        del agent.peers[LEAD]  # it left: no estimate
        agent.control_step()  # and none at this one
        agent.publish_pose()
        assert publisher.sent[-1][1] == wire.RefStamp(agent.ref_id, None, None)
