"""Scenarios rehearsed in simulated time, in one process: the evidence that does not
need a network.

Each platform is a :class:`~agents.simulated.SimulatedPlatform` under its
:class:`~agents.scenario.ScenarioGuidance` (the very objects an agent runs); their
shared poses go through a modelled link (:class:`DelayLine`: a one-way delay with
half-normal jitter) at the pose rate, stamped on one common clock (perfect sync:
the real-process demo adds the sync estimate's error). Everything is seeded, so a
run is repeatable and a comparison (with and without latency compensation, fixed and
adaptive gains) sees the same noise.

- :func:`formation_run`: N platforms keep a formation around a circling centre;
- :func:`docking_run`: a chaser docks with a target from relative measurements;
- :func:`attitude_run`: the paper's experiment, followers tracking the leader's heading;
- :func:`adaptive_run`: a follower tracks a leader's heading maneuver with fixed or
  adaptive gains;
- :func:`rehearse`: any registered scenario (a plug-in's too), each agent's part given,
  its true track and counters returned.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agents.docking import FINAL, ContactState, contact_state
from agents.flown import FlownManeuver
from agents.formation import slot_errors
from agents.guidance import HeadingEstimator, Reference, ReferenceManeuver
from agents.scenario import ScenarioGuidance
from agents.scenarios.docking import Docking
from agents.simulated import SimulatedPlatform
from federation.core.angles import wrap_angle
from federation.core.counters import Count
from federation.core.wire import Pose, PoseSample
from schemas.experiment import ExperimentConfig
from schemas.platform import load_platform
from schemas.scenario import AdaptiveConfig, ScenarioPart

__all__ = [
    "DelayLine",
    "DockingOutcome",
    "adaptive_run",
    "attitude_run",
    "docking_run",
    "formation_run",
    "rehearse",
]

START = 3.0  # s of reference time before the run starts (the filters converge)


class DelayLine:
    """A one-way link: a sample sent at ``t`` arrives at ``t + delay + |N(0, jitter)|``,
    in order (a sample never overtakes the one before)."""

    def __init__(self, delay: float, jitter: float, rng: np.random.Generator):
        self.delay, self.jitter, self.rng = delay, jitter, rng
        self._queue: deque[tuple[float, PoseSample]] = deque()
        self._last_arrival = -math.inf
        self.latest: PoseSample | None = None

    def send(self, t: float, sample: PoseSample) -> None:
        arrival = t + self.delay + abs(float(self.rng.normal(0.0, self.jitter)))
        self._last_arrival = max(arrival, self._last_arrival)
        self._queue.append((self._last_arrival, sample))

    def receive(self, t: float) -> PoseSample | None:
        """The latest sample arrived by ``t``."""
        while self._queue and self._queue[0][0] <= t:
            self.latest = self._queue.popleft()[1]
        return self.latest


@dataclass
class _Member:
    name: str
    platform: Any  # SimulatedPlatform, or a FramedPlatform around one
    guidance: Callable[[float, float | None, Mapping[str, tuple[float, Pose]], Pose], Reference]
    links: dict[str, DelayLine] = field(default_factory=dict)  # to each other member
    estimate: Pose = field(default_factory=Pose)


def _run(
    members: list[_Member],
    duration: float,
    pose_rate: float,
    observe: Callable[[float, float, dict[str, _Member]], None],
    record_every: float = 0.1,
) -> None:
    """Step every member at the control rate for ``START + duration`` s of reference time."""
    rate = members[0].platform.rate
    tick = 1.0 / rate
    pose_every = max(1, round(rate / pose_rate))
    record_steps = max(1, round(record_every * rate))
    by_name = {m.name: m for m in members}
    for k in range(round((START + duration) * rate) + 1):
        t = k * tick
        run_time = t - START if t >= START else None
        for m in members:
            ref = m.guidance(t, run_time, _received(m, members, t), m.estimate)
            m.estimate = m.platform.step(t, ref.heading, ref.rate, ref.track)
        if k % pose_every == 0:
            _send_estimates(members, t)
        if run_time is not None and k % record_steps == 0:
            observe(t, run_time, by_name)


def _received(member: _Member, members: list[_Member], t: float) -> dict[str, tuple[float, Pose]]:
    """What ``member``'s links have delivered by ``t``: every other member's latest
    pose and its stamp, by name (none yet from a member nothing has come from)."""
    others = {}
    for other in members:
        if other is member:
            continue
        got = member.links[other.name].receive(t)
        if got is not None:
            others[other.name] = (got.t, got.pose)
    return others


def _send_estimates(members: list[_Member], t: float) -> None:
    """Every member's estimate, stamped ``t``, onto its link to every other member."""
    for m in members:
        for other in members:
            if other is not m:
                other.links[m.name].send(t, PoseSample(t, m.estimate))


