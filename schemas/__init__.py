"""Validated models for fedlab's configuration files and messages."""

from schemas.config import (
    AgentConfig,
    ConfigError,
    PlatformConfig,
    RouterConfig,
    ZenohOptions,
    load_model,
)
from schemas.messages import PeerStatus, Status

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
