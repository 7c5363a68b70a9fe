"""Navigation: a Kalman filter blending the IMU with external vision (paper section 2.3).

The IMU drives the prediction (gyro and accelerometers as known inputs) and each
vision fix corrects it. No I/O and no clock: every call takes the time ``now``.

State (lab frame; biases in the body frame):

.. math::

    \\hat{x} = [x,\\ y,\\ \\psi,\\ v_x,\\ v_y,\\ b_g,\\ b_{a,x},\\ b_{a,y}]

Prediction over :math:`\\Delta t` with the gyro :math:`\\tilde\\omega` and the
accelerometers :math:`\\tilde{\\mathbf{a}}`, rotated by the current heading estimate
(:math:`R = R(\\hat\\psi)`, held over the step, so the filter stays linear):

.. math::

    \\psi^+ = \\psi + (\\tilde\\omega - b_g) \\Delta t, \\qquad
    \\mathbf{v}^+ = \\mathbf{v} + R(\\tilde{\\mathbf{a}} - \\mathbf{b}_a) \\Delta t, \\qquad
    \\mathbf{p}^+ = \\mathbf{p} + \\mathbf{v} \\Delta t
        + \\tfrac{1}{2} R(\\tilde{\\mathbf{a}} - \\mathbf{b}_a) \\Delta t^2

that is :math:`\\hat{x}^+ = F \\hat{x} + B u` with :math:`u = [R\\tilde{\\mathbf{a}},
\\tilde\\omega]`, each IMU input the mean of the samples at both ends of the step
(trapezoid rule: exact for the piecewise-linear rates of on/off thrusters).

A vision fix :math:`z = [x, y, \\psi]` updates with
:math:`H = [I_3\\ 0]`; its heading is unwrapped next to the estimate first, so the
estimate's heading is continuous (not wrapped). The published rate is
:math:`\\hat\\omega = \\tilde\\omega - b_g`.

How far a fix is from what the filter expects (:meth:`NavigationFilter.innovation_distance`)
is the Mahalanobis distance of its innovation, heading wrapped:

.. math::

    \\nu = z - H\\hat{x}, \\qquad S = H P H^T + R, \\qquad d = \\sqrt{\\nu^T S^{-1} \\nu}

For a filter whose noise model holds, :math:`d^2` is chi-square with 3 degrees of
freedom: :math:`P(d > 5) = 1.5 \\times 10^{-5}`, :math:`P(d > 6) = 7 \\times 10^{-8}`.

A fix that reached the filter late (the metrology's latency) describes the platform
as it was then: :meth:`NavigationFilter.motion_since` gives how far the predictions
alone (the IMU, no fix) moved the estimate since a past time, to carry such a fix to
now. The filter keeps ``history`` seconds of them.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from agents.sensors import ImuSample
from federation.core.angles import wrap_angle
from federation.core.wire import Pose

if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter

__all__ = ["NavigationFilter"]

_X, _Y, _PSI, _VX, _VY, _BG, _BAX, _BAY = range(8)


class NavigationFilter:
    """IMU/vision Kalman filter (a :class:`filterpy.kalman.KalmanFilter` inside).

    Parameters
    ----------
    gyro_noise : float
        Gyro white noise per sample, rad/s.
    accel_noise : float
        Accelerometer white noise per sample, m/s^2.
    position_noise, heading_noise : float
        Vision noise (1 sigma), m and rad.
    unmodelled_accel : float
        Acceleration the accelerometers cannot see (table slope), m/s^2, 1 sigma.
    gyro_bias_walk, accel_bias_walk : float
        Bias random walks, rad/s and m/s^2 per square-root second.
    initial : Pose, optional
        Starting estimate (its ``omega`` is ignored); None: at rest at the origin.
    initial_sigma : tuple of float
        1-sigma uncertainty of the start: position (m), heading (rad), velocity
        (m/s), gyro bias (rad/s), accelerometer bias (m/s^2).
    history : float
        How far back :meth:`motion_since` reaches, s.
    """

    def __init__(
        self,
        gyro_noise: float,
        accel_noise: float,
        position_noise: float,
        heading_noise: float,
        unmodelled_accel: float = 0.003,
        gyro_bias_walk: float = 1e-5,
        accel_bias_walk: float = 1e-4,
        initial: Pose | None = None,
        initial_sigma: tuple[float, float, float, float, float] = (1.0, 1.0, 0.1, 0.02, 0.05),
        history: float = 1.0,
    ):
        self._q_gyro = gyro_noise**2
        self._q_accel = accel_noise**2 + unmodelled_accel**2
        self._q_bg = gyro_bias_walk**2
        self._q_ba = accel_bias_walk**2
        # Imported here: filterpy brings scipy, 60 MiB and half a second at start that a
        # process of kinematic agents (a bench worker, a gateway) never uses (issue 17).
        from filterpy.kalman import KalmanFilter

        kf: KalmanFilter = KalmanFilter(dim_x=8, dim_z=3, dim_u=3)
        if initial is None:
            initial = Pose()
        start = [initial.x, initial.y, initial.heading, initial.vx, initial.vy, 0.0, 0.0, 0.0]
        kf.x = np.array(start, dtype=np.float64).reshape(8, 1)
        sp, sh, sv, sg, sa = initial_sigma
        kf.P = np.diag([sp**2, sp**2, sh**2, sv**2, sv**2, sg**2, sa**2, sa**2])
        kf.H = np.zeros((3, 8))
        kf.H[0, _X] = kf.H[1, _Y] = kf.H[2, _PSI] = 1.0
        kf.R = np.diag([position_noise**2, position_noise**2, heading_noise**2])
        kf.F = np.eye(8)
        kf.B = np.zeros((8, 3))
        kf.Q = np.zeros((8, 8))
        self.kf = kf
        self._u = np.zeros((3, 1))
        self._z = np.zeros((3, 1))
        self._dt = -1.0
        self._t: float | None = None
        self._gyro = 0.0
        self._imu = ImuSample(0.0, 0.0, 0.0)
        self.fixes = 0
        # The predictions' motion summed (x, y, heading) at each prediction's time: what
        # motion_since reads. Corrections are not in it: they are news, not motion.
        self._history = history
        self._odometry: deque[tuple[float, float, float, float]] = deque()
        self._moved = (0.0, 0.0, 0.0)

    @property
    def time(self) -> float | None:
        """Time of the last prediction, s (None before the first IMU sample)."""
        return self._t

    def _set_dt(self, dt: float) -> None:
        kf = self.kf
        h2 = 0.5 * dt * dt
        kf.F[_X, _VX] = kf.F[_Y, _VY] = dt
        kf.F[_PSI, _BG] = -dt
        kf.B[_X, 0] = kf.B[_Y, 1] = h2
        kf.B[_VX, 0] = kf.B[_VY, 1] = dt
        kf.B[_PSI, 2] = dt
        q = kf.Q
        q.fill(0.0)
        qa = self._q_accel
        for p, v in ((_X, _VX), (_Y, _VY)):  # discrete white acceleration per step
            q[p, p] = h2 * h2 * qa
            q[p, v] = q[v, p] = h2 * dt * qa
            q[v, v] = dt * dt * qa
        q[_PSI, _PSI] = dt * dt * self._q_gyro
        q[_BG, _BG] = dt * self._q_bg
        q[_BAX, _BAX] = q[_BAY, _BAY] = dt * self._q_ba
        self._dt = dt

    def predict(self, now: float, imu: ImuSample) -> None:
        """Propagate from the last prediction to ``now`` (s) with an IMU sample.

        The first call only sets the time (and the rate estimate).
        """
        if self._t is not None and now > self._t:
            dt = now - self._t
            if abs(dt - self._dt) > 1e-12:
                self._set_dt(dt)
            kf = self.kf
            psi = float(kf.x[_PSI, 0])
            c = math.cos(psi)
            s = math.sin(psi)
            h2 = 0.5 * dt * dt
            f = kf.F
            f[_X, _BAX], f[_X, _BAY] = -h2 * c, h2 * s
            f[_Y, _BAX], f[_Y, _BAY] = -h2 * s, -h2 * c
            f[_VX, _BAX], f[_VX, _BAY] = -dt * c, dt * s
            f[_VY, _BAX], f[_VY, _BAY] = -dt * s, -dt * c
            # trapezoid: the mean of this and the last sample over the step
            prev = self._imu
            ax = 0.5 * (prev.ax + imu.ax)
            ay = 0.5 * (prev.ay + imu.ay)
            u = self._u
            u[0, 0] = c * ax - s * ay
            u[1, 0] = s * ax + c * ay
            u[2, 0] = 0.5 * (prev.gyro + imu.gyro)
            x = kf.x
            x0, y0, psi0 = float(x[_X, 0]), float(x[_Y, 0]), psi
            kf.predict(u=u)
            x = kf.x
            mx, my, mpsi = self._moved
            self._moved = (
                mx + float(x[_X, 0]) - x0,
                my + float(x[_Y, 0]) - y0,
                mpsi + float(x[_PSI, 0]) - psi0,
            )
        if self._t is None or now > self._t:
            self._t = now
            odometry = self._odometry
            odometry.append((now, *self._moved))
            # One entry at or before the window's start stays, to interpolate from.
            while len(odometry) > 2 and now - odometry[1][0] >= self._history:
                odometry.popleft()
        self._imu = imu
        self._gyro = imu.gyro

    def correct(self, now: float, fix: Pose) -> None:
        """Update with a vision fix (x, y, heading) taken at ``now`` (s).

        The fix is taken to be at the filter's time: call :meth:`predict` up to
        ``now`` first.
        """
        kf = self.kf
        psi = float(kf.x[_PSI, 0])
        z = self._z
        z[0, 0] = fix.x
        z[1, 0] = fix.y
        z[2, 0] = psi + wrap_angle(fix.heading - psi)
        kf.update(z)
        self.fixes += 1
        if self._t is None:
            self._t = now

    def motion_since(self, then: float) -> tuple[float, float, float]:
        """How far the predictions moved the estimate from time ``then`` to the last
        prediction: x, y (m) and heading (rad); interpolated between predictions, from
        the oldest kept (``history``) when ``then`` is older, nothing when ``then`` is
        not in the past."""
        odometry = self._odometry
        if not odometry or not then < odometry[-1][0]:
            return (0.0, 0.0, 0.0)
        _, mx, my, mpsi = odometry[-1]
        i = bisect.bisect_right(odometry, then, key=lambda entry: entry[0])
        if i == 0:
            _, ox, oy, opsi = odometry[0]
        else:
            (t0, x0, y0, p0), (t1, x1, y1, p1) = odometry[i - 1], odometry[i]
            w = (then - t0) / (t1 - t0)
            ox, oy, opsi = x0 + w * (x1 - x0), y0 + w * (y1 - y0), p0 + w * (p1 - p0)
        return (mx - ox, my - oy, mpsi - opsi)

    def innovation_distance(self, fix: Pose) -> float:
        """Mahalanobis distance of a fix (x, y, heading) from the estimate: how many
        sigmas of the innovation covariance :math:`S = H P H^T + R` apart they are
        (heading wrapped). Call :meth:`predict` up to the fix's time first.

        ``inf`` for a fix or a covariance that is not finite.
        """
        kf = self.kf
        x = kf.x
        psi = float(x[_PSI, 0])
        dx, dy, dpsi = fix.x - float(x[_X, 0]), fix.y - float(x[_Y, 0]), fix.heading - psi
        if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dpsi)):
            return math.inf
        nu = np.array([dx, dy, wrap_angle(dpsi)])
        s = kf.H @ kf.P @ kf.H.T + kf.R
        try:
            d2 = float(nu @ np.linalg.solve(s, nu))
        except np.linalg.LinAlgError:
            return math.inf
        return math.sqrt(d2) if d2 >= 0 else math.inf  # NaN and a negative: not a distance

    @property
    def estimate(self) -> Pose:
        """The current estimate; ``omega`` is the latest gyro rate less the bias estimate."""
        x = self.kf.x
        return Pose(
            float(x[_X, 0]),
            float(x[_Y, 0]),
            float(x[_PSI, 0]),
            float(x[_VX, 0]),
            float(x[_VY, 0]),
            self._gyro - float(x[_BG, 0]),
        )

    @property
    def gyro_bias(self) -> float:
        """Estimated gyro bias, rad/s."""
        return float(self.kf.x[_BG, 0])

    @property
    def heading_sigma(self) -> float:
        """1-sigma heading uncertainty the filter claims, rad."""
        return math.sqrt(float(self.kf.P[_PSI, _PSI]))
