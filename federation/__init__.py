"""fedlab's federation layer: keys, wire codecs, sync, Zenoh session and router, CLI."""

from federation.keys import AgentId
from federation.sync import Exchange, PaperEstimator, SyncClient
from federation.wire import Pose, PoseSample

__all__ = ["AgentId", "Exchange", "PaperEstimator", "Pose", "PoseSample", "SyncClient"]
__version__ = "0.1.0"
