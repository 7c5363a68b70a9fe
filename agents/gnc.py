"""The GNC chain of paper section 2.3 (its figure 3), one for every platform.

One call of :meth:`GncChain.update` per control step, ``1 / control.rate`` seconds:

1. navigation: the Kalman filter (:class:`~agents.navigation.NavigationFilter`)
   predicts to ``now`` with the latest IMU sample and corrects with a metrology fix
   (camera or Vicon) if one came in since the last step;
2. control: the PID on the heading reference (Eq. 1, 2) gives a torque demand, the
   position controller force demands, both on the filter's estimate: following a
   3-DOF :class:`~agents.guidance.Track` (position, velocity, acceleration) when
   guidance gives one, else holding a point (optional);
3. actuation: the pulse-width modulator turns the demands into pulses and the
   thruster allocation into the eight valve states to hold until the next step.

The chain is pure: time and sensor data come in as arguments, valve states go out; it
opens no port and reads no clock. A simulated platform (:mod:`agents.simulated`) feeds
it its plant's sensors, a real one (:mod:`agents.serial.platform`) the frames of its
avionics: the same code, built from the same :class:`~schemas.platform.PlatformConfig`.

Fails closed
------------
Every valve stays closed, and :attr:`GncChain.reason` says why, while

- ``"no_fix"``: no metrology fix has come in yet (the estimate is a guess);
- ``"stale_fix"``: the latest fix is older than ``control.fix_timeout`` (dead
  reckoning on the IMU alone drifts; out of the cameras' view, say);
- ``"stale_imu"``: no IMU sample for ``control.imu_timeout`` (or none yet): the filter
  would predict on the last gyro reading for ever;
- ``"nonfinite"``: a reference, the estimate or a demand is not a finite number (a
  comparison with NaN is false, so a clip would pass it and a latch open on it). The
  filter is rebuilt and waits for the next fix;
- ``"held"``: :meth:`GncChain.hold` is in force (safe hold).

Sensor data the chain cannot trust is dropped and counted, never used: an IMU sample
that is not finite or beyond the sensor's range (``imu.gyro_range``,
``imu.accel_range``; one such sample would carry the heading off for good), and a fix
that is not finite. Time that runs backwards (the clock stepped back) makes every
fix and IMU sample before it unusable: the filter is rebuilt from the next fix.

Each closed step is counted (:attr:`GncChain.counters`). When control resumes, the PID's
integral and the PWM period start afresh (bumpless restart).
"""

from __future__ import annotations

import math
from typing import Literal

from agents.control import HeadingPid, PositionHold, PulseWidthModulator, allocate
from agents.dynamics import THRUSTERS
from agents.guidance import Track
from agents.navigation import NavigationFilter
from agents.sensors import ImuSample
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["CLOSED", "GncChain", "Reason"]

CLOSED: tuple[bool, ...] = (False,) * len(THRUSTERS)
"""Every valve closed."""

Reason = Literal["held", "no_fix", "stale_fix", "stale_imu", "nonfinite"]
"""Why every valve is closed."""