def _links(members: list[_Member], delay: float, jitter: float, seed: int) -> None:
    rngs = iter(np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(64))
    for m in members:
        for other in members:
            if other is not m:
                m.links[other.name] = DelayLine(delay, jitter, next(rngs))


def _scenario_member(
    name: str, part: ScenarioPart, platform: SimulatedPlatform, compensate: bool
) -> _Member:
    scenario = ScenarioGuidance(name, part, platform, compensate=compensate)

    def guidance(
        t: float, run_time: float | None, others: Mapping[str, tuple[float, Pose]], own: Pose
    ) -> Reference:
        ref = scenario.reference(t, run_time, others, own)
        return ref if ref is not None else Reference()

    member = _Member(name, scenario.platform, guidance)
    member.scenario = scenario  # type: ignore[attr-defined]
    return member


def _platforms(experiment: ExperimentConfig, seed: int) -> dict[str, SimulatedPlatform]:
    out = {}
    for i, p in enumerate(experiment.participants):
        config = load_platform(p.platform)
        out[p.agent] = SimulatedPlatform(config, seed=seed * 100 + i)
    return out


# ---------------------------------------------------------------- formation


def _scenario_members(
    experiment: ExperimentConfig, delay: float, jitter: float, seed: int, compensate: bool
) -> list[_Member]:
    """Every participant as a linked member; ``seed`` shifts its platform's and its
    relative sensor's seeds, so runs with one seed repeat and runs with others differ."""
    platforms = _platforms(experiment, seed)
    members = []
    for p in experiment.participants:
        part = experiment.part(_agent(p.agent))
        assert part is not None
        sensor = part.relative_sensor.model_copy(update={"seed": part.relative_sensor.seed + seed})
        part = part.model_copy(update={"relative_sensor": sensor})
        members.append(_scenario_member(p.agent, part, platforms[p.agent], compensate))
    _links(members, delay, jitter, seed)
    return members


def formation_run(
    experiment: ExperimentConfig,
    delay: float,
    compensate: bool = True,
    seed: int = 0,
    duration: float | None = None,
    jitter: float = 0.002,
) -> dict[str, Any]:
    """The formation experiment in simulated time; returns its figures.

    Returns
    -------
    dict
        ``error_rms_m``, ``error_max_m`` (every platform's distance from its slot
        around the path's centre, on the truth, every 0.1 s of the run),
        ``per_platform`` (the same per agent), ``workspace`` (clamps and holds per
        agent), ``series`` (run time, per-agent errors and common-frame truths).
    """
    assert experiment.kind == "formation" and experiment.formation is not None
    duration = experiment.duration if duration is None else duration
    members = _scenario_members(experiment, delay, jitter, seed, compensate)
    series: dict[str, list[Any]] = {"run_time": [], "errors": [], "truth": []}
    formation = experiment.formation

    def observe(t: float, run_time: float, by_name: dict[str, _Member]) -> None:
        truths = {n: m.platform.truth for n, m in by_name.items()}
        series["run_time"].append(run_time)
        series["errors"].append(slot_errors(formation, run_time, truths))
        series["truth"].append({n: (p.x, p.y, p.heading) for n, p in truths.items()})

    _run(members, duration, 20.0, observe)
    errors = np.array([[e[m.name] for m in members] for e in series["errors"]])
    return {
        "delay_s": delay,
        "latency_compensation": compensate,
        "seed": seed,
        "error_rms_m": float(np.sqrt(np.mean(errors**2))),
        "error_max_m": float(np.max(errors)),
        "per_platform": {
            m.name: {
                "error_rms_m": float(np.sqrt(np.mean(errors[:, i] ** 2))),
                "error_max_m": float(np.max(errors[:, i])),
            }
            for i, m in enumerate(members)
        },
        "workspace": {m.name: dict(m.platform.workspace_counters) for m in members},
        "series": series,
    }


