"""Key space of a federation (federation/keys.py)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.core import keys
from federation.core.keys import (
    DEFAULT_FEDERATION,
    ROOT,
    AgentId,
    agent_key,
    all_agents,
    all_of,
    parse_agent_key,
    validate_name,
)

KNATTE = AgentId("kiruna", "knatte")
PINOCCHIO = AgentId("rome", "pinocchio")

VALID_NAMES = ["a", "0", "knatte", "lab-1", "lab_2", "a-b_c-9", "-", "_", "x" * 63, "default"]
INVALID_NAMES = [
    pytest.param("", id="empty"),
    pytest.param("x" * 64, id="64 chars"),
    pytest.param("Knatte", id="uppercase first"),
    pytest.param("kNATTE", id="uppercase"),
    pytest.param("a/b", id="slash"),
    pytest.param("/", id="only slash"),
    pytest.param("*", id="star"),
    pytest.param("**", id="double star"),
    pytest.param("lab*", id="trailing star"),
    pytest.param("$", id="dollar"),
    pytest.param("$*", id="dollar star"),
    pytest.param("a b", id="space inside"),
    pytest.param(" a", id="leading space"),
    pytest.param("a ", id="trailing space"),
    pytest.param("a\n", id="trailing newline"),
    pytest.param("a.b", id="dot"),
    pytest.param("a?b", id="question mark"),
    pytest.param("a#b", id="hash"),
    pytest.param("kirunå", id="non-ascii"),
    pytest.param("ｋ", id="fullwidth"),
]


@pytest.mark.parametrize("name", VALID_NAMES)
def test_valid_names(name: str) -> None:
    assert validate_name(name) == name


@pytest.mark.parametrize("name", INVALID_NAMES)
def test_invalid_names(name: str) -> None:
    with pytest.raises(ValueError) as info:
        validate_name(name, "lab name")
    message = str(info.value)
    assert "invalid lab name" in message
    assert repr(name) in message


@pytest.mark.parametrize("value", [None, 5, b"abc", ["abc"]])
def test_non_string_names_rejected_with_value_error(value: object) -> None:
    with pytest.raises(ValueError, match="invalid name"):
        validate_name(value)  # type: ignore[arg-type]


def test_name_length_boundary() -> None:
    assert validate_name("a" * 63) == "a" * 63
    with pytest.raises(ValueError):
        validate_name("a" * 64)


@given(st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789-_", min_size=1, max_size=63))
def test_any_name_from_the_alphabet_is_valid(name: str) -> None:
    assert validate_name(name) == name


NAME_CHARS = st.text(alphabet="abcxyz019-_", max_size=20)


@given(NAME_CHARS, st.sampled_from(list("/*$ A?#.@\n")), NAME_CHARS)
def test_names_with_key_expression_characters_are_invalid(
    before: str, bad: str, after: str
) -> None:
    with pytest.raises(ValueError):
        validate_name(before + bad + after)


# ------------------------------------------------------------------ AgentId


def test_agent_id_fields_and_str() -> None:
    assert KNATTE.lab == "kiruna"
    assert KNATTE.name == "knatte"
    assert str(KNATTE) == "kiruna/knatte"


def test_agent_id_validates_both_parts() -> None:
    with pytest.raises(ValueError, match="invalid lab name"):
        AgentId("Kiruna", "knatte")
    with pytest.raises(ValueError, match="invalid agent name"):
        AgentId("kiruna", "knatte*")


def test_agent_id_is_frozen_hashable_and_ordered() -> None:
    with pytest.raises(AttributeError):
        KNATTE.lab = "rome"  # type: ignore[misc]
    assert {KNATTE, AgentId("kiruna", "knatte")} == {KNATTE}
    assert sorted([PINOCCHIO, KNATTE]) == [KNATTE, PINOCCHIO]
    assert AgentId("a", "b") < AgentId("a", "c")


def test_agent_id_parse() -> None:
    assert AgentId.parse("kiruna/knatte") == KNATTE
    assert AgentId.parse("rome/pinocchio") == PINOCCHIO


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("knatte", "expected LAB/NAME"),
        ("", "expected LAB/NAME"),
        ("/knatte", "invalid lab name"),
        ("kiruna/", "invalid agent name"),
        ("kiruna/knatte/pose", "invalid agent name"),
        ("Kiruna/knatte", "invalid lab name"),
        ("kiruna/kn atte", "invalid agent name"),
        ("kiruna/*", "invalid agent name"),
        ("*/knatte", "invalid lab name"),
        ("kiruna/$knatte", "invalid agent name"),
    ],
)
def test_agent_id_parse_errors(text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        AgentId.parse(text)


def test_agent_id_parse_error_quotes_the_text() -> None:
    with pytest.raises(ValueError, match="'knatte'"):
        AgentId.parse("knatte")


@given(
    st.text(alphabet="abcxyz019-_", min_size=1, max_size=20),
    st.text(alphabet="abcxyz019-_", min_size=1, max_size=20),
)
def test_agent_id_str_parse_round_trip(lab: str, name: str) -> None:
    agent = AgentId(lab, name)
    assert AgentId.parse(str(agent)) == agent


# --------------------------------------------------------------------- keys


def test_constants() -> None:
    assert ROOT == "fedlab"
    assert DEFAULT_FEDERATION == "default"


def test_agent_key() -> None:
    assert agent_key("default", KNATTE) == "fedlab/default/kiruna/knatte"
    assert agent_key("esa", PINOCCHIO, "pose") == "fedlab/esa/rome/pinocchio/pose"
    assert agent_key("esa", PINOCCHIO, "sync") == "fedlab/esa/rome/pinocchio/sync"
    assert agent_key("esa", PINOCCHIO, "status") == "fedlab/esa/rome/pinocchio/status"


def test_agent_key_empty_topic_is_the_token() -> None:
    assert agent_key("esa", KNATTE, "") == "fedlab/esa/kiruna/knatte"
    assert agent_key("esa", KNATTE, None) == "fedlab/esa/kiruna/knatte"


@pytest.mark.parametrize("federation", ["", "Esa", "a/b", "*", "**", "$x", "a b"])
def test_agent_key_validates_federation(federation: str) -> None:
    with pytest.raises(ValueError, match="invalid federation name"):
        agent_key(federation, KNATTE)


def test_all_agents() -> None:
    assert all_agents("default") == "fedlab/default/*/*"
    assert all_agents("esa") == "fedlab/esa/*/*"


def test_all_of() -> None:
    assert all_of("default", "pose") == "fedlab/default/*/*/pose"
    assert all_of("esa", "status") == "fedlab/esa/*/*/status"


@pytest.mark.parametrize("federation", ["", "ESA", "a/b", "*", "$"])
def test_all_agents_and_all_of_validate_federation(federation: str) -> None:
    with pytest.raises(ValueError, match="invalid federation name"):
        all_agents(federation)
    with pytest.raises(ValueError, match="invalid federation name"):
        all_of(federation, "pose")


# ---------------------------------------------------------- parse_agent_key


def test_parse_agent_key_token() -> None:
    assert parse_agent_key("default", "fedlab/default/kiruna/knatte") == (KNATTE, None)


@pytest.mark.parametrize("topic", ["pose", "sync", "status"])
def test_parse_agent_key_topic(topic: str) -> None:
    assert parse_agent_key("esa", f"fedlab/esa/rome/pinocchio/{topic}") == (PINOCCHIO, topic)


@pytest.mark.parametrize("topic", [None, "pose", "sync", "status"])
def test_parse_agent_key_inverts_agent_key(topic: str | None) -> None:
    key = agent_key("esa", KNATTE, topic)
    assert parse_agent_key("esa", key) == (KNATTE, topic)


def test_parse_agent_key_accepts_non_str_keys() -> None:
    class KeyExpr:  # stands in for zenoh.KeyExpr, which converts with str()
        def __str__(self) -> str:
            return "fedlab/default/kiruna/knatte/pose"

    assert parse_agent_key("default", KeyExpr()) == (KNATTE, "pose")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "key",
    [
        "fedlab/other/kiruna/knatte",  # another federation
        "fedlab/other/kiruna/knatte/pose",
        "zenoh/default/kiruna/knatte",  # another root
        "Fedlab/default/kiruna/knatte",
        "fedlab/default/kiruna",  # too short
        "fedlab/default",
        "fedlab",
        "",
        "fedlab/default/kiruna/knatte/pose/extra",  # too long
        "fedlab/default/Kiruna/knatte",  # invalid names
        "fedlab/default/kiruna/KNATTE/pose",
        "fedlab/default/*/*",  # a key expression, not a concrete key
        "fedlab/default/*/*/pose",
        "fedlab/default//knatte",
        "/fedlab/default/kiruna/knatte",
        "@/router/kiruna",
    ],
)
def test_parse_agent_key_foreign_keys(key: str) -> None:
    assert parse_agent_key("default", key) is None


def test_parse_agent_key_rejects_empty_topic() -> None:
    assert parse_agent_key("default", "fedlab/default/kiruna/knatte/") is None


def test_control_is_not_a_lab_name() -> None:
    # A lab's keys, fedlab/<fed>/<lab>/**, would take in fedlab/<fed>/control.
    with pytest.raises(ValueError, match="reserved"):
        keys.validate_lab("control")
    with pytest.raises(ValueError, match="reserved"):
        keys.AgentId.parse("control/x")
    assert keys.validate_name("control", "agent name") == "control"
