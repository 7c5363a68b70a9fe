"""Platforms, dynamics and GNC.

The models (dynamics, sensors, navigation, control, guidance, the serial codec)
do no I/O and read no clock: time comes in as an argument. The serial platform
and the device emulator are the only modules here that touch a port.
"""

from agents.guidance import ReferenceManeuver, track_heading
from agents.kinematic import KinematicPlatform, Platform

__all__ = ["KinematicPlatform", "Platform", "ReferenceManeuver", "track_heading"]
