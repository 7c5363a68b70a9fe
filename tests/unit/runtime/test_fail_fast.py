"""Failing fast on an unreachable router (federation/runtime/session.py): why, named."""

from __future__ import annotations

import socket

import zenoh

from federation.fleet.launch import free_port
from federation.runtime.session import (
    ConnectError,
    build_config,
    connect_error,
    diagnose,
    endpoints,
    fail_fast,
)
from schemas.config import ZenohOptions


def test_a_closed_port_is_refused() -> None:
    assert diagnose(f"tcp/127.0.0.1:{free_port()}").startswith("connection refused")


def test_a_listening_port_that_is_not_zenoh_says_so() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        assert "no Zenoh session" in diagnose(f"tcp/127.0.0.1:{port}")
        assert "TLS" in diagnose(f"tls/127.0.0.1:{port}")


def test_an_unknown_host_and_other_protocols() -> None:
    assert diagnose("tcp/no-such-host.invalid:7447").startswith("cannot resolve")
    assert diagnose("udp/127.0.0.1:7447") == "no answer on udp/127.0.0.1:7447"


def test_the_error_names_every_endpoint_and_the_timeout() -> None:
    closed = f"tcp/127.0.0.1:{free_port()}"
    conf = build_config(ZenohOptions(connect=[closed]), default_mode="client")
    fail_fast(conf, 2.5)
    assert endpoints(conf) == [closed]
    error = connect_error(conf, "Timeout!", 2.5)
    assert isinstance(error, ConnectError)
    assert f"{closed}: connection refused" in str(error) and "within 2.5 s" in str(error)


def test_fail_fast_makes_zenoh_give_up() -> None:
    conf = build_config(ZenohOptions(connect=[f"tcp/127.0.0.1:{free_port()}"]), "client")
    fail_fast(conf, 0.5)
    try:
        zenoh.open(conf).close()
    except zenoh.ZError as error:
        assert "Unable to connect" in str(error)
    else:
        raise AssertionError("a session opened on a closed port")
