"""The platforms an agent flies: the :class:`Platform` protocol and choosing one.

``--platform SPEC`` names a platform kind registered by name
(:data:`schemas.platform.PLATFORMS`; checked at config load by
:func:`schemas.platform.validate_platform_spec`):

- ``kinematic``: :class:`~agents.kinematic.KinematicPlatform`, the pose is the command;
- a preset or a platform file: :class:`~agents.simulated.SimulatedPlatform`, simulated
  dynamics and sensors under the GNC chain (:mod:`agents.gnc`);
- ``serial:PORT``: :class:`~agents.serial.platform.SerialPlatform`, a real platform's
  avionics under the same GNC chain, built from ``preset`` (default ``knatte``);
- ``KIND`` or ``KIND:ARGUMENT``: a kind a plug-in registers
  (:func:`agents.registry.register_platform`, or a ``fedlab.platforms`` entry point).
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
        ``kinematic``, a preset name, a platform file, ``serial:PORT`` or a plug-in's
        ``KIND[:ARGUMENT]``.
    seed : int
        Seed of a simulated platform's sensor noise.
    rate : float
        Steps per second of a kinematic platform, Hz (the others run at their preset's
        ``control.rate``).
    preset : str, optional
        GNC preset (name or file) of a hardware platform (``serial:PORT``); None:
        :data:`DEFAULT_SERIAL_PRESET`.

    Raises
    ------
    PlatformError
        A serial port that cannot be opened, or a kind that builds no :class:`Platform`.
    schemas.base.ConfigError
        A preset that cannot be loaded, an unknown kind or one whose code does not load.
    """
    from schemas.platform import platform_kind

    kind, argument = platform_kind(spec)
    kind.check_spec(argument)
    platform = kind.from_spec(argument, seed=seed, rate=rate, preset=preset)
    if not isinstance(platform, Platform):
        raise PlatformError(
            f"platform kind {kind.kind!r} built a {type(platform).__qualname__}, which lacks "
            "what the Platform protocol states (agents.interface)"
        )
    return platform
