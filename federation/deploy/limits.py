"""What a generated router lets one authenticated session send: which keys, how large
a message on each, and how often its agents' pose and status.

The access rules (``generate.access_control``) say who may write a key; these limits
bound what a writer with the right to write can cost everyone else, derived from the
protocol's own messages (docs/protocol.md):

=============  ==============================  =========================================
key            its messages                    limit
=============  ==============================  =========================================
``pose``       56 bytes and a 24-byte stamp    :data:`SMALL_LIMIT` (1 KiB)
``sync``       8-byte query, 64-byte reply     :data:`SMALL_LIMIT`
                and an 8-byte send time
``status``     JSON: up to 7 KiB and 550 bytes :func:`status_limit`: 8 KiB and 640 bytes
               per peer it reports             per other agent of the federation
``role``       JSON: a claim on the leader's   :data:`ROLE_LIMIT` (1 KiB)
               role, about 400 bytes
everything     collect's chunks and manifests, :func:`message_limit`: the federation's
else           control commands, statuses      (a chunk and 64 KiB), or a status if larger
=============  ==============================  =========================================

Zenoh's low-pass filter applies the smallest limit among the rules a key matches, to
payload and attachment together, and drops a message over it silently at the router's
ingress: the first router an oversized message meets is the last. Rates are capped per
agent, at its own lab's router, for the keys an agent publishes on its own:
:func:`pose_rate_cap` and :func:`status_rate_cap` (twice what its settings need, never
under 100 and 10 Hz), :data:`ROLE_RATE_CAP` for its role messages. A rate rule is one
budget per transport and key, so each of a lab's agents gets rules naming its own keys:
on its session they cap it alone, and on the lab link (where another lab's agents share
one transport) they match nothing, since no other lab may write them. What crosses the
link from one agent is thus at most
``pose_rate_cap x 1 KiB + status_rate_cap x status_limit + ROLE_RATE_CAP x ROLE_LIMIT``
a second, plus its replies to the queries it is sent.
"""

from __future__ import annotations

from typing import Any

from schemas.federation import FederationFile

__all__ = [
    "AGENT_TOPICS",
    "ROLE_LIMIT",
    "ROLE_RATE_CAP",
    "SMALL_LIMIT",
    "downsampling",
    "low_pass_filter",
    "message_limit",
    "pose_rate_cap",
    "status_limit",
    "status_rate_cap",
]

AGENT_TOPICS = ("pose", "sync", "status", "recordings", "role")
"""The keys under an agent's own (its liveliness token) that it writes: its pose, its
sync queryable, its status, its recordings for ``fedlab collect`` and its claims on the
leader's role (in an experiment that names a stand-in)."""

ROLE_RATE_CAP = 20.0
"""Hz: role messages go every 0.1 s (``federation.core.standin.PERIOD``); twice that."""

SMALL_LIMIT = 1024
"""Bytes of payload and attachment on a pose or sync key: the protocol's largest there
is 80 (a pose and its stamp), the rest is room for a later field."""

ROLE_LIMIT = SMALL_LIMIT
"""Bytes of a role message: a claim's fields and its reason (about 400; 887 with names
of 65 characters and a reason of 400)."""

STATUS_BASE = 8192
STATUS_PER_PEER = 640
"""Bytes of a status message: the agent's own fields and one entry per peer. At their
longest (every counter at a billion, eight commands logged, peers' names of 30
characters) they take 6.4 KiB and 550 bytes (tests/unit/runtime/test_status_limit.py);
a leader reports every agent of the federation as a peer."""

POSE_RATE_FLOOR = 100.0
STATUS_RATE_FLOOR = 10.0
DEFAULT_POSE_RATE = 20.0  # AgentConfig.pose_rate
DEFAULT_STATUS_PERIOD = 1.0  # AgentConfig.status_period


def status_limit(fed: FederationFile) -> int:
    """Bytes a status may take: room for every other agent of the federation as a peer
    (a leader reports each agent it syncs with)."""
    agents = sum(len(entry.agents) for entry in fed.labs.values())
    return STATUS_BASE + STATUS_PER_PEER * max(agents - 1, 0)


def message_limit(fed: FederationFile) -> int:
    """Bytes of the largest message a generated process accepts (its
    ``max_message_size``): the federation's, or a leader's status if that is larger
    (from about 140 agents on)."""
    return max(fed.message_limit, status_limit(fed))


def pose_rate_cap(settings: dict[str, Any]) -> float:
    """Poses a second an agent with these settings may send: twice its ``pose_rate``."""
    return max(POSE_RATE_FLOOR, 2.0 * float(settings.get("pose_rate", DEFAULT_POSE_RATE)))


def status_rate_cap(settings: dict[str, Any]) -> float:
    """Status messages a second: twice what its ``status_period`` makes."""
    period = float(settings.get("status_period", DEFAULT_STATUS_PERIOD))
    return max(STATUS_RATE_FLOOR, 2.0 / period)


def low_pass_filter(fed: FederationFile) -> list[dict[str, Any]]:
    """The router's ``low_pass_filter`` section: every message of the federation on
    ingress, the smallest matching limit applying."""
    prefix = f"fedlab/{fed.federation}"
    messages = ["put", "delete", "query", "reply"]

    def rule(id_: str, topics: list[str], limit: int) -> dict[str, Any]:
        keys = [f"{prefix}/*/*/{topic}" for topic in topics] if topics else [f"{prefix}/**"]
        return {
            "id": id_,
            "flows": ["ingress"],
            "messages": messages,
            "key_exprs": keys,
            "size_limit": limit,
        }

    return [
        rule("pose-and-sync", ["pose", "sync"], SMALL_LIMIT),
        rule("status", ["status"], status_limit(fed)),
        rule("role", ["role"], ROLE_LIMIT),
        rule("everything", [], message_limit(fed)),
    ]


def downsampling(fed: FederationFile, lab: str) -> list[dict[str, Any]]:
    """The ``downsampling`` section of lab ``lab``'s router: one entry per agent of the
    lab, capping the rates of its pose and status."""
    prefix = f"fedlab/{fed.federation}/{lab}"
    out = []
    for name, agent in fed.labs[lab].agents.items():
        own = f"{prefix}/{name}"
        out.append(
            {
                "id": f"rates-{name}",
                "flows": ["ingress"],
                "messages": ["put"],
                "rules": [
                    {"key_expr": f"{own}/pose", "freq": pose_rate_cap(agent.settings)},
                    {"key_expr": f"{own}/status", "freq": status_rate_cap(agent.settings)},
                    {"key_expr": f"{own}/role", "freq": ROLE_RATE_CAP},
                ],
            }
        )
    return out
