"""Simulated platforms: truth dynamics and sensors (:class:`Plant`) under the paper's
GNC chain (:class:`SimulatedPlatform` = :class:`Plant` + :class:`~agents.gnc.GncChain`).

One control step of :class:`SimulatedPlatform`, every ``1 / control.rate`` seconds:

1. the plant integrates the truth over the step with the valves held
   (RK4 sub-steps at ``physics_rate``);
2. the IMU (and, when due, the vision system) sample the truth;
3. the GNC chain (:mod:`agents.gnc`, section 2.3) takes the samples and gives the eight
   valve states for the next step: Kalman filter, PID (Eq. 1 and 2), position hold,
   PWM and thruster allocation.

The agent publishes the filter's estimate; the truth stays here for evaluation.
Time comes in through :meth:`SimulatedPlatform.step`, so a test runs it in
simulated time as fast as the CPU allows and an agent runs it in real time.
:class:`Plant` is also the physics of the emulated device behind ``fedlab
emulate-device`` (:mod:`agents.serial.emulator`): one model, one integrator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from agents.dynamics import THRUSTERS, BodyParams, SlopeField, step, wrench
from agents.gnc import CLOSED, GncChain
from agents.guidance import Track
from agents.interface import WithChain
from agents.navigation import NavigationFilter
from agents.sensors import Coverage, Imu, ImuSample, Vision
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.platform import PlatformConfig, load_platform

__all__ = ["Plant", "SimulatedPlatform"]


class Plant:
    """Truth dynamics and sensors, no GNC: what a real platform's hardware is.

    Parameters
    ----------
    config : PlatformConfig
        Mass, inertia, thrusters, sensors and table disturbance.
    seed : int
        Seed of the sensor noise.
    disturbance : bool
        Apply the table's slope field (``config.disturbance``; its own seed fixes the
        table's shape, so every run sees the same table).
    x, y, heading : float
        Starting pose, m and rad (at rest).
    ideal : bool
        Sensors without noise or bias: the preset's nominal response
        (:mod:`agents.flown`).

    The caller schedules the samples: :attr:`imu_sensor` and :attr:`vision_sensor`
    carry :class:`~agents.sensors.Sampler` clocks at the configured rates.
    """

    def __init__(
        self,
        config: PlatformConfig,
        seed: int = 0,
        disturbance: bool = False,
        x: float = 0.0,
        y: float = 0.0,
        heading: float = 0.0,
        ideal: bool = False,
    ):
        self.config = config
        self.params = BodyParams.from_config(config)
        d = config.disturbance
        self.field: SlopeField | None = (
            SlopeField.random(d.seed, d.slope, d.wavelength, d.components) if disturbance else None
        )
        imu_rng, vision_rng = (
            np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2)
        )
        i, v = config.imu, config.vision
        coverage = Coverage(v.width, v.height, v.origin[0], v.origin[1])
        if ideal:
            self.imu_sensor = Imu(i.rate, 0.0, 0.0, 0.0, (0.0, 0.0), imu_rng)
            self.vision_sensor = Vision(v.rate, 0.0, 0.0, coverage, vision_rng)
        else:
            self.imu_sensor = Imu(
                i.rate, i.gyro_noise, i.gyro_bias, i.accel_noise, i.accel_bias, imu_rng
            )
            self.vision_sensor = Vision(
                v.rate, v.position_noise, v.heading_noise, coverage, vision_rng
            )
        self.state: npt.NDArray[np.float64] = np.array(
            [x, y, heading, 0.0, 0.0, 0.0], dtype=np.float64
        )
        self.t = 0.0  # s of simulated time advanced so far
        self._substep = 1.0 / config.physics_rate
        self._valves: tuple[bool, ...] = CLOSED
        self._specific_force = (0.0, 0.0)

    def advance(self, dt: float, valves: Sequence[bool]) -> None:
        """Integrate ``dt`` seconds with the eight ``valves`` held open/closed."""
        if len(valves) != len(THRUSTERS):
            raise ValueError(f"expected {len(THRUSTERS)} valve states, got {len(valves)}")
        if not dt >= 0:
            raise ValueError(f"cannot advance by {dt!r} s")
        valves = tuple(bool(v) for v in valves)
        if valves != self._valves:
            self._valves = valves
            fx, fy, _ = wrench(valves, self.params)
            self._specific_force = (fx / self.params.mass, fy / self.params.mass)
        if dt == 0:
            return
        n = max(1, math.ceil(dt / self._substep - 1e-9))
        h = dt / n
        x = self.state
        for _ in range(n):
            x = step(x, valves, h, self.params, self.field)
        self.state = x
        self.t += dt

    @property
    def valves(self) -> tuple[bool, ...]:
        """The valve states of the last :meth:`advance`."""
        return self._valves

    @property
    def pose(self) -> Pose:
        """The true state as a :class:`~federation.core.wire.Pose`."""
        return Pose(*self.state.tolist())

    def imu(self) -> ImuSample:
        """An IMU sample now: gyro rate (rad/s), body specific force (m/s^2)."""
        fx, fy = self._specific_force
        return self.imu_sensor.measure(float(self.state[5]), fx, fy)

    def vision(self) -> Pose | None:
        """A noisy pose fix now, or None outside the coverage."""
        x, y, heading = self.state[:3].tolist()
        return self.vision_sensor.measure(x, y, heading)


class SimulatedPlatform(WithChain):
    """A physically simulated platform under the GNC chain: a :class:`Plant` and a
    :class:`~agents.gnc.GncChain` (whose fix, restart and causes it reports:
    :class:`~agents.interface.WithChain`).

    Parameters
    ----------
    config : PlatformConfig
        The preset (see :func:`schemas.platform.load_platform`).
    seed : int
        Seed of the sensor noise.
    disturbance : bool, optional
        Table slope force; None: ``config.disturbance.enabled``.
    position_hold : bool, optional
        Hold the position of the first fix; None: ``config.control.position_hold``.
    x, y, heading : float
        Starting pose, m and rad (the filter learns it from the first vision fix).
    """

    kind = "simulated"
    """Its name in an agent's ``platform`` spec; a spec naming no kind is its argument
    (``knatte``, ``deploy/platforms/knatte.toml``)."""
    argument = "PRESET"
    hardware = False

    @classmethod
    def check_spec(cls, argument: str | None) -> None:
        """A preset or platform file that loads (ConfigError naming its file and field)."""
        if not argument:
            raise ValueError(
                "a simulated platform needs a preset name or a platform file, e.g. knatte"
            )
        load_platform(argument)

    @classmethod
    def from_spec(
        cls, argument: str | None, *, seed: int, rate: float, preset: str | None
    ) -> SimulatedPlatform:
        """The preset or file ``argument`` flown with sensor noise of ``seed`` (at its
        own ``control.rate``: ``rate`` is a kinematic platform's)."""
        cls.check_spec(argument)
        assert argument is not None
        return cls(load_platform(argument), seed=seed)

    def __init__(
        self,
        config: PlatformConfig,
        seed: int = 0,
        *,
        disturbance: bool | None = None,
        position_hold: bool | None = None,
        x: float = 0.0,
        y: float = 0.0,
        heading: float = 0.0,
        ideal: bool = False,
    ):
        self.config = config
        self.rate: float = config.control.rate
        self._tick = 1.0 / self.rate
        if disturbance is None:
            disturbance = config.disturbance.enabled
        self.plant = Plant(config, seed, disturbance, x, y, heading, ideal)
        self.chain = GncChain(config, position_hold=position_hold)
        self._t0: float | None = None
        self._k = 0

    # ------------------------------------------------------------------ interface

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """Advance to ``t`` (s) tracking ``heading_ref`` (rad) with ``rate_ref`` (rad/s)
        as the derivative reference (and ``track``, a position reference in the table
        frame, if given); return the filter's estimate.

        The first call sets the time origin. Later calls run every whole control step
        up to ``t`` with this reference (none if ``t`` has not advanced a step); the
        estimate returned is the one at the last of them.
        """
        if self._t0 is None:
            self._t0 = t
            self._tick_at(t, heading_ref, rate_ref, track)
            return self.chain.estimate
        tick, t0 = self._tick, self._t0
        while True:
            now = t0 + (self._k + 1) * tick
            if now > t + 1e-9:
                break
            self.plant.advance(tick, self.chain.valves)
            self._k += 1
            self._tick_at(now, heading_ref, rate_ref, track)
        return self.chain.estimate

    def hold(self) -> None:
        """Safe hold: every valve closed from now until :meth:`release`."""
        self.chain.hold()

    def release(self) -> None:
        """Resume control from a clean start (integral and PWM period reset)."""
        self.chain.release()

    def close(self) -> None:
        """Every valve closed; nothing else to release."""
        self.chain.hold()

    @property
    def held(self) -> bool:
        return self.chain.held

    valves_confirmed: bool | None = None
    """No device to confirm the valve commands: the plant takes them as they are."""

    @property
    def truth(self) -> Pose:
        """The simulator's true pose (for evaluation; the agent publishes the estimate)."""
        return self.plant.pose

    @property
    def estimate(self) -> Pose:
        """The filter's current estimate (what :meth:`step` returned last)."""
        return self.chain.estimate

    @property
    def filter(self) -> NavigationFilter:
        """The chain's navigation filter."""
        return self.chain.filter

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight current valve states."""
        return self.chain.valves

    @property
    def counters(self) -> dict[Count, int]:
        """The chain's: steps closed and why, IMU samples and fixes rejected."""
        return dict(self.chain.counters)

    # ------------------------------------------------------------------ one step

    def _tick_at(
        self, now: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> None:
        """Sample the sensors that are due, then one step of the chain."""
        plant = self.plant
        imu = plant.imu() if plant.imu_sensor.sampler.due(now) else None
        fix = plant.vision() if plant.vision_sensor.sampler.due(now) else None
        self.chain.update(now, heading_ref, rate_ref, imu=imu, fix=fix, track=track)
