"""Who holds the leader's role, free of I/O: what the others said and the present in,
who holds (or whom to follow) out.

An experiment may name a stand-in for its leader: a simulated twin that takes the
leader's role when the leader is lost, under its own name. The role is exclusive:
at no instant do two agents each believe they hold it, and a follower follows only
the agent that holds it (or none, and holds). This module keeps that with epochs
(terms) and leases on reference time; the agents exchange :class:`Claim` messages
(every :data:`PERIOD`, and in their status).

Terms
-----
``lease`` (s): how long an acknowledgement keeps the leader's claim; ``after`` (s,
at least ``lease``): how long the leader must be silent before the stand-in claims;
``skew`` (s): the largest clock error any agent accepts: an agent whose measured
bound (its reference time's error bound) is wider holds nothing, claims nothing
and follows nobody (it fails closed). ``t`` below is an agent's reading of
reference time, ``τ`` the true instant, :math:`|t - τ| \\le` skew.

The rules
---------
Leader (:data:`LEADER_CHECKS`): it asks for its epoch (1 at first) in every
message, stamped with its ``t`` at sending (``at``). The stand-in acknowledges the
latest stamp ``A`` it heard (never one of an epoch lower than the highest it has
seen, never while it holds, never in its first :attr:`Terms.quiet` s). The leader
holds while ``t + skew < A + lease``: a leader that hears nothing from the stand-in
loses the role within ``lease`` of its last acknowledged stamp. It publishes
``until = A + lease - 2 skew``. Seeing an epoch higher than its own (the stand-in
took over), it is deposed: it asks for nothing and holds nothing until an
operator's handback (``fedlab ctl handback LAB/NAME``), after which it asks for
the highest epoch seen plus one.

Stand-in (:data:`CLAIM_CHECKS`): during a run, synchronized within ``skew``, having
heard the leader ask at least once (and having its last pose to start from), it
claims when ``t - skew - H > after``, ``H`` the latest leader stamp it heard, with
the highest epoch seen plus one. Its claim is open (``until`` none) until a
handback, which sets a release instant ``r`` (:data:`HANDOVER` ahead): it holds
while ``t + skew < r`` and publishes ``until = r - 2 skew``.

Follower (:data:`FOLLOW_CHECKS`): of the claims held that it has heard (the newest
message of each agent), a claim counts while fresh (``t + skew < at + lease``) and,
if it has an ``until``, while ``t + skew < until``; it follows the counting claim
with the highest epoch, unless a claim held with a higher epoch was seen (then it
follows none). Never two: one agent or none.

Why two agents never hold at once
---------------------------------
*Leader, then stand-in.* The leader holds at τ only if
:math:`τ \\le t + \\text{skew} < A + \\text{lease}`. The stand-in acknowledged ``A``,
so it had heard it: :math:`H \\ge A`; it claims at τ' only if
:math:`τ' \\ge t' - \\text{skew} > H + \\text{after} \\ge A + \\text{lease}`. So τ < τ'.
Message delays and losses only postpone acknowledgements (the leader's claim
lapses sooner) or the stand-in's hearing (it claims later): neither shortens the
gap. After the claim the stand-in acknowledges nothing, and the leader, seeing the
higher epoch, is deposed.

*Stand-in, then leader (handback).* The leader holds a new epoch only after an
acknowledgement of it, which the stand-in sends only once it no longer holds: the
end of one precedes the start of the other causally, whatever the clocks.

*A partition that heals.* Each side decides from what it heard: the leader cut off
lapses (no acknowledgement), the stand-in claims only after ``after`` without
hearing it. When the partition heals the leader hears the higher epoch and is
deposed; it asks again only after a handback.

*A process that restarts.* Epochs live in memory, but every message carries the
highest epoch its sender has seen, and every agent adopts the highest it hears: a
restarted leader sees it and is deposed. A restarted stand-in acknowledges nothing
for its first ``quiet = lease + 4 skew`` s: a follower may still count the open
claim of its previous life until ``at + lease`` (at most ``τ_death + lease + skew``),
and no leader's claim can start before that.

*Followers.* A follower follows the leader only while ``t_F + skew < until``:
:math:`τ < A + \\text{lease} - 2\\text{skew}`, when the leader's own test
:math:`t + \\text{skew} < A + \\text{lease}` still passes; the stand-in likewise up
to ``r - 2 skew``. A follower that follows one agent follows no other: it follows
the one with the highest epoch, or none.

``tests/unit/core/test_standin.py`` checks these on simulated time, including
random partitions, delays, losses, heals, kills and handbacks.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Literal, TypeVar

__all__ = [
    "CLAIM_CHECKS",
    "FOLLOW_CHECKS",
    "HANDOVER",
    "LEADER_CHECKS",
    "PERIOD",
    "Ack",
    "Choice",
    "Claim",
    "Keeper",
    "Kind",
    "Terms",
    "choose",
]

Kind = Literal["leader", "stand-in", "follower"]

PERIOD = 0.1
"""s between two role messages of an agent."""
HANDOVER = 1.0
"""s between a handback's receipt and the stand-in's release instant: the followers
hear the release instant before it comes."""


@dataclass(frozen=True)
class Terms:
    """The role's timing, s of reference time (see the module)."""

    # A follower counts the leader's claim until A + lease - 2 skew with A, the stamp
    # the stand-in last acknowledged, up to three link crossings and two message
    # periods old (0.32 s over 40 ms links): a 1 s lease left 0.08 s of it, and a
    # tenth of a second's stall on shared cores held the follower (role). 1.5 s
    # leaves 0.58 s.
    lease: float = 1.5
    after: float = 2.0
    skew: float = 0.2

    def __post_init__(self) -> None:
        if not (self.lease > 0 and self.skew >= 0):
            raise ValueError(f"lease must be positive and skew not negative: {self}")
        if self.after < self.lease:
            raise ValueError(f"after ({self.after} s) must be at least lease ({self.lease} s)")
        if 4 * self.skew >= self.lease:
            raise ValueError(f"skew ({self.skew} s) must be under a quarter of the lease")

    @property
    def quiet(self) -> float:
        """s a stand-in new to the federation acknowledges nothing."""
        return self.lease + 4 * self.skew


