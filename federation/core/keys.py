"""Key space of a federation.

Every key fedlab uses is built here, so the layout is written down once::

    fedlab/<federation>/<lab>/<agent>/pose     pose samples (put)
    fedlab/<federation>/<lab>/<agent>/sync     three-timestamp sync (queryable)
    fedlab/<federation>/<lab>/<agent>/status   estimates and counters (put, JSON)
    fedlab/<federation>/<lab>/<agent>          liveliness token
    fedlab/<federation>/control                execution control commands (put, JSON)

Names are lowercase letters, digits, ``-`` and ``_`` (1 to 63 characters), so no name
can smuggle a ``/``, ``*`` or ``$`` into a key expression.
"""

from __future__ import annotations

import re
import weakref
from dataclasses import dataclass

__all__ = [
    "DEFAULT_FEDERATION",
    "ROOT",
    "AgentId",
    "agent_key",
    "all_agents",
    "all_of",
    "control_key",
    "parse_agent_key",
    "validate_lab",
    "validate_name",
]

ROOT = "fedlab"
DEFAULT_FEDERATION = "default"
_NAME = re.compile(r"^[a-z0-9_-]{1,63}$")


RESERVED_LABS = frozenset({"control"})
"""Names no lab may take: a lab's keys, ``fedlab/<federation>/<lab>/**``, would take in
the federation's control key ``fedlab/<federation>/control`` (``**`` matches nothing),
so the routers' rules for a lab named ``control`` would let it publish control."""


def validate_name(value: str, what: str = "name") -> str:
    """Return ``value`` if it is a valid federation, lab or agent name, else raise ValueError."""
    if not isinstance(value, str) or not _NAME.fullmatch(value):
        raise ValueError(
            f"invalid {what} {value!r}: use 1-63 lowercase letters, digits, '-' or '_'"
        )
    return value


def validate_lab(value: str) -> str:
    """Return ``value`` if it is a valid lab name (a name, not reserved), else raise
    ValueError."""
    validate_name(value, "lab name")
    if value in RESERVED_LABS:
        raise ValueError(f"invalid lab name {value!r}: reserved for the federation's control key")
    return value


_INTERNED: weakref.WeakValueDictionary[tuple[str, str], AgentId] = weakref.WeakValueDictionary()


@dataclass(frozen=True, order=True)
class AgentId:
    """One agent's address in the federation: ``lab/name``."""

    lab: str
    name: str

    def __new__(cls, lab: str, name: str) -> AgentId:
        # One object per agent while any is in use: dicts keyed by agents then find
        # theirs by identity, without calling __eq__ (the peers table, the time
        # base and the contest watch would compare equal copies tens of thousands of
        # times a minute). Weak: made-up names leave nothing behind.
        known = _INTERNED.get((lab, name))
        return known if known is not None else super().__new__(cls)

    def __post_init__(self) -> None:
        validate_lab(self.lab)
        validate_name(self.name, "agent name")
        _INTERNED[(self.lab, self.name)] = self
        # Looked up in a dict at every time-base read (several per control step): the
        # generated hash would build a tuple each time (4 % of a lab process's Python
        # time, profiled).
        object.__setattr__(self, "_hash", hash((self.lab, self.name)))
        object.__setattr__(self, "_text", f"{self.lab}/{self.name}")

    def __hash__(self) -> int:
        return self._hash  # type: ignore[attr-defined,no-any-return]

    def __reduce__(self) -> tuple[type[AgentId], tuple[str, str]]:
        return AgentId, (self.lab, self.name)  # rebuilt, so the hash is this process's

    def __eq__(self, other: object) -> bool:
        if self is other:
            return True
        if other.__class__ is not AgentId:
            return NotImplemented
        return self.lab == other.lab and self.name == other.name

    @classmethod
    def parse(cls, text: str) -> AgentId:
        """Parse ``"lab/name"``."""
        lab, sep, name = text.partition("/")
        if not sep:
            raise ValueError(f"invalid agent {text!r}: expected LAB/NAME, e.g. kiruna/knatte")
        return cls(lab, name)

    def __str__(self) -> str:
        return self._text  # type: ignore[attr-defined,no-any-return]


def agent_key(federation: str, agent: AgentId, topic: str | None = None) -> str:
    """Key of one agent (its liveliness token), or of one of its topics."""
    validate_name(federation, "federation name")
    key = f"{ROOT}/{federation}/{agent.lab}/{agent.name}"
    return f"{key}/{topic}" if topic else key


def control_key(federation: str) -> str:
    """Where execution control commands are published (JSON, see schemas.messages.Command)."""
    return f"{ROOT}/{validate_name(federation, 'federation name')}/control"


def all_agents(federation: str) -> str:
    """Key expression matching every agent's liveliness token in a federation."""
    return f"{ROOT}/{validate_name(federation, 'federation name')}/*/*"


def all_of(federation: str, topic: str) -> str:
    """Key expression matching one topic (``pose``, ``status``, ...) of every agent."""
    return f"{all_agents(federation)}/{topic}"


def parse_agent_key(federation: str, key: str) -> tuple[AgentId, str | None] | None:
    """Split a concrete key into (agent, topic); None if not an agent key of ``federation``."""
    parts = str(key).split("/")
    if len(parts) not in (4, 5) or parts[0] != ROOT or parts[1] != federation:
        return None
    if len(parts) == 5 and not parts[4]:
        return None
    try:
        agent = AgentId(parts[2], parts[3])
    except ValueError:
        return None
    return agent, (parts[4] if len(parts) == 5 else None)
