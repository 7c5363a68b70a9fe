"""Validated models for fedlab's configuration files and messages.

Pydantic models with units in every field's description; a bad file fails at load
naming the file, the field and the reason (:class:`ConfigError`). JSON Schemas of
them are exported to ``schemas/json/`` (``fedlab schemas``).

Rule: imports only :mod:`federation.core`; does no I/O beyond reading the file it
is asked to load.
"""

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
