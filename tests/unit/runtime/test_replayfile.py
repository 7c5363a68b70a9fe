"""What a replay's refusals learn of a platform: a serial (real) one, a simulated one,
and none recorded (unknown: the rules then fail closed)."""

from __future__ import annotations

from federation.core.replayplan import Target, refusals
from federation.runtime.replayfile import hardware_of


def test_a_serial_platform_is_real_and_its_identity_is_refused() -> None:
    assert hardware_of("serial:/dev/ttyUSB0") is True
    own = Target("kiruna/knatte", "kiruna/knatte", False, hardware_of("serial:/dev/ttyUSB0"))
    assert [row for row, _ in refusals(own)] == ["own_name_real"]


def test_simulated_platforms_are_not_real() -> None:
    assert hardware_of("knatte") is False
    assert hardware_of("kinematic") is False


def test_a_platform_not_recorded_is_unknown() -> None:
    assert hardware_of(None) is None
    assert hardware_of("") is None
