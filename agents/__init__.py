"""Platforms, dynamics and GNC.

The models (dynamics, sensors, navigation, control, the GNC chain, guidance, the serial
codec and the emulated device) do no I/O and read no clock: time comes in as an
argument. The serial platform and the pseudo-terminal loop of the device emulator
(:mod:`agents.serial.pty`) are the only modules here that touch a port.

Every platform flies the one GNC chain (:mod:`agents.gnc`): the simulated ones
(:mod:`agents.simulated`) and the real ones over a serial link
(:mod:`agents.serial.platform`) differ only in where measurements come from and
where valve commands go. :mod:`agents.platform` holds the protocol the runtime drives.

Rule: imports only :mod:`federation.core`, :mod:`schemas` and :mod:`agents`; never
Zenoh, the runtime or the CLI (import-linter contracts in pyproject.toml).
"""

from agents.guidance import ReferenceManeuver, track_heading
from agents.kinematic import KinematicPlatform
from agents.platform import Platform

__all__ = ["KinematicPlatform", "Platform", "ReferenceManeuver", "track_heading"]
