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
Every valve stays closed, and :attr:`GncChain.reason` says why (the first that holds,
in this order), while

- ``"held"``: :meth:`GncChain.hold` is in force (safe hold);
- ``"no_fix"``: no metrology fix has come in yet (the estimate is a guess);
- ``"device_restart"``: the platform's own reason (``closed_for``): a serial device
  whose clock went back, not yet confirmed as restarted (:mod:`agents.serial.platform`);
- ``"fix_rejected"``: the latest fix was rejected (below), until one is taken;
- ``"stale_fix"``: the latest fix is older than ``control.fix_timeout`` (dead
  reckoning on the IMU alone drifts; out of the cameras' view, say);
- ``"stale_imu"``: no IMU sample for ``control.imu_timeout`` (or none yet): the filter
  would predict on the last gyro reading for ever;
- ``"nonfinite"``: a reference, the estimate or a demand is not a finite number (a
  comparison with NaN is false, so a clip would pass it and a latch open on it). The
  filter is rebuilt and waits for the next fix.

Sensor data the chain cannot trust is dropped and counted, never used: an IMU sample
that is not finite or beyond the sensor's range (``imu.gyro_range``,
``imu.accel_range``; one such sample would carry the heading off for good), and a fix
(``fix_rejected``) that is

- not finite;
- outside where a fix can be (``fix_outside``): the table and the cameras' coverage
  overlap, grown by ``vision.fix_margin`` (:attr:`~schemas.platform.PlatformConfig.fix_area`);
  taken, one POSE at x = 5 m off KNATTE's 3 m table, with a valid checksum, opens valves
  in 436 of the next 1000 steps; at 3e38 m, in every one;
- an outlier (``fix_outlier``): more than ``navigation.fix_gate`` sigmas of the filter's
  innovation covariance from the estimate (x, y and heading together; the first fix of
  an estimate is not gated, there is nothing to gate it on).

A fix is never taken alone when the estimate has none to check it against: the first
fix of an estimate, and the first after a gap longer than ``control.fix_timeout``
(no fix received for that long: out of the cameras' view, dead reckoning on the IMU
alone, the estimate anywhere the drift took it), start a trial copy of the estimate,
and so do the fixes after it until the trial is taken or dropped (none is gated
against the dead-reckoned estimate, so none is an outlier), and the estimate takes it only once
``navigation.fixes_to_start`` fixes in a row agree with it (each within the gate of
the trial so far): taken alone, a glitch right after a gap would be flown on. The
estimate then takes the fixes that follow as usual, gated, and the valves stay closed
(``settling``) until its velocity is known to ``navigation.start_velocity_sigma``: from
a standing start, three fixes leave it 0.06 m/s unsure, and valves opened then would act
on a velocity 0.05 to 0.15 m/s wrong (or on a glitch as the third fix). The velocity is
waited for after the trial, not in it: there, a glitch now and then would begin the
trial again each time, and it might never finish.
Until then the valves stay closed (``no_fix``, ``stale_fix``; ``fix_acquiring`` counts the
fixes held back).

