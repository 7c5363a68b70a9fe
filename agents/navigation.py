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

A fix taken ``age`` seconds before the filter's time (the metrology's latency)
measures the platform as it was then: :math:`z = p - \\Delta`, with
:math:`\\Delta` the motion since, which the predictions alone (the IMU, no fix)
estimate (:meth:`NavigationFilter.motion_since`; the filter keeps ``history`` seconds
of them). Linearized about the estimate, :math:`\\Delta = \\hat\\Delta +
(\\mathbf{v} - \\hat{\\mathbf{v}})\\,age` for position and :math:`-(b_g -
\\hat b_g)\\,age` for heading, so the update uses

.. math::

    z' = z + \\hat\\Delta - \\hat{\\mathbf{v}}\\,age \\ (x, y), \\quad
    z'_\\psi = z_\\psi + \\hat\\Delta_\\psi + \\hat b_g\\,age, \\qquad
    H_{age} = [I_3\\ \\ {-age}\\,I_{v}\\ \\ {+age}\\,e_{b_g}\\ \\ 0]

its innovation that of the fix carried by :math:`\\hat\\Delta`, its covariance and
gain knowing that a velocity or bias error shows in it (carried with :math:`H`
alone, a velocity error confirmed itself: the velocity overshot by 60 % at 0.1 s of
latency, and the valves fired on it).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from agents.sensors import ImuSample
from federation.core.angles import wrap_angle
from federation.core.wire import Pose

__all__ = ["NavigationFilter"]

_X, _Y, _PSI, _VX, _VY, _BG, _BAX, _BAY = range(8)


@dataclass
class _Matrices:
    """The Kalman filter's state and matrices, named as filterpy's ``KalmanFilter``
    names them: its predict and update are :meth:`NavigationFilter._predict` and
    ``_update`` (filterpy's arithmetic, operation for operation: a test runs both), so
    an agent does not import filterpy, whose scipy costs half a second at its start."""

    x: np.ndarray
    P: np.ndarray
    F: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    R: np.ndarray


