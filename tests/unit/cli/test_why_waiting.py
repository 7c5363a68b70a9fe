"""What a service waiting for its router says, and when (federation/cli/common.py)."""

from __future__ import annotations

import logging

import pytest
import zenoh

from federation.cli.common import _WhyWaiting
from federation.core.authfail import AuthFailure

EP = "tls/localhost:7447"


def waiting() -> _WhyWaiting:
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", f'["{EP}"]')
    why = _WhyWaiting(conf, "knatte.json5")
    why.next_probe = 1e9  # no probe thread: the findings are set by the test
    return why


def test_a_tls_failure_is_warned_at_once_and_once(caplog: pytest.LogCaptureFixture) -> None:
    why = waiting()
    failure = AuthFailure("client-ca", f"TLS to {EP} failed: the router does not trust ...")
    why.found, why.found_at = [(failure.message, failure)], 1.0
    with caplog.at_level(logging.WARNING, logger="fedlab"):
        why.poll(1.1)
        why.poll(1.2)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [f"no session with the router yet: {failure.message} (still trying)"]
    assert why.reason == failure.message


def test_a_login_refusal_waits_for_zenohs_next_try(caplog: pytest.LogCaptureFixture) -> None:
    """TLS accepted and no session: a router up a moment ago looks the same until Zenoh
    has tried again (it waits up to 4 s between tries)."""
    why = waiting()
    failure = AuthFailure("password", f"TLS to {EP} is accepted but the router closes ...")
    why.found, why.found_at = [(failure.message, failure)], 1.0
    with caplog.at_level(logging.WARNING, logger="fedlab"):
        why.poll(2.0)
        assert why.reason == "TLS accepted, no session yet" and not caplog.records
        why.poll(1.0 + _WhyWaiting.SETTLED)
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert why.reason == failure.message


def test_a_refused_connection_is_said_but_not_warned(caplog: pytest.LogCaptureFixture) -> None:
    why = waiting()
    why.found = [("connection refused (nothing listens on that port)", None)]
    with caplog.at_level(logging.WARNING, logger="fedlab"):
        why.poll(2.0)
    assert why.reason.startswith("connection refused") and not caplog.records
