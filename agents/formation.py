"""Formation flying across labs: N platforms keep slots around a virtual centre.

The virtual centre follows a circle every agent knows from the experiment
(:class:`CirclePath`, on run time). No agent commands another: each computes its own
reference from the others' shared poses (:class:`FormationGuidance`), a consensus on
where the centre is. Agent :math:`i` with slot :math:`\\mathbf{o}_i` sees the others'
poses :math:`\\mathbf{p}_j` (stamped on reference time :math:`s_j`; dead-reckoned to
now when latency compensation is on) and takes

.. math::

    \\hat{\\mathbf{c}}_i = w_0\\,\\mathbf{c}(t) + (1 - w_0)\\,\\frac{1}{|J|}
        \\sum_{j \\in J} \\big(\\mathbf{p}_j(t) - \\mathbf{o}_j\\big),
    \\qquad \\mathbf{p}_{ref,i} = \\hat{\\mathbf{c}}_i + \\mathbf{o}_i

with :math:`w_0 = 1 -` ``consensus_weight`` and :math:`J` the others whose pose is
fresher than ``stale_after``, and not stamped further ahead than that (none: the path
alone). A member's pose is taken in and let go gradually, so that one joining or
leaving does not step every other's track: with a weight :math:`a_j \\in [0, 1]` that
rises linearly over ``join_ramp`` seconds after its pose appears and falls linearly
over the last half of ``stale_after`` as it ages,

.. math::

    \\hat{\\mathbf{c}}_i = \\mathbf{c}(t) + (1 - w_0)\\,
        \\frac{\\sum_j a_j \\big(\\mathbf{p}_j(t) - \\mathbf{o}_j - \\mathbf{c}(t)\\big)}
             {\\max\\big(1, \\sum_j a_j\\big)},

which is the mean above once every :math:`a_j = 1`, and continuous in each: for a
member :math:`e` off its slot, the track moves at most :math:`(1 - w_0)\\,e / T_{join}`
as it joins (0.7 × 0.1 m / 2 s = 3.5 cm/s) and :math:`2 (1 - w_0)\\,e / t_{stale}` as
it leaves (0.14 m/s), rather than stepping by :math:`(1 - w_0)\\,e` at once. A pose's
normal age (the one-way delay and up to a pose period) must stay below half of
``stale_after`` (1 s by default; the relay case's 250 ms delay leaves room), else a
healthy member is taken at less than its full weight.

Latency compensation moves each shared pose on by its age :math:`a = t - s_j` with
its velocity and the centre's acceleration, which every member knows from the path:
:math:`\\mathbf{p}_j + \\mathbf{v}_j a + \tfrac12 \\ddot{\\mathbf{c}} a^2`,
:math:`\\mathbf{v}_j + \\ddot{\\mathbf{c}} a`. Without compensation every
received pose is one delay old, and the consensus drags the formation behind the
path by about :math:`\\frac{1 - w_0}{w_0} v \\tau` for a centre speed :math:`v`
and a delay :math:`\\tau`.

The formation error of platform :math:`i` is its distance from its slot around the
path's centre, :math:`|\\mathbf{p}_i - \\mathbf{c}(t) - \\mathbf{o}_i|`
(:func:`slot_errors`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

from agents.guidance import Reference, Track
from agents.relative import dead_reckon
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import MAX_PATH_SPEED, FormationConfig

__all__ = ["MEMBER_OFF_MAX", "CirclePath", "FormationGuidance", "PathPoint", "slot_errors"]

MEMBER_FADE = 0.2
"""m: over the last this much before :data:`MEMBER_OFF_MAX` a member's weight fades to
nothing (and over the last ``MEMBER_FADE / MEMBER_OFF_MAX`` of the speed limit alike)."""
MEMBER_OFF_MAX = 0.5
"""m: a member further than this from its slot around the path, or moving faster than
MAX_PATH_SPEED against the path, is left out of the consensus (counted): its shared pose
would move every other member's reference by ``consensus_weight`` of that at once (a
pose 3 m off, or a velocity of 1 m/s, would drive a platform across its table)."""


class PathPoint(NamedTuple):
    """The virtual centre: position (m), velocity (m/s), acceleration (m/s^2)."""

    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    ax: float = 0.0
    ay: float = 0.0


class CirclePath:
    """The centre's circle, still for ``still`` s, then speeding up over ``ramp`` s:

    .. math::

        \\theta(\\tau) = \\begin{cases} \\omega \\tau^2 / (2 T_r) & 0 \\le \\tau < T_r \\\\
            \\omega (\\tau - T_r / 2) & \\tau \\ge T_r \\end{cases}, \\qquad
        \\tau = t - t_{still}, \\quad \\omega = 2\\pi / T
    """

    def __init__(self, config: FormationConfig):
        self.c0 = config.centre
        self.radius = config.radius
        self.omega = 2.0 * math.pi / config.period
        self.still = config.still
        self.ramp = config.ramp

    @property
    def speed(self) -> float:
        """The centre's speed on the circle, m/s."""
        return self.radius * self.omega

    def __call__(self, t: float) -> PathPoint:
        tau = t - self.still
        w, r = self.omega, self.radius
        if tau <= 0:
            return PathPoint(*self.c0)
        if tau < self.ramp:
            th, dth, ddth = w * tau * tau / (2 * self.ramp), w * tau / self.ramp, w / self.ramp
        else:
            th, dth, ddth = w * (tau - self.ramp / 2), w, 0.0
        c, s = math.cos(th), math.sin(th)
        return PathPoint(
            self.c0[0] + r * (c - 1.0),
            self.c0[1] + r * s,
            -r * s * dth,
            r * c * dth,
            -r * s * ddth - r * c * dth * dth,
            r * c * ddth - r * s * dth * dth,
        )


