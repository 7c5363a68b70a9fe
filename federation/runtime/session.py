"""Zenoh configuration from the usual flags (-m, -e, -l, -c, --cfg).

fedlab's defaults, applied before the user's file and flags so either can
override them (a file overrides one by setting a value other than Zenoh's own
default, since Zenoh's loader fills its defaults in; a flag, by any value):

- multicast scouting off: labs join by explicit endpoints, never by accident;
- Zenoh's universal transport with QoS on (``transport/unicast/lowlatency`` off,
  ``transport/unicast/qos/enabled`` on: Zenoh's own defaults), as in the shipped
  router configs, so fedlab's nodes and a client with Zenoh's default settings get the
  same transport. Zenoh 1.10 with QoS off puts a universal link's messages in one
  queue whose congestion mark, once set, is never cleared: after the first time a
  droppable message (pose, status) waits out ``wait_before_drop``, that link drops
  every later one for good while queries and replies still pass. The low-latency
  transport (no queue) avoided it only for nodes that all asked for it; a default
  client on such a router, or any node once the routers were universal, stopped
  receiving under WAN loss (docs/deploy.md, "Transports under loss": the testbed
  runs, a loopback reproduction, and what the change costs);
- ``DATA_QUEUE_BATCHES`` transmit batches queued for data (Zenoh's default is
  two), so that a pose waiting for a busy host's transmit task is not dropped
  after a millisecond;
- clients retry their router forever instead of exiting, so an agent started
  before its router joins when the router comes up.
"""

from __future__ import annotations

import errno
import json
import logging
import socket
from typing import Any

import zenoh

from federation.core.authfail import AuthFailure, ClientTls
from federation.core.endpoints import endpoint_problem
from federation.runtime.zenoh_text import config_file_problem
from schemas.config import ZenohOptions

__all__ = [
    "DATA_QUEUE_BATCHES",
    "DEFAULT_TIMEOUT",
    "QUEUE_BATCHES_MAX",
    "ConnectError",
    "ZenohConfigError",
    "build_config",
    "connect_error",
    "diagnose",
    "endpoints",
    "examine",
    "fail_fast",
    "undeclare_all",
]

log = logging.getLogger("fedlab.session")

DATA_QUEUE_BATCHES = 16
"""Transmit batches queued for data on every link (Zenoh's default is two)."""
QUEUE_BATCHES_MAX = 16
"""The most batches Zenoh queues for one priority (the length of its transmit ring).
Its config takes any number, and then every link panics as it opens: a router with
``transport/link/tx/queue/size/data: 32`` runs and connects nothing, and its agents
wait for it for ever. :func:`build_config` refuses such a value at load."""
_QUEUE_LIMIT = f"Zenoh queues 1 to {QUEUE_BATCHES_MAX} batches per priority"

DEFAULT_TIMEOUT = 5.0
"""s a command or the SDK waits for its router before giving up."""

