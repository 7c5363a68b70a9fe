"""A maneuver as a platform flies it: the followed platform's nominal heading, for the
follower's heading filter (:class:`~agents.guidance.HeadingEstimator`).

The filter moves its state between two received samples as its input profile moves.
Given the maneuver itself, it assumes the followed platform flies the maneuver's exact
shape; but that platform's controller lags its maneuver, and the filter, trusting the
shape (its acceleration noise is small so that it passes little of the sender's noise),
learns the lag only slowly: the compensated reference then trails the followed heading
by a good part of the delay it compensates, on a fast maneuver (33 to 35 ms behind on a
5 s, 20 degree one over a 40 ms link, where the raw sample trails by 53 ms).

:class:`FlownManeuver` is the maneuver as the followed platform's preset flies it: a
simulated twin of the preset (its dynamics and its whole GNC chain) with ideal sensors
(no noise, no bias, no table slope), released at rest on the maneuver's start a second
before run time 0 and stepped at the preset's control rate along run time. Its heading
and rate are the profile; the filter's samples then correct only what the twin does not
know (the real platform's noise, bias and table).

Cost: one twin step (about 35 us) per control period of the preset (100 Hz on the
presets), done by :meth:`FlownManeuver.advance` at most ``max_steps`` at a time: in a
run, one per control step of a follower at the same rate; a follower that joins a run
under way catches up at 16 a step (about 0.6 ms of its 10 ms), 16 times run time,
instead of stalling a step; until it has, the plain maneuver is the profile
(:meth:`FlownManeuver.profile`). It keeps the last ``memory`` seconds; a run time
before them (a new run) starts the twin afresh.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

from agents.simulated import SimulatedPlatform
from schemas.platform import PlatformConfig

__all__ = ["FlownManeuver", "FollowedModel", "Profile"]

Profile = Callable[[float], tuple[float, float]]
"""Run time (s) -> heading (rad) and heading rate (rad/s)."""

SETTLE = 1.0
"""s before run time 0 that the twin is released at rest on the maneuver's start."""


class FlownManeuver:
    """``maneuver`` as a platform of ``preset`` flies it, on run time (see the module).

    Call it with a run time the twin has reached (:meth:`covers`); :meth:`profile`
    says which profile to use for a run time, this or the maneuver itself.
    """

    def __init__(
        self,
        maneuver: Profile,
        preset: PlatformConfig,
        *,
        memory: float = 30.0,
        max_steps: int = 16,
    ):
        if not memory > 0:
            raise ValueError(f"memory must be positive seconds, not {memory!r}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, not {max_steps!r}")
        self.maneuver = maneuver
        self.preset = preset
        self.tick = 1.0 / preset.control.rate
        self.max_steps = max_steps
        self._size = max(2, math.ceil(memory / self.tick) + 1)
        self._times: deque[float] = deque(maxlen=self._size)
        self._headings: deque[float] = deque(maxlen=self._size)  # unwrapped
        self._rates: deque[float] = deque(maxlen=self._size)
        self.restarts = 0  # times the twin started afresh (the first start included)
        self._start()

    def _start(self) -> None:
        """A new twin at rest on the maneuver's start, released, at run time -SETTLE."""
        heading0, _ = self.maneuver(0.0)
        self._twin = SimulatedPlatform(self.preset, disturbance=False, ideal=True, heading=heading0)
        self._times.clear()
        self._headings.clear()
        self._rates.clear()
        self._record(-SETTLE, heading0, 0.0)
        self._k = 0  # twin steps taken since the start
        self.restarts += 1

    def _record(self, run_time: float, heading: float, rate: float) -> None:
        if self._headings:
            last = self._headings[-1]
            heading = last + math.remainder(heading - last, 2.0 * math.pi)
        self._times.append(run_time)
        self._headings.append(heading)
        self._rates.append(rate)

    # -- stepping along run time -------------------------------------------------------
    def advance(self, run_time: float) -> bool:
        """Step the twin towards ``run_time`` (at most :attr:`max_steps` steps); whether
        it has reached it. A run time before the twin's memory starts it afresh."""
        if not math.isfinite(run_time):
            return False
        if run_time < self._times[0] - 1e-9:
            self._start()
        for _ in range(self.max_steps):
            if self._times[-1] >= run_time - 1e-9:
                return True
            self._k += 1
            t = -SETTLE + self._k * self.tick
            heading_ref, rate_ref = self.maneuver(t) if t >= 0.0 else (self.maneuver(0.0)[0], 0.0)
            self._twin.step(self._k * self.tick, heading_ref, rate_ref)
            truth = self._twin.truth
            self._record(t, truth.heading, truth.omega)
        return self._times[-1] >= run_time - 1e-9

    def covers(self, run_time: float) -> bool:
        """Whether the twin has flown up to ``run_time`` (and still remembers it)."""
        return self._times[0] - 1e-9 <= run_time <= self._times[-1] + 1e-9

    def profile(self, run_time: float) -> Profile:
        """This, if the twin has reached ``run_time`` (the present run time); else the
        maneuver itself, until it has caught up."""
        return self if self.covers(run_time) else self.maneuver

    # -- the profile -----------------------------------------------------------------
    def __call__(self, run_time: float) -> tuple[float, float]:
        """The twin's heading (unwrapped from its start) and rate at ``run_time``,
        interpolated between its steps; held at the ends of what it remembers."""
        times = self._times
        if not run_time > times[0]:
            return self._headings[0], self._rates[0]
        if run_time >= times[-1]:
            return self._headings[-1], self._rates[-1]
        # The twin's steps are a tick apart: the step after run_time, found by index.
        i = min(max(1, math.ceil((run_time - times[0]) / self.tick - 1e-9)), len(times) - 1)
        t0, t1 = times[i - 1], times[i]
        w = (run_time - t0) / (t1 - t0)
        h = self._headings[i - 1] + w * (self._headings[i] - self._headings[i - 1])
        r = self._rates[i - 1] + w * (self._rates[i] - self._rates[i - 1])
        return h, r


class FollowedModel:
    """A follower's model of how the followed platform flies the run's maneuver: a
    :class:`FlownManeuver` of ``preset`` for the maneuver in force, made afresh when the
    maneuver changes (a start command may carry its own); without a preset (a kinematic
    or plug-in leader), the maneuver itself."""

    def __init__(self, preset: PlatformConfig | None):
        self.preset = preset
        self.flown: FlownManeuver | None = None

    def profile(self, maneuver: Profile, run_time: float) -> Profile:
        """The profile for the heading filter at the present ``run_time``, the twin
        stepped towards it (:meth:`FlownManeuver.advance`)."""
        if self.preset is None:
            return maneuver
        flown = self.flown
        if flown is None or flown.maneuver is not maneuver:
            flown = self.flown = FlownManeuver(maneuver, self.preset)
        flown.advance(run_time)
        return flown.profile(run_time)
