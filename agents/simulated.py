"""Simulated platforms: truth dynamics and sensors (:class:`Plant`) under the paper's
GNC chain (:class:`SimulatedPlatform`, section 2.3).

One control step of :class:`SimulatedPlatform`, every ``1 / control.rate`` seconds:

1. the plant integrates the truth over the step with the valves held
   (RK4 sub-steps at ``physics_rate``);
2. the IMU (and, when due, the vision system) sample the truth;
3. the Kalman filter predicts with the IMU and corrects with a vision fix;
4. the PID (Eq. 1 and 2) turns the estimated heading error into a torque demand,
   the optional position hold into force demands, and the PWM and the thruster
   allocation into the eight valve states for the next step.

The agent publishes the filter's estimate; the truth stays here for evaluation.
Time comes in through :meth:`SimulatedPlatform.step`, so a test runs it in
simulated time as fast as the CPU allows and an agent runs it in real time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from agents.control import HeadingPid, PositionHold, PulseWidthModulator, allocate
from agents.dynamics import THRUSTERS, BodyParams, SlopeField, step, wrench
from agents.navigation import NavigationFilter
from agents.sensors import Coverage, Imu, ImuSample, Vision
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["Plant", "SimulatedPlatform"]

_CLOSED = (False,) * len(THRUSTERS)


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
        i = config.imu
        self.imu_sensor = Imu(
            i.rate, i.gyro_noise, i.gyro_bias, i.accel_noise, i.accel_bias, imu_rng
        )
        v = config.vision
        coverage = Coverage(v.width, v.height, v.origin[0], v.origin[1])
        self.vision_sensor = Vision(v.rate, v.position_noise, v.heading_noise, coverage, vision_rng)
        self.state: npt.NDArray[np.float64] = np.array(
            [x, y, heading, 0.0, 0.0, 0.0], dtype=np.float64
        )
        self.t = 0.0  # s of simulated time advanced so far
        self._substep = 1.0 / config.physics_rate
        self._valves: tuple[bool, ...] = _CLOSED
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


class SimulatedPlatform:
    """A physically simulated platform under PID + PWM with Kalman navigation.

    Parameters
    ----------
    config : PlatformConfig
        The preset (see :func:`schemas.platform.load_platform`).
    seed : int
        Seed of the sensor noise.
    disturbance : bool, optional
        Table slope force; None: ``config.disturbance.enabled``.
    position_hold : bool, optional
        Hold the starting x, y; None: ``config.control.position_hold``.
    x, y, heading : float
        Starting pose, m and rad (the filter learns it from the first vision fix).
    """

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
    ):
        self.config = config
        c = config.control
        self.rate: float = c.rate
        self._tick = 1.0 / c.rate
        if disturbance is None:
            disturbance = config.disturbance.enabled
        if position_hold is None:
            position_hold = c.position_hold
        self.plant = Plant(config, seed, disturbance, x, y, heading)
        v, i, n = config.vision, config.imu, config.navigation
        self.filter = NavigationFilter(
            gyro_noise=i.gyro_noise,
            accel_noise=i.accel_noise,
            position_noise=v.position_noise,
            heading_noise=v.heading_noise,
            unmodelled_accel=n.unmodelled_accel,
            gyro_bias_walk=n.gyro_bias_walk,
            accel_bias_walk=n.accel_bias_walk,
        )
        self.pid = HeadingPid(c.kp, c.ki, c.kd, config.pair_torque, c.integral_limit)
        # Channels: body x force, body y force, torque. The torque pairs share valves
        # with the x pairs, so x pulses sit at the end of the period, torque at the start.
        self.pwm = PulseWidthModulator(
            c.pwm_period, c.min_on_time, self._tick, channels=3, right_aligned=(True, False, False)
        )
        self.position_hold: PositionHold | None = (
            PositionHold(c.kp_position, c.kd_position, config.pair_force, (x, y))
            if position_hold
            else None
        )
        self._force_scale = 1.0 / config.pair_force
        self._torque_scale = 1.0 / config.pair_torque
        self._valves: tuple[bool, ...] = _CLOSED
        self._held = False
        self._t0: float | None = None
        self._k = 0
        self._imu = ImuSample(0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ interface

    def step(self, t: float, heading_ref: float, rate_ref: float) -> Pose:
        """Advance to ``t`` (s) tracking ``heading_ref`` (rad) with ``rate_ref`` (rad/s)
        as the derivative reference; return the filter's estimate.

        The first call sets the time origin. Later calls run every whole control step
        up to ``t`` with this reference (none if ``t`` has not advanced a step); the
        estimate returned is the one at the last of them.
        """
        if self._t0 is None:
            self._t0 = t
            self._sense(t)
            self._control(t, heading_ref, rate_ref)
            return self.filter.estimate
        tick, t0 = self._tick, self._t0
        while True:
            now = t0 + (self._k + 1) * tick
            if now > t + 1e-9:
                break
            self.plant.advance(tick, self._valves)
            self._k += 1
            self._sense(now)
            self._control(now, heading_ref, rate_ref)
        return self.filter.estimate

    def hold(self) -> None:
        """Safe hold: every valve closed from now until :meth:`release`."""
        self._held = True
        self._valves = _CLOSED

    def release(self) -> None:
        """Resume control from a clean start (integral and PWM period reset)."""
        if self._held:
            self._held = False
            self.pid.reset()
            self.pwm.reset()

    @property
    def held(self) -> bool:
        return self._held

    @property
    def truth(self) -> Pose:
        """The simulator's true pose (for evaluation; the agent publishes the estimate)."""
        return self.plant.pose

    @property
    def estimate(self) -> Pose:
        """The filter's current estimate (what :meth:`step` returned last)."""
        return self.filter.estimate

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight current valve states."""
        return self._valves

    # ------------------------------------------------------------------ one step

    def _sense(self, now: float) -> None:
        plant = self.plant
        if plant.imu_sensor.sampler.due(now):
            self._imu = plant.imu()
        self.filter.predict(now, self._imu)
        if plant.vision_sensor.sampler.due(now):
            fix = plant.vision()
            if fix is not None:
                self.filter.correct(now, fix)

    def _control(self, now: float, heading_ref: float, rate_ref: float) -> None:
        if self._held:
            self._valves = _CLOSED
            return
        est = self.filter.estimate
        torque = self.pid.update(now, est.heading, est.omega, heading_ref, rate_ref)
        fx = fy = 0.0
        if self.position_hold is not None:
            fx, fy = self.position_hold.update(est)
        signs = self.pwm.update(
            now, (fx * self._force_scale, fy * self._force_scale, torque * self._torque_scale)
        )
        self._valves = allocate(*signs)
