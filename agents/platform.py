"""The platforms an agent flies: the :class:`Platform` protocol and choosing one.

``--platform kinematic|knatte|pinocchio|FILE|serial:PORT`` (checked at config load by
:func:`schemas.platform.validate_platform_spec`):

- ``kinematic``: :class:`~agents.kinematic.KinematicPlatform`, the pose is the command;
- a preset or a platform file: :class:`~agents.simulated.SimulatedPlatform`, simulated
  dynamics and sensors under the GNC chain (:mod:`agents.gnc`);
- ``serial:PORT``: :class:`~agents.serial.platform.SerialPlatform`, a real platform's
  avionics under the same GNC chain, built from ``preset`` (default ``knatte``).
"""

from __future__ import annotations

from agents.interface import Platform, PlatformError

__all__ = ["DEFAULT_SERIAL_PRESET", "Platform", "PlatformError", "make_platform"]

DEFAULT_SERIAL_PRESET = "knatte"
"""The GNC preset of a ``serial:PORT`` platform when none is given."""


def make_platform(
    spec: str, seed: int = 0, rate: float = 20.0, preset: str | None = None
) -> Platform:
    """The pose source named by ``spec``.

    Parameters
    ----------
    spec : str
        ``kinematic``, a preset name, a platform file or ``serial:PORT``.
    seed : int
        Seed of a simulated platform's sensor noise.
    rate : float
        Steps per second of a kinematic platform, Hz (the others run at their preset's
        ``control.rate``).
    preset : str, optional
        GNC preset (name or file) of a ``serial:PORT`` platform; None:
        :data:`DEFAULT_SERIAL_PRESET`.

    Raises
    ------
    PlatformError
        A serial port that cannot be opened.
    schemas.base.ConfigError
        A preset that cannot be loaded.
    """
    from schemas.platform import load_platform

    if spec == "kinematic":
        from agents.kinematic import KinematicPlatform

        return KinematicPlatform(rate=rate)
    if spec.startswith("serial:"):
        from agents.serial.platform import SerialPlatform

        config = load_platform(preset or DEFAULT_SERIAL_PRESET)
        return SerialPlatform(spec[len("serial:") :], config)
    from agents.simulated import SimulatedPlatform

    return SimulatedPlatform(load_platform(spec), seed=seed)