@dataclass(frozen=True)
class Ack:
    """An acknowledgement: ``agent`` asked for ``epoch`` at its ``at``, heard."""

    agent: str
    epoch: int
    at: float


@dataclass(frozen=True)
class Claim:
    """One agent's word on the role, as sent (its role message and its status)."""

    agent: str
    kind: Kind
    epoch: int
    """The epoch it holds, asks for or last held (0: none yet)."""
    at: float
    """Its reference time at sending, s."""
    holding: bool
    until: float | None = None
    """Reference time up to which a follower may count it, s (None: open)."""
    asking: bool = False
    """A leader asking for ``epoch`` to be acknowledged."""
    ack: Ack | None = None
    top: int = 0
    """The highest epoch its sender has seen."""
    follows: str | None = None
    """A follower's choice (None: none)."""
    why: str = ""
    """Why it holds or not (or, a follower, whom it follows and why)."""

    def as_dict(self) -> dict[str, object]:
        """The claim as its JSON message has it."""
        return {
            "agent": self.agent, "kind": self.kind, "epoch": self.epoch, "at": self.at,
            "holding": self.holding, "until": self.until, "asking": self.asking,
            "ack": None if self.ack is None else
            {"agent": self.ack.agent, "epoch": self.ack.epoch, "at": self.ack.at},
            "top": self.top, "follows": self.follows, "why": self.why,
        }  # fmt: skip

    @classmethod
    def from_dict(cls, data: object) -> Claim:
        """A claim from its JSON message; ValueError naming what is wrong."""
        if not isinstance(data, dict):
            raise ValueError("a role message is a JSON object")
        try:
            kind = data["kind"]
            if kind not in ("leader", "stand-in", "follower"):
                raise ValueError(f"kind {kind!r} is not leader, stand-in or follower")
            ack = data.get("ack")
            until = data.get("until")
            return cls(
                agent=str(data["agent"]), kind=kind, epoch=_int(data, "epoch"),
                at=_num(data["at"], "at"), holding=_bool(data, "holding"),
                until=None if until is None else _num(until, "until"),
                asking=_bool(data, "asking"),
                ack=None if ack is None else Ack(
                    str(ack["agent"]), _int(ack, "epoch"), _num(ack["at"], "ack.at")
                ),
                top=_int(data, "top"), follows=data.get("follows"), why=str(data.get("why", "")),
            )  # fmt: skip
        except (KeyError, TypeError) as error:
            raise ValueError(f"a role message lacks or mistypes {error}") from None


