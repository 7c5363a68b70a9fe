"""Recording channel names (federation/core/channels.py) and the estimator list
(federation/core/estimators.py): one list each, used by the configuration too."""

from __future__ import annotations

import typing

import pytest
from pydantic import ValidationError

from federation.core.channels import CHANNEL_FIELDS, Channel
from federation.core.estimators import ESTIMATORS, make_estimator
from schemas.config import AgentConfig


def test_channel_names_are_the_recorded_topics() -> None:
    assert [str(c) for c in Channel] == [
        "/pose/sent", "/pose/received", "/sync/exchange", "/reference", "/truth",
        "/control", "/status",
    ]  # fmt: skip
    assert set(CHANNEL_FIELDS) == set(Channel)


def test_a_channel_is_its_name() -> None:
    assert isinstance(Channel.STATUS, str) and Channel("/status") is Channel.STATUS
    assert f"{Channel.STATUS}" == "/status"
    assert {"/status": 1}[Channel.STATUS] == 1  # recordings read back by plain names


def test_every_channel_carries_its_times() -> None:
    for channel, fields in CHANNEL_FIELDS.items():
        assert "host_monotonic" in fields, channel
        assert len(set(fields)) == len(fields), channel


def test_the_config_takes_channel_names_and_refuses_others() -> None:
    config = AgentConfig(lab="a", name="b", role="leader", record_channels=["/status"])
    assert config.record_channels == [Channel.STATUS]
    with pytest.raises(ValidationError, match="record_channels"):
        AgentConfig(lab="a", name="b", role="leader", record_channels=["/pose"])


def test_the_config_offers_exactly_the_estimators() -> None:
    field = AgentConfig.model_fields["estimator"]
    assert typing.get_args(field.annotation) == ESTIMATORS
    for name in ESTIMATORS:
        assert AgentConfig(lab="a", name="b", role="leader", estimator=name).estimator == name
        make_estimator(name)
    with pytest.raises(ValueError, match="unknown estimator"):
        make_estimator("kalman")
