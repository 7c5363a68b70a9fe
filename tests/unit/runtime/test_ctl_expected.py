"""Whom ctl waits to hear from when no experiment names the participants."""

from __future__ import annotations

from federation.runtime import control


def test_every_agent_seen_but_a_replay_is_expected_to_confirm() -> None:
    seen = {
        "kiruna/knatte": {"platform": "knatte"},
        "rome/pinocchio": {"platform": "serial:/dev/ttyUSB0"},
        "kiruna/ghost": {"platform": "replay:kiruna-knatte.mcap"},
        "lund/old": {},  # a status without a platform: expected
    }
    assert control._expected(None, seen) == {"kiruna/knatte", "rome/pinocchio", "lund/old"}