def _agent(text: str) -> Any:
    from federation.core.keys import AgentId

    return AgentId.parse(text)


# ---------------------------------------------------------------- docking


@dataclass
class DockingOutcome:
    """A docking attempt scored on the truth at the first contact (:math:`s \\le L`)."""

    success: bool
    time_s: float | None  # run time of the contact
    contact: ContactState | None  # at the contact
    phases: list[tuple[float, str]]
    counters: dict[Count, int]
    velocity_error_rms_mps: float  # chaser's Kalman velocity estimate vs truth
    velocity_error_max_mps: float
    workspace: dict[str, dict[Count, int]]
    final_lateral_rms_m: float  # chaser's true offset across the axis in the final phase

    def summary(self) -> dict[str, Any]:
        c = self.contact
        return {
            "success": self.success,
            "time_s": self.time_s,
            "contact_speed_mps": None if c is None else c.closing_speed,
            "lateral_error_m": None if c is None else abs(c.lateral),
            "heading_error_deg": None if c is None else math.degrees(abs(c.heading_error)),
            "chaser_velocity_error_rms_mps": self.velocity_error_rms_mps,
            "chaser_velocity_error_max_mps": self.velocity_error_max_mps,
            "final_lateral_rms_m": self.final_lateral_rms_m,
            "phases": self.phases,
            "counters": self.counters,
            "workspace": self.workspace,
        }


def docking_run(
    experiment: ExperimentConfig,
    delay: float,
    seed: int = 0,
    duration: float | None = None,
    jitter: float = 0.002,
    compensate: bool = True,
) -> DockingOutcome:
    """The docking experiment in simulated time, scored on the truth."""
    d = experiment.docking
    assert experiment.kind == "docking" and d is not None
    duration = experiment.duration if duration is None else duration
    members = _scenario_members(experiment, delay, jitter, seed, compensate)
    chaser = next(m for m in members if m.name == d.chaser)
    target = next(m for m in members if m.name == d.target)
    found: dict[str, Any] = {}
    verr: list[float] = []
    final: list[float] = []  # m, the chaser's lateral offset (truth) in the final phase
    scenario: ScenarioGuidance = chaser.scenario  # type: ignore[attr-defined]
    assert isinstance(scenario.scenario, Docking)
    guidance = scenario.scenario.chaser
    assert guidance is not None

    def observe(t: float, run_time: float, by_name: dict[str, _Member]) -> None:
        truth = chaser.platform.truth
        est = chaser.platform.frame.to_common(chaser.platform.inner.estimate)
        verr.append(math.hypot(est.vx - truth.vx, est.vy - truth.vy))
        if "contact" in found:
            return
        state = contact_state(truth, target.platform.truth)
        if guidance.phase == FINAL:
            final.append(state.lateral)
        if state.axial <= d.contact_distance:
            found["contact"] = state
            found["time"] = run_time

    _run(members, duration, 20.0, observe, record_every=0.01)
    c: ContactState | None = found.get("contact")
    criteria = d.contact
    success = (
        c is not None
        and c.closing_speed <= criteria.max_speed
        and abs(c.lateral) <= criteria.max_lateral
        and math.degrees(abs(c.heading_error)) <= criteria.max_heading_deg
    )
    return DockingOutcome(
        success=success,
        time_s=found.get("time"),
        contact=c,
        phases=list(guidance.events),
        counters=scenario.counters,
        velocity_error_rms_mps=float(np.sqrt(np.mean(np.square(verr)))) if verr else math.nan,
        velocity_error_max_mps=float(np.max(verr)) if verr else math.nan,
        workspace={m.name: dict(m.platform.workspace_counters) for m in members},
        final_lateral_rms_m=float(np.sqrt(np.mean(np.square(final)))) if final else math.nan,
    )


# ---------------------------------------------------------------- any scenario


