"""fedlab's federation layer: keys, wire codecs, sync, Zenoh session and router, CLI."""

from federation.core.keys import AgentId
from federation.core.sync import Exchange, PaperEstimator, SyncClient
from federation.core.wire import Pose, PoseSample

__all__ = ["Agent", "AgentId", "Exchange", "PaperEstimator", "Pose", "PoseSample", "SyncClient"]


def __getattr__(name: str) -> object:
    # The SDK opens Zenoh sessions: import it only when asked for (``from federation
    # import Agent``), so the command line and the pure modules stay light.
    if name == "Agent":
        from federation.runtime.sdk import Agent

        return Agent
    raise AttributeError(f"module 'federation' has no attribute {name!r}")


__version__ = "0.1.0"
