"""Agents hosted together in one process, for the runtime's tests of what they share
(sync links, pose feeds): their configurations, the agents started on one session's
shared subscriptions, links and clock, a loop that runs them for a while or for a
number of one agent's ticks, and a sync reply made by hand from a chosen replier."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import zenoh

from federation.core import wire
from federation.core.keys import AgentId
from federation.core.sync import serve
from federation.runtime.agent import AgentRuntime, run_together
from federation.runtime.clock import ExecClock
from federation.runtime.fanout import Fanout
from federation.runtime.links import SyncLink, SyncLinks
from schemas.config import AgentConfig

LEAD = AgentId.parse("lab0/lead")


def leader_config(**extra: Any) -> AgentConfig:
    return AgentConfig(
        **{"lab": "lab0", "name": "lead", "role": "leader", "duration": 60.0} | extra
    )


def follower_config(name: str, **extra: Any) -> AgentConfig:
    return AgentConfig(
        **{"lab": "lab1", "name": name, "role": "follower", "follow": str(LEAD),
           "duration": 60.0} | extra
    )  # fmt: skip


@contextmanager
def cohosted(
    session: zenoh.Session, *configs: AgentConfig
) -> Iterator[tuple[Fanout, SyncLinks, list[AgentRuntime]]]:
    """Agents of ``configs`` in this process, as a lab's worker hosts them: one
    :class:`Fanout`, one :class:`SyncLinks` and one clock; started, and every one
    closed at the end (closing twice is harmless: a test may close one earlier)."""
    fanout, links, clock = Fanout(session), SyncLinks(), ExecClock()
    agents = [AgentRuntime(c, session, clock, fanout=fanout, links=links) for c in configs]
    try:
        for agent in agents:
            agent.start()
        yield fanout, links, agents
    finally:
        for agent in agents:
            agent.close()


def run_for(
    agents: list[AgentRuntime], seconds: float, stop: threading.Event | None = None
) -> None:
    """Run ``agents`` on this thread for ``seconds``, or until ``stop`` is set."""
    stop = stop or threading.Event()
    timer = threading.Timer(seconds, stop.set)
    timer.start()
    try:
        run_together(agents, stop, spread=0.05)
    finally:
        timer.cancel()


class Tally:
    """The calls an agent's loop makes of one of its periodic tasks (``task``:
    ``publish_pose`` at its pose rate, ``send_sync_requests`` at its sync rate).

    A claim about what arrives per tick of the sender holds on a host that stalls the
    process, where a claim per second of wall time does not: the loop skips the ticks
    a stall made it miss, so fewer are sent, not fewer delivered."""

    def __init__(self, agent: AgentRuntime, task: str):
        self.n = 0
        self._stop_at: tuple[int, threading.Event] | None = None
        inner: Callable[..., Any] = getattr(agent, task)

        def counted(*args: Any) -> Any:
            result = inner(*args)
            self.n += 1
            if self._stop_at is not None and self.n >= self._stop_at[0]:
                self._stop_at[1].set()
            return result

        setattr(agent, task, counted)

    def stop_at(self, n: int, stop: threading.Event) -> None:
        self._stop_at = (n, stop)


def run_ticks(agents: list[AgentRuntime], tally: Tally, n: int, timeout: float) -> None:
    """Run ``agents`` until ``tally`` has counted ``n`` more calls: ``timeout`` s at
    most, and an AssertionError if they did not come."""
    stop = threading.Event()
    target = tally.n + n
    tally.stop_at(target, stop)
    run_for(agents, timeout, stop)
    assert tally.n >= target, f"{n - (target - tally.n)} of {n} ticks within {timeout:g} s"


class Payload:
    """What the agent reads of a zenoh.ZBytes."""

    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data

    def __len__(self) -> int:
        return len(self.data)


class ControlSample:
    """What the agent's control subscriber reads of a zenoh.Sample."""

    def __init__(self, command: dict[str, Any]):
        self.payload = Payload(json.dumps(command).encode())
        self.key_expr = "fedlab/default/@control"


class Reply:
    """What ``_on_sync_reply`` reads of a zenoh.Reply."""

    def __init__(self, payload: bytes, attachment: bytes, replier: str):
        self.ok = type("Ok", (), {"payload": Payload(payload), "attachment": Payload(attachment)})
        self.replier_id = type("Replier", (), {"zid": replier})


def reply(link: SyncLink, t1: float, replier: str) -> Reply:
    """The reply of ``replier`` (a session id) to a request on ``link`` sent at ``t1``."""
    request = link.client.request(t1)
    served = serve(request, t1 + 5.0, wire.Pose(), t1 + 5.0)
    return Reply(served.payload, served.attachment, replier)
