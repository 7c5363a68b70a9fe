"""Agents hosted together in one process, for the runtime's tests of what they share
(sync links, pose feeds): their configurations, a loop that runs them for a while,
and a sync reply made by hand from a chosen replier."""

from __future__ import annotations

import threading
from typing import Any

from federation.core import wire
from federation.core.keys import AgentId
from federation.core.sync import serve
from federation.runtime.agent import AgentRuntime, run_together
from federation.runtime.links import SyncLink
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


def run_for(agents: list[AgentRuntime], seconds: float) -> None:
    stop = threading.Event()
    timer = threading.Timer(seconds, stop.set)
    timer.start()
    try:
        run_together(agents, stop, spread=0.05)
    finally:
        timer.cancel()


class _Bytes:
    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data

    def __len__(self) -> int:
        return len(self.data)


class Reply:
    """What ``_on_sync_reply`` reads of a zenoh.Reply."""

    def __init__(self, payload: bytes, attachment: bytes, replier: str):
        self.ok = type("Ok", (), {"payload": _Bytes(payload), "attachment": _Bytes(attachment)})
        self.replier_id = type("Replier", (), {"zid": replier})


def reply(link: SyncLink, t1: float, replier: str) -> Reply:
    """The reply of ``replier`` (a session id) to a request on ``link`` sent at ``t1``."""
    request = link.client.request(t1)
    served = serve(request, t1 + 5.0, wire.Pose(), t1 + 5.0)
    return Reply(served.payload, served.attachment, replier)
