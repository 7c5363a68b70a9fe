"""The generated routers' size and rate limits (federation/deploy/limits.py): derived from
the protocol's messages, large enough for the largest a real agent sends, and written
into every generated router."""

from __future__ import annotations

import json
from pathlib import Path

import zenoh

from federation.core import wire
from federation.core.standin import PERIOD, Ack, Claim
from federation.deploy import generate as gen
from federation.deploy import limits
from federation.runtime import collect
from federation.runtime.agent.role import ROLE_TOPIC
from schemas.federation import load_federation

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "deploy" / "federation.example.toml"


def test_the_keys_an_agent_writes_are_the_protocols() -> None:
    assert set(limits.AGENT_TOPICS) == {"pose", "sync", "status", collect.TOPIC, ROLE_TOPIC}


def test_a_role_message_fits_its_limit_and_rate() -> None:
    """A claim with every field at its largest and a reason of 400 characters (the core's
    reasons are sentences under 150, with two agents' names)."""
    name = "a-lab-name-of-32-characters-long/an-agent-name-of-32-characters-lon"
    claim = Claim(
        agent=name, kind="stand-in", epoch=2**63, at=-1.2345678901234567e15,
        holding=True, until=-1.2345678901234567e15, asking=True,
        ack=Ack(name, 2**63, -1.2345678901234567e15), top=2**63, follows=name, why="x" * 400,
    )  # fmt: skip
    assert len(json.dumps(claim.as_dict())) <= limits.ROLE_LIMIT
    assert limits.ROLE_RATE_CAP >= 2 / PERIOD


def test_pose_and_sync_messages_fit_the_small_limit() -> None:
    stamp = wire.encode_stamp(1, 1.0, 0.001)
    pose = wire.encode_pose(1.0, wire.Pose())
    assert len(pose) + len(stamp) <= limits.SMALL_LIMIT
    assert len(wire.encode_request(1.0)) <= limits.SMALL_LIMIT
    reply = wire.encode_reply(1.0, 2.0, wire.Pose())
    assert len(reply) + 8 <= limits.SMALL_LIMIT  # and its 8-byte send time


def test_rate_caps_are_twice_what_the_settings_need_with_a_floor() -> None:
    assert limits.pose_rate_cap({}) == 100.0  # 20 Hz by default: the floor
    assert limits.pose_rate_cap({"pose_rate": 200.0}) == 400.0
    assert limits.status_rate_cap({}) == 10.0
    assert limits.status_rate_cap({"status_period": 0.05}) == 40.0


def test_every_generated_router_caps_sizes_and_its_own_agents_rates() -> None:
    fed = load_federation(EXAMPLE)
    for lab, entry in fed.labs.items():
        doc = gen.router_config(fed, lab, gen.DEFAULT_ROOT)
        assert doc["transport"]["shared_memory"] == {"enabled": False}
        assert doc["transport"]["link"]["rx"]["max_message_size"] == limits.message_limit(fed)
        sizes = {r["id"]: r["size_limit"] for r in doc["low_pass_filter"]}
        assert sizes == {
            "pose-and-sync": limits.SMALL_LIMIT,
            "status": limits.status_limit(fed),
            "role": limits.ROLE_LIMIT,
            "everything": limits.message_limit(fed),
        }
        assert all(r["flows"] == ["ingress"] for r in doc["low_pass_filter"])
        capped = {rule["key_expr"] for entry_ in doc["downsampling"] for rule in entry_["rules"]}
        assert capped == {
            f"fedlab/default/{lab}/{name}/{topic}"
            for name in entry.agents
            for topic in ("pose", "status", "role")
        }  # its own agents only: nothing that arrives over the lab link


def test_generated_clients_use_no_shared_memory() -> None:
    fed = load_federation(EXAMPLE)
    doc = gen.agent_zenoh(fed, "kiruna", "knatte", gen.DEFAULT_ROOT, None)
    assert doc["transport"]["shared_memory"] == {"enabled": False}


def test_a_zenoh_router_accepts_the_generated_limits() -> None:
    """Zenoh 1.10 takes every section as written (an unknown field fails the load)."""
    fed = load_federation(EXAMPLE)
    doc = gen.router_config(fed, "kiruna", gen.DEFAULT_ROOT)
    conf = zenoh.Config()
    for key in ("low_pass_filter", "downsampling"):
        conf.insert_json5(key, json.dumps(doc[key]))
    conf.insert_json5("transport/shared_memory/enabled", "false")