A fix describes the platform when the metrology saw it, which may be some time before
it reaches the chain (``fix_age``: a camera pipeline's latency, known from the
device's clock): the filter sets it against the estimate as it was then, by the
motion the IMU has shown since and the velocity's and gyro bias's part in it
(:mod:`agents.navigation`), and its staleness counts from when it was taken: as a
turn begins, a lag the gate does not know of would make good fixes outliers that agree
with one another, and restart the estimate. A fix older than the estimate's known
motion (just restarted) is held back (``fix_uncarried``); one older than
``vision.latency_max`` is rejected (``fix_late``): no metrology is that late, a
device time is wrong.

Outliers go to a second filter that runs beside the first, started from the first of
them and fed with the same IMU: when ``navigation.outliers_to_restart`` outliers in a row
agree with it (each within the gate of it), the platform is where they say (it was moved,
or the metrology restarted with another origin) and the estimate restarts from them
(``fix_restarts``): the second filter becomes the estimate, and position hold re-takes
its point there. An outlier that disagrees with it too starts it afresh. Until then
every valve stays closed (``fix_rejected``, then ``stale_fix``).

Time that runs backwards (the clock stepped back) makes every fix and IMU sample
before it unusable: the filter is rebuilt from the next fix. :meth:`GncChain.restart`
does the same for a platform whose device restarted, and re-takes the point to hold.

Each closed step is counted (:attr:`GncChain.counters`). When control resumes, the PID's
integral and the PWM period start afresh (bumpless restart).
"""

from __future__ import annotations

import copy
import math
from typing import Literal

from agents.control import HeadingPid, PositionHold, PulseWidthModulator, allocate
from agents.dynamics import THRUSTERS
from agents.guidance import Track
from agents.navigation import NavigationFilter
from agents.sensors import ImuSample
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["CLOSED", "CLOSED_COUNT", "GncChain", "PlatformReason", "Reason"]

CLOSED: tuple[bool, ...] = (False,) * len(THRUSTERS)
"""Every valve closed."""

Reason = Literal[
    "held",
    "no_fix",
    "device_restart",
    "fix_restart",
    "fix_rejected",
    "stale_fix",
    "stale_imu",
    "settling",
    "nonfinite",
]
"""Why every valve is closed (the first that holds, in this order)."""

PlatformReason = Literal["device_restart"]
"""A reason the platform gives the chain to keep every valve closed (``closed_for``)."""

CLOSED_COUNT: dict[Reason, Count] = {
    "held": Count.CLOSED_HELD,
    "no_fix": Count.CLOSED_NO_FIX,
    "device_restart": Count.CLOSED_DEVICE_RESTART,
    "fix_restart": Count.CLOSED_FIX_RESTART,
    "fix_rejected": Count.CLOSED_FIX_REJECTED,
    "stale_fix": Count.CLOSED_STALE_FIX,
    "stale_imu": Count.CLOSED_STALE_IMU,
    "settling": Count.CLOSED_SETTLING,
    "nonfinite": Count.CLOSED_NONFINITE,
}
"""The counter of the control steps closed for each :data:`Reason`."""


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
        self.fix_area: tuple[float, float, float, float] = config.fix_area
        """Where a fix may lie (x_min, x_max, y_min, y_max), m; beyond: rejected."""
        self.fix_gate: float = config.navigation.fix_gate
        self._outliers_to_restart = config.navigation.outliers_to_restart
        self._fixes_to_start = config.navigation.fixes_to_start
        self._start_velocity_sigma = config.navigation.start_velocity_sigma
        self.filter = self._new_filter()
        # The estimate's trial copy while fixes are acquired, how many it has taken, when
        # it took the last.
        self._trial: NavigationFilter | None = None
        self._trial_fixes = 0
        self._trial_at = -math.inf
        self._settling = False  # acquired: closed until the velocity is known
        # Two fix periods inside fix_timeout: a fix that old is still a fresh one (else
        # every fix would come after the last went stale, and be acquired anew). The
        # preset is checked so at load; a fix_timeout given here must allow it too.
        self.latency_max: float = config.vision.latency_max
        room = self.fix_timeout - 2.0 / config.vision.rate
        if self.latency_max > room:
            raise ValueError(
                f"fix_timeout {self.fix_timeout:g} s leaves less than two vision periods for "
                f"fixes vision.latency_max ({self.latency_max:g} s) late: at least "
                f"{self.latency_max + 2.0 / config.vision.rate:g} s, or a smaller latency_max"
            )
        """Oldest a fix may be when it arrives (``fix_age``), s; older: rejected."""
        # The second filter that outliers feed, and how many in a row have agreed with it.
        self._shadow: NavigationFilter | None = None
        self._agreeing = 0
        self._rejecting = False  # the latest fix was rejected: closed until one is taken
        self._restarted = False  # restarted from outliers: closed until acknowledged
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
        # when a hold is released: the first fix's point may be across the table from a
        # platform released between runs, and holding it would send the platform back
        # there. (Not after a camera's gap: the point it held is still the one to hold.)
        self._hold_here = False
        self._force_scale = 1.0 / config.pair_force
        self._torque_scale = 1.0 / config.pair_torque
        self._imu = ImuSample(0.0, 0.0, 0.0)
        self._imu_at: float | None = None  # ``now`` of the latest IMU sample used
        self._fix_at: float | None = None  # ``now`` of the latest fix
        self._seen_at: float | None = None  # ``now`` of the latest fix received, taken or not
        self._last_now: float | None = None
        self._held = False
        self._closed = True  # the last step was forced closed: restart PID and PWM
        self._valves = CLOSED
        self.reason: Reason | None = "no_fix"
        """Why every valve is closed now; None while the chain controls."""
        self.cause: Reason | None = "no_fix"
        """Why every valve would be closed now were the platform not held (``reason``
        says ``held`` then): what preflight tells of a platform waiting for its run."""
        self.last_rejection: str | None = None
        """The kind of the latest fix rejected (``fix_outside``, ``fix_late``, ...)."""
        self.counters: dict[Count, int] = {
            **dict.fromkeys(CLOSED_COUNT.values(), 0),
            Count.IMU_REJECTED: 0,
            Count.FIX_REJECTED: 0,
            Count.FIX_OUTSIDE: 0,
            Count.FIX_OUTLIER: 0,
            Count.FIX_LATE: 0,
            Count.FIX_ACQUIRING: 0,
            Count.FIX_ACQUIRE_RESTARTS: 0,
            Count.FIX_UNCARRIED: 0,
            Count.FIX_RESTARTS: 0,
            Count.CLOCK_STEPS_BACK: 0,
            Count.RESTARTS: 0,
        }
        """Control steps closed, per reason; sensor data dropped (``fix_rejected``: every
        fix dropped, of which ``fix_outside``, ``fix_late`` and ``fix_outlier``); fixes
        held back until enough agree (``fix_acquiring``) and trials begun again
        (``fix_acquire_restarts``: a fix disagreed, or a gap); fixes held back for being
        older than the estimate's known motion (``fix_uncarried``); estimates restarted:
        from agreeing outliers (``fix_restarts``), after the clock stepped back
        (``clock_steps_back``), by :meth:`restart` (``restarts``)."""

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
            history=self.fix_timeout,
        )

    def _restart_estimate(self) -> None:
        """Forget the estimate and every sensor time: closed until a new fix and IMU."""
        self.filter = self._new_filter()
        self._fix_at = self._imu_at = None
        self._imu = ImuSample(0.0, 0.0, 0.0)
        self._shadow = self._trial = None
        self._agreeing = self._trial_fixes = 0
        self._settling = False
        self._trial_at = -math.inf
        self._seen_at = None
        self._rejecting = False

    def acknowledge_restart(self) -> None:
        """An operator has seen the estimate restarted from agreeing outliers
        (``fix_restart``; ``fedlab ctl reset``): control may resume on it."""
        self._restarted = False

    def restart(self) -> None:
        """Start the estimate afresh: every valve closed (``no_fix``) until a new fix and
        IMU sample, and position hold holds where that fix puts the platform (a target
        given to the chain stays). For a platform whose sensors restarted (a serial
        device's reset): nothing measured before it describes the platform now."""
        self.counters[Count.RESTARTS] += 1
        self._restart_estimate()
        if not self._explicit_target:
            self._target_set = False

    # ------------------------------------------------------------------ one step

    def update(
        self,
        now: float,
        heading_ref: float,
        rate_ref: float,
        imu: ImuSample | None = None,
        fix: Pose | None = None,
        track: Track | None = None,
        closed_for: PlatformReason | None = None,
        fix_age: float = 0.0,
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
            A new metrology fix (x, y, heading; its rates are ignored).
        track : Track, optional
            A position reference with its rates (this chain's frame, the table's); None:
            hold the target if position hold is on, else no force.
        closed_for : str, optional
            The platform's reason to keep every valve closed this step (the estimate
            goes on): ``"device_restart"``.
        fix_age : float
            How long before ``now`` the metrology took ``fix``, s (its latency); the fix
            is carried forward to ``now`` along the estimate. At most ``fix_timeout``.
        """
        if not math.isfinite(now):  # no time to judge anything by: closed, nothing kept
            return self._close("nonfinite")
        self._navigate(now, imu, fix, fix_age)
        self.cause = self._closed_reason(now, closed_for, held=False)
        reason = "held" if self._held else self.cause
        if reason is not None:
            return self._close(reason)
        return self._control(now, heading_ref, rate_ref, track)

    def _navigate(
        self, now: float, imu: ImuSample | None, fix: Pose | None, fix_age: float
    ) -> None:
        """Navigation: the estimate, its shadow and its trial predicted to ``now`` on the
        latest plausible IMU sample, then corrected with ``fix`` (or not, see
        :meth:`_take_fix`). Time that went back starts the estimate afresh."""
        if self._last_now is not None and now < self._last_now:
            self.counters[Count.CLOCK_STEPS_BACK] += 1
            self._restart_estimate()
        self._last_now = now
        if imu is not None:
            if self._plausible_imu(imu):
                self._imu, self._imu_at = imu, now
            else:
                self.counters[Count.IMU_REJECTED] += 1
        for filt in (self.filter, self._shadow, self._trial):
            if filt is not None:
                filt.predict(now, self._imu)
        if fix is not None:
            self._take_fix(now, fix, fix_age)

    def _control(
        self, now: float, heading_ref: float, rate_ref: float, track: Track | None
    ) -> tuple[bool, ...]:
        """Control and actuation on the estimate, once nothing holds the valves closed:
        torque and force demands, pulses, valve states."""
        est = self.filter.estimate
        if not all(map(math.isfinite, est)):
            self._restart_estimate()  # a NaN in the filter stays there: start afresh
            return self._close("nonfinite")
        if not (math.isfinite(heading_ref) and math.isfinite(rate_ref)):
            return self._close("nonfinite")
        # No reference spins the platform faster than it may turn (a peer's rate).
        rate_ref = max(-self.config.max_rate, min(self.config.max_rate, rate_ref))
        if self._closed:  # resuming: no integral or PWM period left from before
            self._closed = False
            self.pid.reset()
            self.pwm.reset()
        self.reason = None
        torque = self.pid.update(now, est.heading, est.omega, heading_ref, rate_ref)
        fx, fy = self._force(est, track)
        demands = (fx * self._force_scale, fy * self._force_scale, torque * self._torque_scale)
        if not all(map(math.isfinite, demands)):  # a track's NaN, an overflow
            return self._close("nonfinite")
        signs = self.pwm.update(now, demands)
        self._valves = allocate(*signs)
        return self._valves

    def _force(self, est: Pose, track: Track | None) -> tuple[float, float]:
        """The position controller's force demand (N, body frame): following ``track``,
        else holding a point if position hold is on, else none."""
        if track is not None:
            force = self.position.update(est, track)
            self._hold_here = True  # when the track ends, hold where it left the platform
            return force
        if self.position_hold is None:
            return 0.0, 0.0
        if self._hold_here and not self._explicit_target:
            self.position_hold.target = (est.x, est.y)
        self._hold_here = False
        return self.position_hold.update(est)

    def _take_fix(self, now: float, fix: Pose, age: float) -> None:
        """Correct the filter with ``fix`` (taken ``age`` s ago), or hold it back until
        enough agree, or reject it (and maybe restart from outliers)."""
        x, y, heading = fix.x, fix.y, fix.heading
        if not (
            math.isfinite(x) and math.isfinite(y) and math.isfinite(heading) and math.isfinite(age)
        ):
            self._reject(None)
            return
        x0, x1, y0, y1 = self.fix_area
        if not (x0 <= x <= x1 and y0 <= y <= y1):  # where the metrology saw it
            self._reject(Count.FIX_OUTSIDE)
            return
        if age > self.latency_max + 1e-9:  # no metrology is that late: a device time wrong
            self._reject(Count.FIX_LATE)
            return
        age = max(0.0, age)  # a POSE newer than the IMU: taken as of now
        if not self.filter.reaches(age):
            # Older than the estimate's motion is known (it has just started again): set
            # against it uncarried, the first fixes after a restart in a turn would agree
            # with one another on a heading 0.1 rad behind. Held back.
            self.counters[Count.FIX_UNCARRIED] += 1
            return
        filt = self.filter
        seen, self._seen_at = self._seen_at, now
        stale = self._fix_at is None or now - self._fix_at > self.fix_timeout
        gap = seen is None or now - seen > self.fix_timeout
        if stale and (gap or self._trial is not None):
            # Nothing recent to gate it on: the metrology saw nothing for longer than
            # fix_timeout (out of the cameras' view), so the estimate is dead reckoning
            # and a fix that disagrees with it is where the platform went, not an
            # outlier for an operator to acknowledge. It is acquired, with those that
            # follow it: taken once ``fixes_to_start`` in a row agree. Fixes that keep
            # coming and are rejected are no gap: those go on as outliers.
            self._shadow, self._agreeing = None, 0
            if not self._acquired(now, fix, age):
                return
        elif filt.fixes and not filt.innovation_distance(fix, age) <= self.fix_gate:
            if not self._outlier(now, fix, age):
                self._reject(Count.FIX_OUTLIER)
            return
        else:
            self._shadow, self._agreeing = None, 0  # within the gate: outliers not in a row
            filt.correct(now, fix, age)
        self._fix_at = now - age  # its staleness counts from when the metrology took it
        self._rejecting = False
        if self.position_hold is not None and not self._target_set:
            self._hold_at_estimate()

    def _acquired(self, now: float, fix: Pose, age: float) -> bool:
        """A fix with nothing recent to check it: into the trial copy of the estimate,
        which becomes the estimate once ``fixes_to_start`` in a row agree (True)."""
        trial = self._trial
        if (
            trial is None
            or now - self._trial_at > self.fix_timeout  # its fixes are old news: a gap since
            or not trial.innovation_distance(fix, age) <= self.fix_gate
        ):
            if trial is not None:
                self.counters[Count.FIX_ACQUIRE_RESTARTS] += 1
            trial = self._trial = copy.deepcopy(self.filter)  # from the estimate as it is now
            self._trial_fixes = 0
        trial.correct(now, fix, age)
        self._trial_fixes += 1
        self._trial_at = now
        if self._trial_fixes < self._fixes_to_start:
            self.counters[Count.FIX_ACQUIRING] += 1
            self._rejecting = False  # not rejected: closed for want of a fix, as before it
            return False
        self.filter, self._trial, self._trial_fixes = trial, None, 0
        # Closed still until its velocity is known (``settling``): the fixes that follow
        # are gated and taken by the estimate meanwhile, so a glitch now and then is an
        # outlier of it, not the end of a trial that must begin again.
        self._settling = True
        return True

    def _reject(self, kind: Count | None) -> None:
        self.counters[Count.FIX_REJECTED] += 1
        if kind is not None:
            self.counters[kind] += 1
        self.last_rejection = kind or "fix_nonfinite"
        self._rejecting = True

    def _outlier(self, now: float, fix: Pose, age: float) -> bool:
        """Feed the second filter; restart the estimate from it once enough agree (True:
        this outlier completed them, and the estimate restarted)."""
        shadow = self._shadow
        self._trial, self._trial_fixes = None, 0  # the estimate's fixes no longer agree
        if shadow is None or not shadow.innovation_distance(fix, age) <= self.fix_gate:
            shadow = self._shadow = self._new_filter()  # a first, or one that disagrees
            shadow.predict(now, self._imu)
            # The IMU's record of the motion, not the estimate: late fixes are set against
            # the shadow as they are against the estimate (taken as current, they would lag
            # by the turn since, and the shadow would never complete, or go wrong).
            shadow.follow_motion_of(self.filter)
            self._agreeing = 0
        shadow.correct(now, fix, age)  # uncarried while its own history is short
        self._agreeing += 1
        if self._agreeing >= self._outliers_to_restart and all(map(math.isfinite, shadow.estimate)):
            self.filter = shadow
            self._fix_at = now - age
            self._shadow, self._agreeing, self._rejecting = None, 0, False
            self.counters[Count.FIX_RESTARTS] += 1
            # Closed until an operator acknowledges it (acknowledge_restart): agreeing
            # fixes are where the platform is only if the metrology is right, and a
            # frozen or glitching one repeats the same wrong value (five of them would
            # take over the estimate and fly the platform by it).
            self._restarted = True
            if self.position_hold is not None and not self._explicit_target:
                self._hold_at_estimate()
            return True
        return False

    def _hold_at_estimate(self) -> None:
        assert self.position_hold is not None
        est = self.filter.estimate
        self.position_hold.target = (est.x, est.y)
        self._target_set = True

    def _close(self, reason: Reason) -> tuple[bool, ...]:
        self.counters[CLOSED_COUNT[reason]] += 1
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

    def _closed_reason(
        self, now: float, closed_for: PlatformReason | None, held: bool = True
    ) -> Reason | None:
        if held and self._held:
            return "held"
        if self._fix_at is None:
            return "no_fix"
        if closed_for is not None:
            return closed_for
        if self._restarted:
            return "fix_restart"
        if self._rejecting:
            return "fix_rejected"
        if now - self._fix_at > self.fix_timeout:
            return "stale_fix"
        if self._imu_at is None or now - self._imu_at > self.imu_timeout:
            return "stale_imu"
        if self._settling:
            if not self.filter.velocity_sigma <= self._start_velocity_sigma:
                return "settling"
            self._settling = False
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
    def restarted(self) -> bool:
        """The estimate restarted from agreeing outliers, not yet acknowledged."""
        return self._restarted

    @property
    def acquiring(self) -> tuple[int, int] | None:
        """While fixes are acquired: how many agree so far, and how many it takes."""
        return None if self._trial is None else (self._trial_fixes, self._fixes_to_start)

    @property
    def fix_time(self) -> float | None:
        """``now`` of the latest fix, s (None before the first)."""
        return self._fix_at
