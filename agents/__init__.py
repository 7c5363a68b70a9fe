"""Platforms, dynamics and GNC. Nothing here does I/O or reads a clock:
time comes in as an argument."""

from agents.guidance import ReferenceManeuver, track_heading
from agents.kinematic import KinematicPlatform, Platform

__all__ = ["KinematicPlatform", "Platform", "ReferenceManeuver", "track_heading"]