class NavigationFilter:
    """IMU/vision Kalman filter.

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
        if initial is None:
            initial = Pose()
        start = [initial.x, initial.y, initial.heading, initial.vx, initial.vy, 0.0, 0.0, 0.0]
        sp, sh, sv, sg, sa = initial_sigma
        h = np.zeros((3, 8))
        h[0, _X] = h[1, _Y] = h[2, _PSI] = 1.0
        self.kf = _Matrices(
            x=np.array(start, dtype=np.float64).reshape(8, 1),
            P=np.diag([sp**2, sp**2, sh**2, sv**2, sv**2, sg**2, sa**2, sa**2]),
            F=np.eye(8),
            B=np.zeros((8, 3)),
            Q=np.zeros((8, 8)),
            H=h,
            R=np.diag([position_noise**2, position_noise**2, heading_noise**2]),
        )
        self._u = np.zeros((3, 1))
        self._eye = np.eye(8)
        self._z = np.zeros((3, 1))
        self._dt = -1.0
        self._t: float | None = None
        self._gyro = 0.0
        self._imu = ImuSample(0.0, 0.0, 0.0)
        self.fixes = 0
        # What the IMU alone says, summed since the filter began, at each prediction's
        # time (what motion_since reads): the accelerations' velocity (V, lab frame) and
        # its integral (P), and the gyro's turn (G). No estimate is in them: a correction
        # that moves the velocity does not make the past motion look otherwise.
        self._history = history
        self._odometry: deque[tuple[float, float, float, float]] = deque()
        self._sums = (0.0, 0.0, 0.0, 0.0, 0.0)  # Px, Py, Vx, Vy, G

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
            self._predict(u)
            px, py, vx, vy, g = self._sums
            ux, uy = float(u[0, 0]), float(u[1, 0])
            self._sums = (
                px + (vx + 0.5 * ux * dt) * dt,
                py + (vy + 0.5 * uy * dt) * dt,
                vx + ux * dt,
                vy + uy * dt,
                g + float(u[2, 0]) * dt,
            )
        if self._t is None or now > self._t:
            self._t = now
            odometry = self._odometry
            px, py, _, _, g = self._sums
            odometry.append((now, px, py, g))
            # One entry at or before the window's start stays, to interpolate from.
            while len(odometry) > 2 and now - odometry[1][0] >= self._history:
                odometry.popleft()
        self._imu = imu
        self._gyro = imu.gyro

    def _predict(self, u: np.ndarray) -> None:
        """:math:`\\hat{x}^+ = F \\hat{x} + B u`, :math:`P^+ = F P F^T + Q`: the
        arithmetic of ``KalmanFilter.predict`` (its fading memory is 1), operation for
        operation, less the prior's copies it keeps and this filter never reads (a
        control step's time goes to the filter's bookkeeping otherwise)."""
        kf = self.kf
        f = kf.F
        kf.x = np.dot(f, kf.x) + np.dot(kf.B, u)
        kf.P = np.dot(np.dot(f, kf.P), f.T) + kf.Q

    def _update(self, z: np.ndarray) -> None:
        """The Kalman update with ``z`` (3 x 1) in the Joseph form, as
        ``KalmanFilter.update`` computes it, operation for operation, less the copies of
        the measurement and the posterior it keeps and this filter never reads:

        .. math::

            S = H P H^T + R, \\quad K = P H^T S^{-1}, \\quad
            \\hat{x}^+ = \\hat{x} + K (z - H \\hat{x}), \\quad
            P^+ = (I - K H) P (I - K H)^T + K R K^T
        """
        kf = self.kf
        h, r, p = kf.H, kf.R, kf.P
        y = z - np.dot(h, kf.x)
        pht = np.dot(p, h.T)
        k = np.dot(pht, np.linalg.inv(np.dot(h, pht) + r))
        kf.x = kf.x + np.dot(k, y)
        i_kh = self._eye - np.dot(k, h)
        kf.P = np.dot(np.dot(i_kh, p), i_kh.T) + np.dot(np.dot(k, r), k.T)

    def correct(self, now: float, fix: Pose, age: float = 0.0) -> None:
        """Update with a vision fix (x, y, heading) taken ``age`` s before ``now`` (s),
        the filter's time: call :meth:`predict` up to ``now`` first. ValueError for an
        ``age`` the history does not reach back (:meth:`reaches`): taken as of now, it
        would be a lagging fix taken as a current one."""
        z = self._z
        try:
            z[0, 0], z[1, 0], z[2, 0] = self._measured(fix, age)
            self._update(z)
        finally:
            self._h_age(0.0)
        self.fixes += 1
        if self._t is None:
            self._t = now

    def follow_motion_of(self, other: NavigationFilter) -> None:
        """Take ``other``'s record of what the IMU alone said (a filter started beside it
        on the same IMU: it knows the motion as far back, and can set late fixes against
        it at once). No estimate is in that record."""
        self._odometry = deque(other._odometry)
        self._sums = other._sums

    def reaches(self, age: float) -> bool:
        """Whether the history reaches ``age`` s back from the filter's time (a fix that
        old can be set against the motion since)."""
        odometry = self._odometry
        return age <= 0.0 or (bool(odometry) and odometry[-1][0] - age >= odometry[0][0])

    def _measured(self, fix: Pose, age: float) -> tuple[float, float, float]:
        """The fix as :math:`z'` for :math:`H_{age}` (set in ``kf.H``; module notes), its
        heading next to the measurement predicted (the estimate's, unwrapped)."""
        x = self.kf.x
        psi = float(x[_PSI, 0])
        if age <= 0.0:
            self._h_age(0.0)
            return fix.x, fix.y, psi + wrap_angle(fix.heading - psi)
        motion = None if self._t is None else self.motion_since(self._t - age)
        if motion is None:
            raise ValueError(f"a fix {age:g} s old is older than the motion this filter knows")
        self._h_age(age)
        dx, dy, dpsi = motion
        predicted = psi + float(x[_BG, 0]) * age  # H_age's heading row on the estimate
        return fix.x + dx, fix.y + dy, predicted + wrap_angle(fix.heading + dpsi - predicted)

    def _h_age(self, age: float) -> None:
        h = self.kf.H
        h[0, _VX] = h[1, _VY] = -age
        h[2, _BG] = age

    def motion_since(self, then: float) -> tuple[float, float, float] | None:
        """What the IMU alone says of the motion from time ``then`` to the last
        prediction, beyond what the model's terms take (module notes): x, y (m), the
        accelerations' part beyond the velocity now times the time since
        (:math:`\\hat\\Delta - \\hat{\\mathbf{v}}\\,age`; 0 at a steady velocity), and
        heading (rad), the gyro's turn (:math:`\\hat\\Delta_\\psi + \\hat b_g\\,age`).
        Interpolated between predictions; nothing when ``then`` is not in the past;
        None when it is older than the history kept (``history``, or the filter's
        start: a restart)."""
        odometry = self._odometry
        if odometry and not then < odometry[-1][0]:
            return (0.0, 0.0, 0.0)
        if not odometry or then < odometry[0][0]:
            return None
        now, mx, my, mpsi = odometry[-1]
        _, _, vx, vy, _ = self._sums
        mx -= vx * (now - then)  # the velocity now's part: the model's (H_age)
        my -= vy * (now - then)
        i = bisect.bisect_right(odometry, then, key=lambda entry: entry[0])
        if i == 0:
            _, ox, oy, opsi = odometry[0]
        else:
            (t0, x0, y0, p0), (t1, x1, y1, p1) = odometry[i - 1], odometry[i]
            w = (then - t0) / (t1 - t0)
            ox, oy, opsi = x0 + w * (x1 - x0), y0 + w * (y1 - y0), p0 + w * (p1 - p0)
        return (mx - ox, my - oy, mpsi - opsi)

    def innovation_distance(self, fix: Pose, age: float = 0.0) -> float:
        """Mahalanobis distance of a fix (x, y, heading) taken ``age`` s before the
        filter's time from the estimate: how many sigmas of the innovation covariance
        :math:`S = H_{age} P H_{age}^T + R` apart they are (heading wrapped). Call
        :meth:`predict` up to the filter's time first.

        ``inf`` for a fix or a covariance that is not finite.
        """
        kf = self.kf
        if not self.reaches(age):
            return math.inf  # not to be set against this estimate: no agreement claimed
        try:
            zx, zy, zpsi = self._measured(fix, age)
            h = kf.H
            nu = np.array([zx, zy, zpsi]) - (h @ kf.x)[:, 0]
            if not all(map(math.isfinite, nu)):
                return math.inf
            s = h @ kf.P @ h.T + kf.R
        finally:
            self._h_age(0.0)
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
    def velocity_sigma(self) -> float:
        """1-sigma velocity uncertainty the filter claims, along its worse axis, m/s."""
        p = self.kf.P
        return math.sqrt(max(float(p[_VX, _VX]), float(p[_VY, _VY])))

    @property
    def heading_sigma(self) -> float:
        """1-sigma heading uncertainty the filter claims, rad."""
        return math.sqrt(float(self.kf.P[_PSI, _PSI]))
