"""Zenoh configuration from the usual flags (-m, -e, -l, -c, --cfg).

fedlab's defaults, applied before the user's file and flags so either can
override them:

- multicast scouting off: labs join by explicit endpoints, never by accident;
- ``transport/unicast/lowlatency`` on and QoS off: about half the round trip of the
  default transport (../shared/zenoh-notes.md); Zenoh nodes with default settings
  still connect;
- clients retry their router forever instead of exiting, so an agent started
  before its router joins when the router comes up.
"""

from __future__ import annotations

import json
from typing import Any

import zenoh

from schemas.config import ZenohOptions

__all__ = ["ConnectError", "ZenohConfigError", "build_config"]

_DEFAULTS: dict[str, Any] = {
    "scouting/multicast/enabled": False,
    "transport/unicast/lowlatency": True,
    "transport/unicast/qos/enabled": False,
}
_CLIENT_DEFAULTS: dict[str, Any] = {
    "connect/timeout_ms": -1,
    "connect/exit_on_failure": False,
}


class ZenohConfigError(ValueError):
    """Zenoh refused a configuration; the message says which setting."""


class ConnectError(ConnectionError):
    """A network failure: no session could be opened, or the federation did not answer.

    Not a configuration error (the settings may be right and the router down).
    """


def _insert(conf: zenoh.Config, key: str, value_json5: str, source: str) -> None:
    try:
        conf.insert_json5(key, value_json5)
    except Exception as error:  # zenoh raises its own ZError
        raise ZenohConfigError(f"{source}: cannot set '{key}' to {value_json5}: {error}") from None


def build_config(
    options: ZenohOptions, default_mode: str, extra: dict[str, Any] | None = None
) -> zenoh.Config:
    """A zenoh.Config: fedlab defaults, then ``extra``, the file, then the flags."""
    conf = zenoh.Config()
    mode = options.mode or default_mode
    settings = dict(_DEFAULTS)
    if mode == "client":
        settings.update(_CLIENT_DEFAULTS)
    settings.update(extra or {})
    if options.config is not None:
        try:
            conf = zenoh.Config.from_file(str(options.config))
        except Exception as error:
            raise ZenohConfigError(f"{options.config}: not a valid Zenoh config: {error}") from None
        # The file wins over fedlab's defaults: only fill what it leaves unset.
        settings = {k: v for k, v in settings.items() if _is_unset(conf, k)}
    for key, value in settings.items():
        _insert(conf, key, json.dumps(value), "fedlab defaults")
    if options.mode or options.config is None:
        _insert(conf, "mode", json.dumps(mode), "--mode")
    if options.connect:
        _insert(conf, "connect/endpoints", json.dumps(options.connect), "--connect")
    if options.listen:
        _insert(conf, "listen/endpoints", json.dumps(options.listen), "--listen")
    for item in options.cfg:
        key, sep, value = item.partition(":")
        if not sep or not key:
            raise ZenohConfigError(
                f"--cfg {item!r}: expected KEY:VALUE, e.g. transport/link/tx/lease:3000"
            )
        _insert(conf, key, value, f"--cfg {item}")
    return conf


def _is_unset(conf: zenoh.Config, key: str) -> bool:
    try:
        return json.loads(conf.get_json(key)) is None
    except Exception:
        return True


def config_value(conf: zenoh.Config, key: str) -> Any:
    """A setting of ``conf`` as a Python value (None when unset)."""
    try:
        return json.loads(conf.get_json(key))
    except Exception:
        return None