def _num(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
        raise ValueError(f"{name} must be a number, not {value!r}")
    return float(value)


def _int(data: dict[str, object], name: str) -> int:
    value = data[name]
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{name} must be a non-negative integer, not {value!r}")
    return value


def _bool(data: dict[str, object], name: str) -> bool:
    value = data[name]
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, not {value!r}")
    return value


# -- the leader and the stand-in -----------------------------------------------------
@dataclass
class Keeper:
    """The role as one agent (``kind`` leader or stand-in) keeps it; ``leader``: the
    leader's name (a stand-in's partner)."""

    me: str
    kind: Literal["leader", "stand-in"]
    leader: str
    terms: Terms = field(default_factory=Terms)
    epoch: int = 0
    top: int = 0
    holding: bool = False
    why: str = "not yet decided"
    deposed: bool = False
    """A leader that saw a higher epoch: asks again only after a handback."""
    handback: bool = False
    """A deposed leader handed the role back by an operator."""
    acked: float | None = None
    """A leader: its latest stamp acknowledged for its epoch."""
    heard: float | None = None
    """A stand-in: the latest stamp of the leader's asking it heard (and acknowledges)."""
    heard_epoch: int = 0
    release_at: float | None = None
    """A stand-in: the instant it releases the role (a handback)."""
    born: float | None = None
    """A stand-in: its reference time when it first knew it."""

    def __post_init__(self) -> None:
        if self.kind == "leader" and self.epoch == 0:
            self.epoch = self.top = 1  # the leader asks for epoch 1 from the start

    def hear(self, claim: Claim) -> None:
        """Another agent's message."""
        if claim.agent == self.me:
            return
        # Acknowledged only if no higher epoch was seen: a leader asking for an epoch
        # below one already held is not let back.
        if (
            self.kind == "stand-in"
            and claim.agent == self.leader
            and claim.asking
            and claim.epoch >= self.top
            and (self.heard is None or claim.at > self.heard)
        ):
            self.heard, self.heard_epoch = claim.at, claim.epoch
        ack = claim.ack
        if (
            self.kind == "leader"
            and ack is not None
            and ack.agent == self.me
            and ack.epoch == self.epoch
            and not self.deposed
        ):
            self.acked = ack.at if self.acked is None else max(self.acked, ack.at)
        self.top = max(self.top, claim.top, claim.epoch)

    def time_restarted(self) -> None:
        """Reference time began afresh (the reference's clock restarted, so it reads
        earlier than before): the instants heard are on another time base. They are
        forgotten, epochs kept: a stand-in hears the leader ask again before it may
        claim and keeps its quiet period again before it acknowledges; a leader asks
        for a new acknowledgement. Each only waits longer: exclusivity holds."""
        self.heard, self.heard_epoch, self.acked, self.born = None, 0, None, None
        if self.release_at is not None:
            self.release_at = None
            self.holding, self.why = False, "released the role: reference time began afresh"

    def hand_back(self, to: str, now: float | None) -> str | None:
        """An operator hands the role back to ``to``: why it changes nothing here, or
        None."""
        if to != self.leader:
            return f"{to} is not the leader {self.leader}: the role goes back to it only"
        if self.kind == "leader":
            if not self.deposed:
                return "the leader was not deposed: nothing to hand back"
            self.handback = True
            return None
        if not self.holding:
            return "the stand-in does not hold the role"
        if now is None:
            return "no reference time: the release instant cannot be set"
        if self.release_at is None:
            self.release_at = now + HANDOVER
        return None

    def tick(
        self, now: float | None, bound: float | None, running: bool = True, ready: bool = True
    ) -> Claim:
        """Decide at reference time ``now`` (None: unsynchronized) with the clock's
        error ``bound``; ``running``: a run is under way; ``ready`` (a stand-in): it has
        the leader's last pose to start from. The message to send."""
        if self.kind == "leader":
            return self._lead(now, bound)
        return self._stand_in(now, bound, running, ready)

    def _lead(self, now: float | None, bound: float | None) -> Claim:
        terms = self.terms
        if self.top > self.epoch and not self.deposed:
            self.deposed, self.acked = True, None
        if self.deposed and self.handback:
            self.deposed, self.handback, self.acked = False, False, None
            self.epoch = self.top = self.top + 1
        situation = _LeaderSituation(self, now, bound)
        self.why = _first(LEADER_CHECKS, situation) or "holds the role"
        self.holding = self.why == "holds the role"
        until = None
        if self.holding:
            assert self.acked is not None
            until = self.acked + terms.lease - 2 * terms.skew
        return Claim(
            self.me, "leader", self.epoch, now if now is not None else 0.0, self.holding,
            until=until, asking=not self.deposed and now is not None, top=self.top,
            why=self.why,
        )  # fmt: skip

    def _stand_in(
        self, now: float | None, bound: float | None, running: bool, ready: bool
    ) -> Claim:
        terms = self.terms
        if self.born is None and now is not None:
            self.born = now
        if self.holding:
            if (
                self.release_at is not None
                and now is not None
                and now + terms.skew >= self.release_at
            ):
                self.holding, self.release_at = False, None
                self.why = "released the role (handed back)"
            elif bound is None or bound > terms.skew or now is None:
                # Its clock no longer bounded: it cannot tell its claim's instants.
                self.holding, self.release_at = False, None
                self.why = "released the role: its clock's error is not bounded within skew"
        else:
            situation = _StandInSituation(self, now, bound, running, ready)
            refused = _first(CLAIM_CHECKS, situation)
            if refused is None:
                self.epoch = self.top = self.top + 1
                self.holding, self.release_at = True, None
                self.why = f"claimed epoch {self.epoch}: the leader silent past {terms.after} s"
            else:
                self.why = refused
        until = None
        if self.holding and self.release_at is not None:
            until = self.release_at - 2 * terms.skew
        ack = None
        if (
            not self.holding
            and self.heard is not None
            and now is not None
            and self.born is not None
            and now - self.born >= terms.quiet
        ):
            ack = Ack(self.leader, self.heard_epoch, self.heard)
        return Claim(
            self.me, "stand-in", self.epoch, now if now is not None else 0.0, self.holding,
            until=until, ack=ack, top=self.top, why=self.why,
        )  # fmt: skip


@dataclass(frozen=True)
class _LeaderSituation:
    keeper: Keeper
    now: float | None
    bound: float | None


@dataclass(frozen=True)
class _StandInSituation:
    keeper: Keeper
    now: float | None
    bound: float | None
    running: bool
    ready: bool


_S = TypeVar("_S")


def _first(checks: tuple[tuple[str, Callable[[_S], str | None]], ...], s: _S) -> str | None:
    for _name, check in checks:
        why = check(s)
        if why is not None:
            return why
    return None


def _unsynchronized(s: _LeaderSituation | _StandInSituation) -> str | None:
    return "no reference time: not synchronized" if s.now is None else None


def _unbounded(s: _LeaderSituation | _StandInSituation) -> str | None:
    skew = s.keeper.terms.skew
    if s.bound is None or s.bound > skew:
        shown = "unknown" if s.bound is None else f"{s.bound:.3f} s"
        return f"its clock's error bound ({shown}) exceeds the role's skew ({skew} s)"
    return None


def _deposed(s: _LeaderSituation) -> str | None:
    k = s.keeper
    if k.deposed:
        return (
            f"deposed: epoch {k.top} was claimed; it leads again only after an operator's "
            f"handback (fedlab ctl handback {k.me})"
        )
    return None


def _unacknowledged(s: _LeaderSituation) -> str | None:
    k = s.keeper
    return f"epoch {k.epoch} not acknowledged by the stand-in" if k.acked is None else None


def _lapsed(s: _LeaderSituation) -> str | None:
    k = s.keeper
    assert s.now is not None and k.acked is not None
    if s.now + k.terms.skew >= k.acked + k.terms.lease:
        return f"lease lapsed: no acknowledgement for {s.now - k.acked:.2f} s"
    return None


LEADER_CHECKS: tuple[tuple[str, Callable[[_LeaderSituation], str | None]], ...] = (
    ("unsynchronized", _unsynchronized),
    ("unbounded", _unbounded),
    ("deposed", _deposed),
    ("unacknowledged", _unacknowledged),
    ("lapsed", _lapsed),
)
"""Whether a leader holds its role: the first check that refuses says why not."""


def _not_running(s: _StandInSituation) -> str | None:
    return None if s.running else "no run under way: nothing to stand in for"


def _never_heard(s: _StandInSituation) -> str | None:
    k = s.keeper
    if k.heard is None:
        return f"never heard {k.leader} ask for the role: nothing to take over from"
    return None


def _no_pose(s: _StandInSituation) -> str | None:
    return None if s.ready else f"no pose of {s.keeper.leader} to start from"


def _leader_heard(s: _StandInSituation) -> str | None:
    k = s.keeper
    assert s.now is not None and k.heard is not None
    silent = s.now - k.terms.skew - k.heard
    if silent <= k.terms.after:
        return f"listening: {k.leader} heard {max(silent, 0.0):.2f} s ago"
    return None


CLAIM_CHECKS: tuple[tuple[str, Callable[[_StandInSituation], str | None]], ...] = (
    ("not running", _not_running),
    ("unsynchronized", _unsynchronized),
    ("unbounded", _unbounded),
    ("never heard", _never_heard),
    ("no pose", _no_pose),
    ("leader heard", _leader_heard),
)
"""Whether a stand-in that does not hold claims now: the first that refuses says why
not; none refusing, it claims the highest epoch seen plus one."""


# -- followers -----------------------------------------------------------------------
@dataclass(frozen=True)
class Choice:
    """Whom a follower follows now (None: nobody, it holds) and why."""

    holder: str | None
    epoch: int
    why: str


@dataclass(frozen=True)
class _FollowSituation:
    claims: tuple[Claim, ...]
    now: float | None
    bound: float | None
    terms: Terms

    def counts(self, c: Claim) -> bool:
        assert self.now is not None
        t = self.now + self.terms.skew
        return c.holding and t < c.at + self.terms.lease and (c.until is None or t < c.until)

    def counting(self) -> list[Claim]:
        return sorted((c for c in self.claims if self.counts(c)), key=lambda c: -c.epoch)


def _follow_unsynchronized(s: _FollowSituation) -> str | None:
    return "no reference time: not synchronized" if s.now is None else None


def _follow_unbounded(s: _FollowSituation) -> str | None:
    skew = s.terms.skew
    if s.bound is None or s.bound > skew:
        shown = "unknown" if s.bound is None else f"{s.bound:.3f} s"
        return f"its clock's error bound ({shown}) exceeds the role's skew ({skew} s)"
    return None


def _nobody(s: _FollowSituation) -> str | None:
    if s.counting():
        return None
    held = [c for c in s.claims if c.holding]
    if held:
        return "no claim holds now: " + ", ".join(
            f"{c.agent}'s epoch {c.epoch} expired" for c in sorted(held, key=lambda c: c.agent)
        )
    return "nobody claims the role"


def _superseded(s: _FollowSituation) -> str | None:
    best = s.counting()[0]
    higher = [c for c in s.claims if c.holding and c.epoch > best.epoch]
    if higher:
        c = max(higher, key=lambda c: c.epoch)
        return f"{c.agent} held epoch {c.epoch}, above {best.agent}'s {best.epoch}: following none"
    return None


FOLLOW_CHECKS: tuple[tuple[str, Callable[[_FollowSituation], str | None]], ...] = (
    ("unsynchronized", _follow_unsynchronized),
    ("unbounded", _follow_unbounded),
    ("nobody", _nobody),
    ("superseded", _superseded),
)
"""Whether a follower follows anyone: the first that refuses says why not; none
refusing, it follows the counting claim with the highest epoch."""


def choose(claims: Iterable[Claim], now: float | None, bound: float | None, terms: Terms) -> Choice:
    """Whom a follower follows at reference time ``now`` (its clock's error
    ``bound``), of ``claims`` (the newest message of each agent)."""
    s = _FollowSituation(tuple(claims), now, bound, terms)
    refused = _first(FOLLOW_CHECKS, s)
    if refused is not None:
        return Choice(None, 0, refused)
    best = s.counting()[0]
    return Choice(best.agent, best.epoch, f"{best.agent} holds epoch {best.epoch}")
