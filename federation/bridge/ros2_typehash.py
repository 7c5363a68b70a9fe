"""ROS 2 type hashes (RIHS01) of the messages the bridge speaks, and the DDS USER_DATA
that announces them.

Since Iron, a ROS 2 node puts ``typehash=RIHS01_<64 hex>;`` in the USER_DATA QoS of
each of its DDS readers and writers (``rmw_dds_common``'s
``encode_type_hash_for_user_data_qos``); tools such as ``ros2 topic info -v`` show it,
and a type description service can be asked for it. The hash is the ROS Interface
Hashing Standard version 1 (REP-2011, ``rosidl_generator_type_description``):

1. the type's description, a ``type_description_interfaces/msg/TypeDescription``: the
   type's own fields, then every type it refers to (transitively), sorted by name; each
   field is ``{name, type: {type_id, capacity, string_capacity, nested_type_name}}``
   (default values left out);
2. written as JSON with Python's ``json.dumps(..., separators=(", ", ": "))``, keys in
   that order, ASCII;
3. ``RIHS01_`` + the SHA-256 of those bytes, in hex.

Comments and constants of a ``.msg`` are not in the hash, so it is the same for every
distribution whose definition of the fields is the same (Iron, Jazzy, Kilted for the
types here). The field lists below are the ``.msg`` files' (``ros2_types`` writes the
same structures as DDS types). Pure: no I/O.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

__all__ = [
    "BOOL",
    "ODOMETRY",
    "STRING_MESSAGE",
    "TF_MESSAGE",
    "TYPES",
    "type_description",
    "type_hash",
    "user_data",
]

ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
BOOL = "std_msgs/msg/Bool"
STRING_MESSAGE = "std_msgs/msg/String"

# type_description_interfaces/msg/FieldType: the ids of the field types used here.
NESTED = 1
INT32 = 6
UINT32 = 7
DOUBLE = 11
BOOLEAN = 15
STRING = 17
ARRAY = 48  # added to a type id: fixed-size array of it
UNBOUNDED_SEQUENCE = 144  # added to a type id: sequence<it>

Field = tuple[str, int, int, str]
"""(name, type id, capacity, nested type name); string capacity is 0 for every field here."""

_TIME = "builtin_interfaces/msg/Time"
_HEADER = "std_msgs/msg/Header"
_POINT, _QUATERNION = "geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion"
_VECTOR3, _POSE = "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Pose"
_TWIST, _TRANSFORM = "geometry_msgs/msg/Twist", "geometry_msgs/msg/Transform"


def _doubles(*names: str) -> list[Field]:
    return [(n, DOUBLE, 0, "") for n in names]


TYPES: Mapping[str, list[Field]] = {
    _TIME: [("sec", INT32, 0, ""), ("nanosec", UINT32, 0, "")],
    _HEADER: [("stamp", NESTED, 0, _TIME), ("frame_id", STRING, 0, "")],
    _POINT: _doubles("x", "y", "z"),
    _VECTOR3: _doubles("x", "y", "z"),
    _QUATERNION: _doubles("x", "y", "z", "w"),
    _POSE: [("position", NESTED, 0, _POINT), ("orientation", NESTED, 0, _QUATERNION)],
    "geometry_msgs/msg/PoseWithCovariance": [
        ("pose", NESTED, 0, _POSE),
        ("covariance", DOUBLE + ARRAY, 36, ""),
    ],
    _TWIST: [("linear", NESTED, 0, _VECTOR3), ("angular", NESTED, 0, _VECTOR3)],
    "geometry_msgs/msg/TwistWithCovariance": [
        ("twist", NESTED, 0, _TWIST),
        ("covariance", DOUBLE + ARRAY, 36, ""),
    ],
    ODOMETRY: [
        ("header", NESTED, 0, _HEADER),
        ("child_frame_id", STRING, 0, ""),
        ("pose", NESTED, 0, "geometry_msgs/msg/PoseWithCovariance"),
        ("twist", NESTED, 0, "geometry_msgs/msg/TwistWithCovariance"),
    ],
    _TRANSFORM: [("translation", NESTED, 0, _VECTOR3), ("rotation", NESTED, 0, _QUATERNION)],
    "geometry_msgs/msg/TransformStamped": [
        ("header", NESTED, 0, _HEADER),
        ("child_frame_id", STRING, 0, ""),
        ("transform", NESTED, 0, _TRANSFORM),
    ],
    TF_MESSAGE: [
        (
            "transforms",
            NESTED + UNBOUNDED_SEQUENCE,
            0,
            "geometry_msgs/msg/TransformStamped",
        )
    ],
    BOOL: [("data", BOOLEAN, 0, "")],
    STRING_MESSAGE: [("data", STRING, 0, "")],
}
"""The fields of each type, in ``.msg`` order."""


def _individual(name: str, types: Mapping[str, list[Field]]) -> dict[str, Any]:
    return {
        "type_name": name,
        "fields": [
            {
                "name": field,
                "type": {
                    "type_id": type_id,
                    "capacity": capacity,
                    "string_capacity": 0,
                    "nested_type_name": nested,
                },
            }
            for field, type_id, capacity, nested in types[name]
        ],
    }


def type_description(name: str, types: Mapping[str, list[Field]] = TYPES) -> dict[str, Any]:
    """The hashed form of ``name``'s TypeDescription: its fields and, sorted by name,
    those of every type it refers to (raises KeyError for a type not in ``types``)."""
    referenced: set[str] = set()
    queue = [f[3] for f in types[name] if f[3]]
    while queue:
        nested = queue.pop()
        if nested not in referenced:
            referenced.add(nested)
            queue.extend(f[3] for f in types[nested] if f[3])
    return {
        "type_description": _individual(name, types),
        "referenced_type_descriptions": [_individual(n, types) for n in sorted(referenced)],
    }


def type_hash(name: str, types: Mapping[str, list[Field]] = TYPES) -> str:
    """``RIHS01_`` and the SHA-256 (hex) of ``name``'s description as ROS 2 writes it."""
    text = json.dumps(type_description(name, types), ensure_ascii=True, separators=(", ", ": "))
    return "RIHS01_" + hashlib.sha256(text.encode("utf-8")).hexdigest()


def user_data(name: str) -> bytes:
    """The USER_DATA a ROS 2 endpoint of type ``name`` announces: ``typehash=RIHS01_...;``."""
    return f"typehash={type_hash(name)};".encode("ascii")
