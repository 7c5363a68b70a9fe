"""The agent runtime: one platform on an open Zenoh session
(:class:`~federation.runtime.agent.runtime.AgentRuntime`), split into parts by the
state each owns (see :mod:`federation.runtime.agent.runtime`).

:func:`run_together`, :class:`Schedule` and :func:`peer_status` are importable from
here as well.
"""

from __future__ import annotations

from federation.runtime.agent.intake import MAX_SMALL_PAYLOAD
from federation.runtime.agent.peers import Peer
from federation.runtime.agent.reporting import RateLimitedLog
from federation.runtime.agent.runtime import AgentRuntime
from federation.runtime.agent.watches import NO_ROUTER_HOLD, ROUTER_CHECK_PERIOD
from federation.runtime.loop import Schedule, run_together
from federation.runtime.names import NameTaken
from federation.runtime.status import peer_status

__all__ = [
    "MAX_SMALL_PAYLOAD",
    "NO_ROUTER_HOLD",
    "ROUTER_CHECK_PERIOD",
    "AgentRuntime",
    "NameTaken",
    "Peer",
    "RateLimitedLog",
    "Schedule",
    "peer_status",
    "run_together",
]
