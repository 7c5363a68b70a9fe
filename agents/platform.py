"""Choosing an agent's pose source: ``--platform kinematic|knatte|pinocchio|FILE|serial:PORT``."""

from __future__ import annotations

from agents.kinematic import KinematicPlatform, Platform

__all__ = ["make_platform", "validate_platform_spec"]


def validate_platform_spec(spec: str) -> str:
    """Check a platform spec at config load (a missing preset or port fails here)."""
    if spec == "kinematic":
        return spec
    if spec.startswith("serial:"):
        if not spec[len("serial:") :]:
            raise ValueError("serial platform needs a port: serial:/dev/ttyUSB0")
        return spec
    from schemas.platform import load_platform

    try:
        load_platform(spec)  # a ConfigError (a ValueError) naming the file and the field
    except ValueError as error:
        raise ValueError(f"{error} (other choices: kinematic, serial:PORT)") from None
    return spec


def make_platform(spec: str, seed: int = 0, rate: float = 20.0) -> Platform:
    """The pose source named by ``spec``; ``rate`` (Hz) for a kinematic one."""
    if spec == "kinematic":
        return KinematicPlatform(rate=rate)
    if spec.startswith("serial:"):
        from agents.serial.platform import SerialPlatform

        return SerialPlatform(spec[len("serial:") :])
    from agents.simulated import SimulatedPlatform
    from schemas.platform import load_platform

    return SimulatedPlatform(load_platform(spec), seed=seed)