class FormationGuidance:
    """One member's reference from the path and the others' shared poses.

    Parameters
    ----------
    me : str
        This agent (``LAB/NAME``), a key of ``config.slots``.
    config : FormationConfig
    compensate : bool
        Dead-reckon the others' poses from their stamps to now.
    """

    def __init__(self, me: str, config: FormationConfig, compensate: bool = True):
        if me not in config.slots:
            raise ValueError(f"{me} has no slot in the formation ({', '.join(config.slots)})")
        self.me = me
        self.config = config
        self.compensate = compensate
        self.path = CirclePath(config)
        self.slot = config.slots[me]
        self.heading = math.radians(config.heading_deg)
        self.used = 0
        """How many others the last reference used."""
        self.counters = {Count.MEMBERS_OFF_SLOT: 0, Count.MEMBERS_TOO_FAST: 0}
        """References that left a member out for lying too far from its slot, or moving
        too fast against the path (:data:`MEMBER_OFF_MAX`)."""
        self._since: dict[str, float] = {}  # reference time each used member appeared

    def new_run(self) -> None:
        """A run was armed: every member's pose is taken in afresh over ``join_ramp``."""
        self._since = {}

    def reference(
        self,
        t: float | None,
        run_time: float | None,
        others: Mapping[str, tuple[float, Pose]],
        frozen: bool = False,
    ) -> Reference:
        """The reference at reference time ``t`` and run time ``run_time`` (s); None
        before the run: no track (the platform keeps its position). ``frozen``: the run
        is paused, so the centre stands still where it is (no rates: a track that kept
        them would hold each platform off its point by what they ask)."""
        if t is None or run_time is None:
            return Reference(self.heading, 0.0, None)
        c = self.path(run_time)
        if frozen:
            c = PathPoint(c.x, c.y)
        cfg = self.config
        sx = sy = svx = svy = 0.0  # weighted sums of each member's difference from the path
        n, total = 0, 0.0
        since = {}
        for agent, (stamp, pose) in others.items():
            slot = cfg.slots.get(agent)
            age = t - stamp
            # A pose stamped further ahead than the stale window is no fresher than a
            # stale one: its sender's clock estimate is wrong, and it would otherwise
            # count for as long as it lies ahead once its sender went silent.
            if slot is None or agent == self.me or not -cfg.stale_after <= age <= cfg.stale_after:
                continue
            since[agent] = first = self._since.get(agent, t)
            half = cfg.stale_after / 2
            a = min(1.0, max(0.0, (t - first) / cfg.join_ramp), (cfg.stale_after - abs(age)) / half)
            if a <= 0.0:
                continue
            if self.compensate:  # on to now, with the centre's acceleration every member shares
                dt = min(max(age, 0.0), cfg.stale_after)
                pose = dead_reckon(pose, dt)._replace(
                    x=pose.x + pose.vx * dt + 0.5 * c.ax * dt * dt,
                    y=pose.y + pose.vy * dt + 0.5 * c.ay * dt * dt,
                    vx=pose.vx + c.ax * dt,
                    vy=pose.vy + c.ay * dt,
                )
            ex, ey = pose.x - slot[0] - c.x, pose.y - slot[1] - c.y
            evx, evy = pose.vx - c.vx, pose.vy - c.vy
            if not math.hypot(ex, ey) <= MEMBER_OFF_MAX:
                self.counters[Count.MEMBERS_OFF_SLOT] += 1
                del since[agent]  # taken in afresh, over join_ramp, once back
                continue
            if not math.hypot(evx, evy) <= MAX_PATH_SPEED:
                self.counters[Count.MEMBERS_TOO_FAST] += 1
                del since[agent]
                continue
            # Let go gradually near either bound: dropped at once, a member drifting
            # past it would step the others' reference by 0.35 m in one step.
            a = min(
                a,
                (MEMBER_OFF_MAX - math.hypot(ex, ey)) / MEMBER_FADE,
                (MAX_PATH_SPEED - math.hypot(evx, evy)) / (MEMBER_FADE * MAX_PATH_SPEED),
            )
            if a <= 0.0:
                continue
            sx, sy = sx + a * ex, sy + a * ey
            svx, svy = svx + a * evx, svy + a * evy
            n, total = n + 1, total + a
        self._since = since  # a member not used now appears afresh when it comes back
        self.used = n
        k = cfg.consensus_weight / max(1.0, total)
        dvx, dvy = (0.0, 0.0) if frozen else (k * svx, k * svy)
        track = Track(
            c.x + k * sx + self.slot[0],
            c.y + k * sy + self.slot[1],
            c.vx + dvx,
            c.vy + dvy,
            c.ax,
            c.ay,
        )
        return Reference(self.heading, 0.0, track)


def slot_errors(
    config: FormationConfig, run_time: float, poses: Mapping[str, Pose]
) -> dict[str, float]:
    """Each platform's distance from its slot around the path's centre at ``run_time``, m."""
    c = CirclePath(config)(run_time)
    out = {}
    for agent, pose in poses.items():
        slot = config.slots.get(agent)
        if slot is not None:
            out[agent] = math.hypot(pose.x - c.x - slot[0], pose.y - c.y - slot[1])
    return out
