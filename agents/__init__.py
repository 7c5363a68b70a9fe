"""Platforms, dynamics and GNC.

The models (dynamics, sensors, navigation, control, the GNC chain, guidance, the serial
codec and the emulated device) do no I/O and read no clock: time comes in as an
argument. The serial platform and the pseudo-terminal loop of the device emulator
(:mod:`agents.serial.pty`) are the only modules here that touch a port.
"""

from agents.guidance import ReferenceManeuver, track_heading
from agents.kinematic import KinematicPlatform
from agents.platform import Platform

__all__ = ["KinematicPlatform", "Platform", "ReferenceManeuver", "track_heading"]
