"""federation.core.endpoints: a Zenoh endpoint checked as text, its port above all."""

from __future__ import annotations

import pytest

from federation.core.endpoints import endpoint_problem


@pytest.mark.parametrize(
    "endpoint",
    [
        "tcp/127.0.0.1:7447",
        "tls/kiruna.example.org:7447",
        "tcp/[::]:7447",
        "udp/[::1]:0",
        "quic/host:7447?prio=1",
        "tcp/127.0.0.1:7447#iface=eth0",
        "unixsock-stream//tmp/zenoh.sock",
        "serial//dev/ttyUSB0#baudrate=115200",
    ],
)
def test_a_well_formed_endpoint_has_no_problem(endpoint: str) -> None:
    assert endpoint_problem(endpoint) is None


@pytest.mark.parametrize(
    ("endpoint", "said"),
    [
        ("tcp/127.0.0.1", "no port: write tcp/127.0.0.1:PORT, e.g. tcp/127.0.0.1:7447"),
        ("tls/host:", "no port: write tls/host:PORT, e.g. tls/host:7447"),
        ("tcp/[::1]", "no port: write tcp/[::1]:PORT, e.g. tcp/[::1]:7447"),
        ("tcp/127.0.0.1#iface=eth0", "no port: write tcp/127.0.0.1:PORT"),
        ("tcp/127.0.0.1:http", "the port is a number from 0 to 65535, not 'http'"),
        ("tcp/127.0.0.1:65536", "the port is a number from 0 to 65535, not '65536'"),
        ("tcp/::1:7447", "an IPv6 address goes in brackets, e.g. tcp/[::1]:7447"),
        ("tcp/[::1:7447", "'[::1:7447' opens a bracket it does not close"),
        ("tcp/[::1]7447", "expected :PORT after [::1]"),
        ("tcp/:7447", "no host before :7447"),
        ("127.0.0.1:7447", "expected PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447"),
        ("tcp/", "expected PROTOCOL/ADDRESS"),
    ],
)
def test_a_malformed_endpoint_says_what_is_missing(endpoint: str, said: str) -> None:
    problem = endpoint_problem(endpoint)
    assert problem is not None and problem.startswith(said), problem