class GncChain:
    """Navigation, heading PID, position control, PWM and allocation: sensors in, valves out.

    Parameters
    ----------
    config : PlatformConfig
        The preset: sensor noise (filter tuning), gains, PWM, thrusters, ``fix_timeout``.
    position_hold : bool, optional
        Hold a position with a PD; None: ``config.control.position_hold``.
    target : tuple of float, optional
        Position to hold (x, y), m; None: the estimate after the first fix.
    fix_timeout : float, optional
        Seconds after the latest fix at which the valves close; None:
        ``config.control.fix_timeout``.
    """

    def __init__(
        self,
        config: PlatformConfig,
        *,
        position_hold: bool | None = None,
        target: tuple[float, float] | None = None,
        fix_timeout: float | None = None,
    ):
        self.config = config
        c, i = config.control, config.imu
        self.rate: float = c.rate
        self.fix_timeout = c.fix_timeout if fix_timeout is None else fix_timeout
        if not self.fix_timeout > 0:
            raise ValueError(f"fix_timeout must be positive seconds, not {self.fix_timeout!r}")
        self.imu_timeout = c.imu_timeout
        self._gyro_range, self._accel_range = i.gyro_range, i.accel_range
        self.filter = self._new_filter()
        self.pid = HeadingPid(c.kp, c.ki, c.kd, config.pair_torque, c.integral_limit)
        # Channels: body x force, body y force, torque. The torque pairs share valves
        # with the x pairs, so x pulses sit at the end of the period, torque at the start.
        self.pwm = PulseWidthModulator(
            c.pwm_period,
            c.min_on_time,
            1.0 / c.rate,
            channels=3,
            right_aligned=(True, False, False),
        )
        if position_hold is None:
            position_hold = c.position_hold
        self.position = PositionHold(
            c.kp_position, c.kd_position, config.pair_force, target or (0.0, 0.0), config.mass
        )
        """The position controller: follows a track when given one, else holds a point."""
        self.position_hold: PositionHold | None = self.position if position_hold else None
        self._target_set = target is not None
        self._explicit_target = target is not None
        # Where position hold holds is re-taken from the estimate when a track ends and
        # when a hold is released: holding the first fix's point instead sent a platform
        # released between runs back across the table. (Not after a camera's gap: the
        # point it held is still the one to hold.)
        self._hold_here = False
        self._force_scale = 1.0 / config.pair_force
        self._torque_scale = 1.0 / config.pair_torque
        self._imu = ImuSample(0.0, 0.0, 0.0)
        self._imu_at: float | None = None  # ``now`` of the latest IMU sample used
        self._fix_at: float | None = None  # ``now`` of the latest fix
        self._last_now: float | None = None
        self._held = False
        self._closed = True  # the last step was forced closed: restart PID and PWM
        self._valves = CLOSED
        self.reason: Reason | None = "no_fix"
        """Why every valve is closed now; None while the chain controls."""
        self.counters: dict[str, int] = {
            "closed_held": 0,
            "closed_no_fix": 0,
            "closed_stale_fix": 0,
            "closed_stale_imu": 0,
            "closed_nonfinite": 0,
            "imu_rejected": 0,
            "fix_rejected": 0,
            "clock_steps_back": 0,
        }
        """Control steps closed, per reason; sensor data dropped; clock steps back."""

    def _new_filter(self) -> NavigationFilter:
        i, v, n = self.config.imu, self.config.vision, self.config.navigation
        return NavigationFilter(
            gyro_noise=i.gyro_noise,
            accel_noise=i.accel_noise,
            position_noise=v.position_noise,
            heading_noise=v.heading_noise,
            unmodelled_accel=n.unmodelled_accel,
            gyro_bias_walk=n.gyro_bias_walk,
            accel_bias_walk=n.accel_bias_walk,
        )

    def _restart_estimate(self) -> None:
        """Forget the estimate and every sensor time: closed until a new fix and IMU."""
        self.filter = self._new_filter()
        self._fix_at = self._imu_at = None
        self._imu = ImuSample(0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ one step

    def update(
        self,
        now: float,
        heading_ref: float,
        rate_ref: float,
        imu: ImuSample | None = None,
        fix: Pose | None = None,
        track: Track | None = None,
    ) -> tuple[bool, ...]:
        """The eight valve states for the control step starting at ``now`` (s).

        Parameters
        ----------
        now : float
            Time of the step, s (any clock, as long as it is the same every step).
        heading_ref, rate_ref : float
            Heading (rad) and rate (rad/s) references from guidance.
        imu : ImuSample, optional
            A new IMU sample; None: keep using the last one.
        fix : Pose, optional
            A new metrology fix (x, y, heading; its rates are ignored), taken now.
        track : Track, optional
            A position reference with its rates (this chain's frame, the table's); None:
            hold the target if position hold is on, else no force.
        """
        if self._last_now is not None and now < self._last_now:
            self.counters["clock_steps_back"] += 1
            self._restart_estimate()
        self._last_now = now
        if imu is not None:
            if self._plausible_imu(imu):
                self._imu, self._imu_at = imu, now
            else:
                self.counters["imu_rejected"] += 1
        if fix is not None and not (
            math.isfinite(fix.x) and math.isfinite(fix.y) and math.isfinite(fix.heading)
        ):
            self.counters["fix_rejected"] += 1
            fix = None
        self.filter.predict(now, self._imu)
        if fix is not None:
            self.filter.correct(now, fix)
            self._fix_at = now
            if self.position_hold is not None and not self._target_set:
                est = self.filter.estimate
                self.position_hold.target = (est.x, est.y)
                self._target_set = True
        reason = self._closed_reason(now)
        if reason is not None:
            return self._close(reason)
        est = self.filter.estimate
        if not all(map(math.isfinite, est)):
            self._restart_estimate()  # a NaN in the filter stays there: start afresh
            return self._close("nonfinite")
        if not (math.isfinite(heading_ref) and math.isfinite(rate_ref)):
            return self._close("nonfinite")
        if self._closed:  # resuming: no integral or PWM period left from before
            self._closed = False
            self.pid.reset()
            self.pwm.reset()
        self.reason = None
        torque = self.pid.update(now, est.heading, est.omega, heading_ref, rate_ref)
        fx = fy = 0.0
        if track is not None:
            fx, fy = self.position.update(est, track)
            self._hold_here = True  # when the track ends, hold where it left the platform
        elif self.position_hold is not None:
            if self._hold_here and not self._explicit_target:
                self.position_hold.target = (est.x, est.y)
            self._hold_here = False
            fx, fy = self.position_hold.update(est)
        demands = (fx * self._force_scale, fy * self._force_scale, torque * self._torque_scale)
        if not all(map(math.isfinite, demands)):  # a track's NaN, an overflow
            return self._close("nonfinite")
        signs = self.pwm.update(now, demands)
        self._valves = allocate(*signs)
        return self._valves

    def _close(self, reason: Reason) -> tuple[bool, ...]:
        self.counters[f"closed_{reason}"] += 1
        self.reason = reason
        self._closed = True
        self._valves = CLOSED
        return CLOSED

    def _plausible_imu(self, imu: ImuSample) -> bool:
        gyro, ax, ay = imu
        # ``not x <= r`` is true for NaN, where ``x > r`` is not.
        return (
            abs(gyro) <= self._gyro_range
            and abs(ax) <= self._accel_range
            and abs(ay) <= self._accel_range
        )

    def _closed_reason(self, now: float) -> Reason | None:
        if self._held:
            return "held"
        if self._fix_at is None:
            return "no_fix"
        if now - self._fix_at > self.fix_timeout:
            return "stale_fix"
        if self._imu_at is None or now - self._imu_at > self.imu_timeout:
            return "stale_imu"
        return None

    # ------------------------------------------------------------------ safe hold

    def hold(self) -> None:
        """Safe hold: every valve closed from now until :meth:`release`."""
        self._held = True
        self._closed = True
        self._valves = CLOSED
        self.reason = "held"

    def release(self) -> None:
        """End the hold; control resumes (from a clean start) at the next :meth:`update`,
        holding position (if it does) where the platform is then, not where it was."""
        self._held = False
        self._hold_here = True

    @property
    def held(self) -> bool:
        return self._held

    # ------------------------------------------------------------------ outputs

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight valve states of the last step (all closed after :meth:`hold`)."""
        return self._valves

    @property
    def estimate(self) -> Pose:
        """The navigation estimate: what the agent publishes."""
        return self.filter.estimate

    @property
    def fix_time(self) -> float | None:
        """``now`` of the latest fix, s (None before the first)."""
        return self._fix_at