def rehearse(
    parts: Mapping[str, ScenarioPart],
    platforms: Mapping[str, str],
    duration: float,
    delay: float = 0.04,
    seed: int = 0,
    jitter: float = 0.002,
    compensate: bool = True,
) -> dict[str, Any]:
    """Any registered scenario in simulated time: each agent (``LAB/NAME`` -> its part)
    flies its own simulated platform (``platforms``: agent -> preset or platform file)
    under its scenario's guidance, every other's shared pose coming over a link of
    ``delay`` s one way (``jitter`` s half-normal).

    Returns
    -------
    dict
        ``series``: ``run_time`` (s, every 0.1 s of the run) and, per agent, ``truth``
        (x, y in m and heading in rad: the common frame for a framed scenario) and
        ``x_ref``, ``y_ref`` (its position reference, None without one); ``counters``
        per agent (workspace and the scenario's, at the end).
    """
    members = []
    for i, (agent, part) in enumerate(parts.items()):
        platform = SimulatedPlatform(load_platform(platforms[agent]), seed=seed * 100 + i)
        members.append(_scenario_member(agent, part, platform, compensate))
    _links(members, delay, jitter, seed)
    series: dict[str, Any] = {"run_time": [], "truth": {}, "x_ref": {}, "y_ref": {}}
    for key in ("truth", "x_ref", "y_ref"):
        series[key] = {m.name: [] for m in members}

    def observe(t: float, run_time: float, by_name: dict[str, _Member]) -> None:
        series["run_time"].append(run_time)
        for name, m in by_name.items():
            truth = m.platform.truth
            series["truth"][name].append((truth.x, truth.y, truth.heading))
            fields = m.scenario.fields()  # type: ignore[attr-defined]
            series["x_ref"][name].append(fields["x_ref"])
            series["y_ref"][name].append(fields["y_ref"])

    _run(members, duration, 20.0, observe)
    return {
        "series": series,
        "counters": {m.name: m.scenario.counters for m in members},  # type: ignore[attr-defined]
    }


# ---------------------------------------------------------------- attitude tracking


@functools.cache
def _flown(preset: str, maneuver: ReferenceManeuver, until: float) -> FlownManeuver:
    """``maneuver`` as ``preset`` flies it (:mod:`agents.flown`) up to run time ``until``,
    flown once for every rehearsal that asks: the twin has no noise, so every seed and
    delay would fly it alike (it was more than half of a rehearsal's time)."""
    flown = FlownManeuver(maneuver, load_platform(preset), memory=until + 2.0, max_steps=1 << 30)
    flown.advance(until)
    return flown


def _profile(
    flown: FlownManeuver | None, maneuver: ReferenceManeuver, run_time: float | None
) -> Callable[[float], tuple[float, float]] | None:
    """The heading filter's input at ``run_time``: the leader's twin where the follower
    knows its preset (as the agent runtime's FollowedModel), else the maneuver."""
    if run_time is None:
        return None
    return maneuver if flown is None else flown.profile(run_time)


def attitude_run(
    experiment: ExperimentConfig,
    delay: float,
    compensate: bool = True,
    seed: int = 0,
    duration: float | None = None,
    jitter: float = 0.002,
) -> dict[str, Any]:
    """The paper's attitude-tracking experiment in simulated time: the leader flies its
    maneuver on run time, each follower tracks the heading it receives from the agent
    it follows (with ``compensate``, predicted to now by a
    :class:`~agents.guidance.HeadingEstimator` with the maneuver as the leader's preset
    flies it as its input: :mod:`agents.flown`), as the agent runtime does.

    Returns
    -------
    dict
        ``heading_error_rms_deg``, ``heading_error_max_deg``: every follower's true
        heading against its leader's true heading at the same reference time, every
        0.01 s from the maneuver's start to the run's end (before it both hold still);
        ``per_follower`` (the same per follower).
    """
    assert experiment.kind == "attitude-tracking"
    duration = experiment.duration if duration is None else duration
    m = experiment.maneuver
    maneuver = ReferenceManeuver(m.still, m.duration, math.radians(m.amplitude_deg))
    platforms = _platforms(experiment, seed)
    follows = {p.agent: p.follow for p in experiment.participants if p.follow is not None}
    presets = {p.agent: experiment.follow_preset(p) for p in experiment.participants}

    def guidance_of(agent: str) -> Callable[..., Reference]:
        followed = follows.get(agent)
        estimator = HeadingEstimator()
        preset = presets[agent]
        flown = None if preset is None else _flown(preset, maneuver, duration)

        def guidance(
            t: float, run_time: float | None, others: Mapping[str, tuple[float, Pose]], own: Pose
        ) -> Reference:
            if followed is None:  # the leader
                return Reference(*maneuver(run_time)) if run_time is not None else Reference()
            got = others.get(followed)
            if got is None:
                return Reference()
            sample = PoseSample(*got)
            profile = _profile(flown, maneuver, run_time)
            return Reference(*estimator.reference(sample, t, compensate, profile, run_time))

        return guidance

    members = [_Member(a, platforms[a], guidance_of(a)) for a in platforms]
    _links(members, delay, jitter, seed)
    errors: dict[str, list[float]] = {a: [] for a in follows}

    def observe(t: float, run_time: float, by_name: dict[str, _Member]) -> None:
        if run_time < m.still:
            return
        for agent, followed in follows.items():
            own, lead = by_name[agent].platform.truth, by_name[followed].platform.truth
            errors[agent].append(wrap_angle(own.heading - lead.heading))

    _run(members, duration, 20.0, observe, record_every=0.01)
    every = np.degrees(np.abs(np.concatenate([errors[a] for a in follows])))
    return {
        "delay_s": delay,
        "latency_compensation": compensate,
        "seed": seed,
        "heading_error_rms_deg": float(np.sqrt(np.mean(every**2))),
        "heading_error_max_deg": float(np.max(every)),
        "per_follower": {a: float(np.sqrt(np.mean(np.degrees(e) ** 2))) for a, e in errors.items()},
    }


