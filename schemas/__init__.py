"""Validated models for fedlab's configuration files and messages."""

from schemas.config import (
    AgentConfig,
    ConfigError,
    RouterConfig,
    ZenohOptions,
    load_model,
)
from schemas.messages import PeerStatus, Status
from schemas.platform import PlatformConfig

__all__ = [
    "AgentConfig",
    "ConfigError",
    "PeerStatus",
    "PlatformConfig",
    "RouterConfig",
    "Status",
    "ZenohOptions",
    "load_model",
]
