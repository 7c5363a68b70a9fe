"""RIHS01 type hashes (federation/bridge/ros2_typehash.py) against the published ones.

The expected values are those ``rosidl_generator_c`` wrote into the ``*__description.c``
files of public ROS 2 workspaces (``..._get_type_hash`` and ``..._EXPECTED_HASH``
arrays, e.g. in a message package that nests Odometry and TFMessage): 15 types, every
one the bridge's messages are built from, so a wrong field id, capacity, order or
JSON separator anywhere would show.
"""

from __future__ import annotations

import hashlib
import json

import pytest

from federation.bridge import ros2_typehash as th

PUBLISHED = {
    "builtin_interfaces/msg/Time": (
        "b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"
    ),
    "std_msgs/msg/Header": "f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "geometry_msgs/msg/Point": "6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881",
    "geometry_msgs/msg/Vector3": "cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
    "geometry_msgs/msg/Quaternion": (
        "8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684"
    ),
    "geometry_msgs/msg/Pose": "d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
    "geometry_msgs/msg/PoseWithCovariance": (
        "9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb"
    ),
    "geometry_msgs/msg/Twist": "9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/TwistWithCovariance": (
        "49f574f033f095d8b6cd1beaca5ca7925e296e84af1716d16c89d38b059c8c18"
    ),
    "geometry_msgs/msg/Transform": (
        "beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc"
    ),
    "geometry_msgs/msg/TransformStamped": (
        "0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206"
    ),
    "nav_msgs/msg/Odometry": "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "tf2_msgs/msg/TFMessage": "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "std_msgs/msg/Bool": "feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9",
    "std_msgs/msg/String": "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
}


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_the_hash_is_the_published_one(name: str) -> None:
    assert th.type_hash(name) == "RIHS01_" + PUBLISHED[name]


def test_user_data_is_ros2s_key_value_form() -> None:
    assert th.user_data(th.ODOMETRY) == (
        b"typehash=RIHS01_" + PUBLISHED["nav_msgs/msg/Odometry"].encode() + b";"
    )
    assert th.user_data(th.TF_MESSAGE).startswith(b"typehash=RIHS01_e369d0f0")


def test_the_hashed_text_is_rosidls_json() -> None:
    """Time's description written out: keys in rosidl's order, ', ' and ': ' separators,
    no referenced types, no default values."""
    text = (
        '{"type_description": {"type_name": "builtin_interfaces/msg/Time", "fields": ['
        '{"name": "sec", "type": {"type_id": 6, "capacity": 0, "string_capacity": 0, '
        '"nested_type_name": ""}}, '
        '{"name": "nanosec", "type": {"type_id": 7, "capacity": 0, "string_capacity": 0, '
        '"nested_type_name": ""}}]}, "referenced_type_descriptions": []}'
    )
    assert hashlib.sha256(text.encode()).hexdigest() == PUBLISHED["builtin_interfaces/msg/Time"]
    assert th.type_description("builtin_interfaces/msg/Time") == json.loads(text)


def test_referenced_types_are_transitive_and_sorted() -> None:
    described = th.type_description(th.TF_MESSAGE)
    names = [t["type_name"] for t in described["referenced_type_descriptions"]]
    assert names == [
        "builtin_interfaces/msg/Time", "geometry_msgs/msg/Quaternion",
        "geometry_msgs/msg/Transform", "geometry_msgs/msg/TransformStamped",
        "geometry_msgs/msg/Vector3", "std_msgs/msg/Header",
    ]  # fmt: skip


def test_a_changed_field_changes_the_hash() -> None:
    changed = dict(th.TYPES) | {"builtin_interfaces/msg/Time": [("sec", th.INT32, 0, "")]}
    assert th.type_hash(th.ODOMETRY, changed) != th.type_hash(th.ODOMETRY)
    with pytest.raises(KeyError):
        th.type_hash("nav_msgs/msg/Path")