_DEFAULTS: dict[str, Any] = {
    "scouting/multicast/enabled": False,
    # Universal transport with QoS, as the routers and a default Zenoh client: QoS off
    # stops a congested link's pose for good (see the docstring).
    "transport/unicast/lowlatency": False,
    "transport/unicast/qos/enabled": True,
    # Sixteen batches queued for data, not Zenoh's two: on a busy host, express poses
    # waiting over a millisecond for a full queue were dropped (1 in 2000 to 3000 at 64
    # agents on 2 cores with two, none with eight; with agents ticking in groups of 8,
    # a group's replies and poses fill eight at once: docs/scale.md, "Loss on a busy host").
    "transport/link/tx/queue/size/data": DATA_QUEUE_BATCHES,
    # No shared memory: a Zenoh 1.10 process maps and locks every same-host sender's
    # pool (16 MiB, the sender's choice) for its lifetime, so each new session that
    # sends one large message grows a router and an agent by a pool for good; a message
    # in shared memory also bypasses max_message_size. fedlab's messages are 8 bytes to
    # 64 KiB and cross hosts, where shared memory never applies (docs/deploy.md,
    # "Bounded resources").
    "transport/shared_memory/enabled": False,
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
        hint = ""
        if key.startswith("transport/link/tx/queue/size"):
            hint = f" ({_QUEUE_LIMIT})"
        raise ZenohConfigError(
            f"{source}: cannot set '{key}' to {value_json5}{hint}: {error}"
        ) from None


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
            why = _invalid_because(str(error))
            raise ZenohConfigError(f"{options.config}: not a valid Zenoh config: {why}") from None
        _check_queues(conf, str(options.config))  # Zenoh's loader checks this too, today
        settings = _left_to_defaults(conf, settings, str(options.config))
    for key, value in settings.items():
        _insert(conf, key, json.dumps(value), "fedlab defaults")
    _check_queues(conf, "fedlab's settings")  # its defaults and the caller's (``extra``)
    if options.mode or options.config is None or config_value(conf, "mode") is None:
        # A file that leaves the mode unset gets the command's (Zenoh's own default is
        # peer: an agent then listened on every interface, a router ran as a peer).
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
        # Checked flag by flag: a bad size is refused even if a later flag would mend it.
        _check_queues(conf, f"--cfg {item}")
    _check_endpoints(conf, str(options.config) if options.config else "--cfg")
    return conf


def _check_endpoints(conf: zenoh.Config, source: str) -> None:
    """Refuse an endpoint of the file or a ``--cfg`` that Zenoh would take and never
    reach (``tcp/127.0.0.1``: no port), naming it and what is missing (the -e and -l
    flags are checked as they are parsed, :class:`~schemas.config.ZenohOptions`)."""
    for key in ("connect/endpoints", "listen/endpoints"):
        value = config_value(conf, key)
        listed = value.values() if isinstance(value, dict) else [value]  # per mode, or one
        for endpoint in (str(e) for items in listed for e in items or []):
            problem = endpoint_problem(endpoint)
            if problem is not None:
                raise ZenohConfigError(f"{source}: '{key}': {endpoint}: {problem}")


def _check_queues(conf: zenoh.Config, source: str) -> None:
    """Refuse a transmit queue size Zenoh would panic on (:data:`QUEUE_BATCHES_MAX`),
    naming ``source`` (the file, the flag) and the setting."""
    problem = _queue_problem(config_value(conf, "transport/link/tx/queue/size"))
    if problem is not None:
        raise ZenohConfigError(f"{source}: {problem}")


def _queue_problem(sizes: Any) -> str | None:
    """What is wrong with a ``transport/link/tx/queue/size`` table, or None."""
    if not isinstance(sizes, dict):
        return None
    for priority, value in sizes.items():
        if (
            isinstance(value, bool)
            or not isinstance(value, int)
            or not 1 <= value <= QUEUE_BATCHES_MAX
        ):
            return (
                f"'transport/link/tx/queue/size/{priority}' is {value!r}: {_QUEUE_LIMIT} "
                "(outside that, every link fails as it opens)"
            )
    return None


def _invalid_because(text: str) -> str:
    """Why Zenoh's loader refused a file. It says "Invalid configuration: " and dumps the
    whole configuration as JSON, naming no setting: the settings whose limits fedlab
    knows are named; otherwise the dump is left out."""
    prefix = "Invalid configuration: "
    if not text.startswith(prefix):
        return config_file_problem(text)  # where in the file, without Zenoh's Rust source
    try:
        dump = json.loads(text[len(prefix) :].rsplit(" at ", 1)[0])
        sizes = dump["transport"]["link"]["tx"]["queue"]["size"]
    except (ValueError, KeyError, TypeError):
        sizes = None
    return _queue_problem(sizes) or "Zenoh refused one of its settings without naming it"


def _left_to_defaults(conf: zenoh.Config, settings: dict[str, Any], path: str) -> dict[str, Any]:
    """Those of fedlab's ``settings`` that the file ``path`` (loaded as ``conf``) leaves
    to the defaults: unset, or at Zenoh's own default. Zenoh's loader fills some
    settings in (a file that names no transmit queue size has Zenoh's two batches), so
    a file cannot be told from one that sets that same value: both get fedlab's, said
    in the log (a flag, applied last, still sets any value). The file wins elsewhere."""
    zenoh_defaults = zenoh.Config()
    fill = {}
    for key, value in settings.items():
        current = config_value(conf, key)
        if current is None:
            fill[key] = value
        elif current == config_value(zenoh_defaults, key):
            fill[key] = value
            if current != value:
                log.info(
                    "%s leaves '%s' at Zenoh's %s: fedlab's %s is used "
                    "(--cfg %s:%s keeps Zenoh's)",
                    path, key, json.dumps(current), json.dumps(value), key, json.dumps(current),
                )  # fmt: skip
    return fill


def config_value(conf: zenoh.Config, key: str) -> Any:
    """A setting of ``conf`` as a Python value (None when unset)."""
    try:
        return json.loads(conf.get_json(key))
    except Exception:
        return None


def fail_fast(conf: zenoh.Config, timeout: float) -> None:
    """Make ``conf`` give up on its endpoints after ``timeout`` s instead of retrying
    for ever (commands and the SDK; agents keep waiting for their router)."""
    _insert(conf, "connect/timeout_ms", json.dumps(max(1, int(timeout * 1000))), "--timeout")
    _insert(conf, "connect/exit_on_failure", "true", "--timeout")


def endpoints(conf: zenoh.Config) -> list[str]:
    """The endpoints ``conf`` dials."""
    value = config_value(conf, "connect/endpoints")
    if isinstance(value, dict):  # per-mode endpoints: {router: [...], peer: [...], ...}
        return [e for items in value.values() for e in items or []]
    return [str(e) for e in value or []]


def _host_port(address: str) -> tuple[str, int] | None:
    address = address.split("#", 1)[0]  # endpoint metadata, e.g. #iface=eth0
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def diagnose(endpoint: str, timeout: float = 2.0, tls: ClientTls | None = None) -> str:
    """Why ``endpoint`` cannot be reached (see :func:`examine`), in words."""
    return examine(endpoint, timeout, tls)[0]


def examine(
    endpoint: str, timeout: float = 2.0, tls: ClientTls | None = None
) -> tuple[str, AuthFailure | None]:
    """Why ``endpoint`` (``tcp/host:port``, ``tls/...``) cannot be reached, probed with a
    plain TCP connection: refused, unreachable, no answer, unknown host; or, when TCP
    connects, that the failure is above it: with the client's TLS settings ``tls``, what
    a TLS handshake as that client shows (:mod:`federation.runtime.tlsprobe`: which
    certificate or login the router refuses, or the client refuses); else TLS, or not a
    Zenoh router. Returns that, and the authentication failure when it is one."""
    proto, _, address = endpoint.partition("/")
    target = _host_port(address)
    if proto not in ("tcp", "tls", "ws") or target is None:
        return f"no answer on {endpoint}", None
    try:
        with socket.create_connection(target, timeout=timeout):
            pass
    except socket.gaierror as error:
        return f"cannot resolve {target[0]} ({error.strerror})", None
    except ConnectionRefusedError:
        return "connection refused (nothing listens on that port)", None
    except TimeoutError:
        return f"no answer within {timeout:g} s (host down, or a firewall drops the packets)", None
    except OSError as error:
        if error.errno in (errno.ENETUNREACH, errno.EHOSTUNREACH):
            return f"unreachable ({error.strerror})", None
        return f"cannot connect ({error.strerror or error})", None
    if proto == "tls" and tls is not None:
        from federation.runtime.tlsprobe import probe  # cryptography: only when probing

        failure = probe(target[0], target[1], endpoint, tls, timeout)
        if failure is not None:
            return failure.message, failure
    if proto == "tls":
        return (
            "TCP connects but the TLS session failed (check the CA, the certificate and its name)",
            None,
        )
    return "TCP connects but no Zenoh session opened (is it a Zenoh router?)", None


def connect_error(
    conf: zenoh.Config, error: object, timeout: float, source: str = "the Zenoh config"
) -> ConnectError:
    """A :class:`ConnectError` naming every endpoint and why it failed (``source``: where
    ``conf`` came from, the file a TLS failure's message names)."""
    from federation.runtime.tlsprobe import client_tls

    tls = client_tls(conf, source)
    reasons = [f"{e}: {diagnose(e, min(2.0, timeout), tls)}" for e in endpoints(conf)]
    where = "; ".join(reasons) or "no endpoint to dial (give -e/--connect)"
    return ConnectError(f"no Zenoh session within {timeout:g} s: {where} [zenoh: {error}]")


def undeclare_all(declared: list[Any]) -> None:
    """Undeclare Zenoh entities, the last declared first, and empty the list.

    One that fails (its session already closed by Zenoh) is logged and skipped, so a
    close after a failed start or a lost session still releases the rest.
    """
    for entity in reversed(declared):
        try:
            entity.undeclare()
        except Exception as error:  # a session already closed by zenoh
            log.debug("undeclare failed: %s", error)
    declared.clear()
