"""What a Foxglove scene shows of a platform and its lab, in Foxglove's own types: a
platform's footprint and name (locked to its frame), a work area's outline in the
common frame, the rotation and timestamps they carry. Pure: data in, messages out;
the live view (:mod:`federation.runtime.foxglove`) and the merged run
(:mod:`federation.report.merge`) draw with it.

The footprint is a square of side ``2 * moment_arm`` (the thrusters' lines of action)
of the platform's preset, or :data:`DEFAULT_FOOTPRINT` m when there is none
(kinematic, a ROS 2 platform). A work area's corners, :math:`p_c = R(\\theta) p_t + o`,
are drawn as a closed line in ``fedlab_common`` (:func:`area_corners`).
"""

from __future__ import annotations

import functools
import math
import re

from foxglove.messages import (
    Color,
    CubePrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from agents.workspace import Area, Frame
from federation.core.channels import COMMON_FRAME
from schemas.messages import Workspace
from schemas.platform import load_platform
from schemas.scenario import DockingConfig

__all__ = [
    "COMMON_FRAME",
    "DEFAULT_FOOTPRINT",
    "area_corners",
    "area_entity",
    "corridor_entity",
    "footprint",
    "platform_entity",
    "rotation",
    "stamp",
]

DEFAULT_FOOTPRINT = 0.3  # m, side of the square drawn for a platform with no preset
CORRIDOR_BEYOND = 0.5  # m: how far the corridor is drawn past the hold point


_PRESET = re.compile(r"[a-z0-9_-]{1,63}")


@functools.lru_cache(maxsize=64)
def footprint(platform: str) -> float:
    """Side of the square drawn for a platform (m): twice its preset's moment arm, or
    :data:`DEFAULT_FOOTPRINT` for a pose source with no preset. Only a preset's name is
    looked up (deploy/platforms/NAME.toml), never a path: the name comes from any
    agent's status, and a path there would have this host open what it names (a FIFO
    hangs the view, /dev/zero fills its memory)."""
    if platform == "kinematic" or not _PRESET.fullmatch(platform):
        return DEFAULT_FOOTPRINT
    try:
        return 2.0 * load_platform(platform).moment_arm
    except Exception:  # a preset that does not load: drawn at the default size
        return DEFAULT_FOOTPRINT


def area_corners(workspace: Workspace) -> list[tuple[float, float]]:
    """The usable area's corners in the common frame (m), counter-clockwise from
    (x_min, y_min) of the table frame: :math:`p_c = R(\\theta) p_t + o`."""
    return Frame.from_config(workspace.frame).area_to_common(Area(*workspace.area))


def stamp(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def rotation(heading: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(heading / 2), w=math.cos(heading / 2))


def platform_entity(agent: str, side: float, ns: int) -> SceneEntity:
    """A platform's footprint and name, locked to its frame."""
    half = 0.5 * side
    return SceneEntity(
        timestamp=stamp(ns),
        frame_id=agent,
        id=f"platform:{agent}",
        frame_locked=True,
        cubes=[
            CubePrimitive(
                pose=Pose(position=Vector3(z=0.025), orientation=rotation(0.0)),
                size=Vector3(x=side, y=side, z=0.05),
                color=Color(r=0.2, g=0.55, b=0.9, a=0.8),
            ),
            # A nose on the body's +x: the heading at a glance.
            CubePrimitive(
                pose=Pose(position=Vector3(x=half, z=0.05), orientation=rotation(0.0)),
                size=Vector3(x=0.3 * side, y=0.1 * side, z=0.05),
                color=Color(r=0.95, g=0.45, b=0.1, a=1.0),
            ),
        ],
        texts=[
            TextPrimitive(
                pose=Pose(position=Vector3(z=0.3), orientation=rotation(0.0)),
                billboard=True,
                font_size=14.0,
                scale_invariant=True,
                color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
                text=agent,
            )
        ],
    )


def _floor_line(
    points: list[tuple[float, float]], kind: LinePrimitiveLineType, thickness: float, color: Color
) -> LinePrimitive:
    """A line on the floor through ``points`` (m) of its entity's frame."""
    return LinePrimitive(
        type=kind,
        pose=Pose(position=Vector3(), orientation=rotation(0.0)),
        thickness=thickness,
        scale_invariant=False,
        points=[Point3(x=x, y=y, z=0.0) for x, y in points],
        color=color,
    )


def _label(x: float, y: float, text: str, color: Color) -> TextPrimitive:
    """A label just above the floor at (``x``, ``y``) of its entity's frame."""
    return TextPrimitive(
        pose=Pose(position=Vector3(x=x, y=y, z=0.05), orientation=rotation(0.0)),
        billboard=True,
        font_size=12.0,
        scale_invariant=True,
        color=color,
        text=text,
    )


def area_entity(agent: str, corners: list[tuple[float, float]], ns: int) -> SceneEntity:
    """A work area's outline in the common frame (a closed line on the floor), labelled
    with its lab at its first corner."""
    green = Color(r=0.3, g=0.85, b=0.4, a=1.0)
    return SceneEntity(
        timestamp=stamp(ns),
        frame_id=COMMON_FRAME,
        id=f"area:{agent}",
        lines=[_floor_line(corners, LinePrimitiveLineType.LineLoop, 0.02, green)],
        texts=[_label(*corners[0], f"{agent.split('/')[0]} work area", green)],
    )


def corridor_points(docking: DockingConfig) -> list[list[tuple[float, float]]]:
    """The docking corridor in the target's body frame (m), as the chaser's guidance
    checks it (:mod:`agents.docking`): its two edges, :math:`|l| = (s - L)\\tan\\alpha`
    plus the hold tolerance, from the contact point (:math:`s = L`, the contact distance
    along the port, the body's +x) to :data:`CORRIDOR_BEYOND` past the hold point; and
    the hold point's mark across the axis."""
    contact, tolerance = docking.contact_distance, docking.hold_tolerance
    hold = contact + docking.hold_distance
    far = hold + CORRIDOR_BEYOND
    slope = math.tan(math.radians(docking.corridor_deg))

    def half(s: float) -> float:
        return (s - contact) * slope + tolerance

    return [
        [(contact, tolerance), (far, half(far))],
        [(contact, -tolerance), (far, -half(far))],
        [(hold, half(hold)), (hold, -half(hold))],
    ]


def corridor_entity(docking: DockingConfig, ns: int) -> SceneEntity:
    """The docking corridor on the floor, locked to the target's frame (it moves and
    turns with the target), labelled at the hold point."""
    yellow = Color(r=0.95, g=0.8, b=0.2, a=1.0)
    hold = docking.contact_distance + docking.hold_distance
    return SceneEntity(
        timestamp=stamp(ns),
        frame_id=docking.target,
        id=f"corridor:{docking.target}",
        frame_locked=True,
        lines=[
            _floor_line(line, LinePrimitiveLineType.LineStrip, 0.01, yellow)
            for line in corridor_points(docking)
        ],
        texts=[_label(hold, 0.0, f"docking corridor of {docking.chaser}", yellow)],
    )