# ---------------------------------------------------------------- adaptive gains


def adaptive_run(
    amplitude_deg: float,
    maneuver_s: float,
    adaptive: AdaptiveConfig | None,
    delay: float = 0.04,
    seed: int = 0,
    leader: str = "knatte",
    follower: str = "pinocchio",
    still: float = 5.0,
) -> dict[str, Any]:
    """A leader flies the raised-cosine maneuver (``amplitude_deg`` out and back in
    ``maneuver_s``); a follower tracks the heading it receives (latency compensated: a
    :class:`~agents.guidance.HeadingEstimator` with the maneuver as the leader's preset
    flies it as its input, as the agent runtime does), with its preset's gains
    (``adaptive`` None) or scheduled ones.

    Returns the follower's heading error against the leader (truth, RMS and max, deg,
    over the maneuver), its valve-open time (s) and the scale its gains reached."""
    maneuver = ReferenceManeuver(still, maneuver_s, math.radians(amplitude_deg))
    lead = SimulatedPlatform(load_platform(leader), seed=seed * 100)
    follow = SimulatedPlatform(load_platform(follower), seed=seed * 100 + 1)
    gains = None
    if adaptive is not None:
        from agents.adaptive import AdaptiveGains

        gains = AdaptiveGains(adaptive, follow.chain.pid)

    def lead_guidance(
        t: float, run_time: float | None, others: Mapping[str, tuple[float, Pose]], own: Pose
    ) -> Reference:
        return Reference(*maneuver(run_time)) if run_time is not None else Reference()

    estimator = HeadingEstimator()
    flown = _flown(leader, maneuver, still + maneuver_s + 5.0)

    def follow_guidance(
        t: float, run_time: float | None, others: Mapping[str, tuple[float, Pose]], own: Pose
    ) -> Reference:
        got = others.get("leader")
        if got is None:
            return Reference()
        if gains is not None:
            gains.observe(got[0], got[1].omega)
        profile = _profile(flown, maneuver, run_time)
        return Reference(*estimator.reference(PoseSample(*got), t, True, profile, run_time))

    members = [_Member("leader", lead, lead_guidance), _Member("follower", follow, follow_guidance)]
    _links(members, delay, 0.002, seed)
    errors: list[float] = []
    valve_steps = [0]
    peak_scale = [1.0]

    def observe(t: float, run_time: float, by_name: dict[str, _Member]) -> None:
        if still <= run_time <= still + maneuver_s + 5.0:
            errors.append(wrap_angle(follow.truth.heading - lead.truth.heading))
            valve_steps[0] += sum(follow.valves)
            if gains is not None:
                peak_scale[0] = max(peak_scale[0], gains.scale)

    _run(members, still + maneuver_s + 5.0, 20.0, observe, record_every=0.01)
    e = np.degrees(np.abs(errors))
    return {
        "amplitude_deg": amplitude_deg,
        "maneuver_s": maneuver_s,
        "adaptive": adaptive is not None,
        "heading_error_rms_deg": float(np.sqrt(np.mean(e**2))),
        "heading_error_max_deg": float(np.max(e)),
        "valve_open_s": valve_steps[0] * 0.01,
        "scale_max": peak_scale[0],
    }
