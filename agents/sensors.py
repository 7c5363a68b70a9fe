"""Sensor models: an IMU (gyro and body accelerometers) and external vision.

No I/O and no clock: the caller passes the true state and the time. Noise comes
from a seeded :class:`numpy.random.Generator`, so a run repeats exactly.

IMU (100 Hz on KNATTE), white noise :math:`n` and a constant bias :math:`b`:

.. math::

    \\tilde\\omega = \\omega + b_g + n_g, \\qquad
    \\tilde{\\mathbf{a}} = \\mathbf{a}_b + \\mathbf{b}_a + \\mathbf{n}_a

where :math:`\\mathbf{a}_b` is the specific force in the body frame (the thrusters'
force over the mass; the table slope is not sensed, see :mod:`agents.dynamics`).

Vision (one camera at 20 Hz on KNATTE, six Vicon cameras on PINOCCHIO): the pose
plus white noise, heading wrapped to :math:`(-\\pi, \\pi]`, and no fix at all
outside the coverage rectangle.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from federation.core.angles import wrap_angle
from federation.core.wire import Pose

# wrap_angle is federation.core.angles's, the one wrap; re-exported for older callers.
__all__ = ["Coverage", "Imu", "ImuSample", "Sampler", "Vision", "wrap_angle"]


class ImuSample(NamedTuple):
    """Gyro rate (rad/s) and body-frame specific force along x and y (m/s^2)."""

    gyro: float
    ax: float
    ay: float


class Coverage(NamedTuple):
    """The rectangle the vision system sees: width along x and height along y (m),
    centred at (cx, cy) in the lab frame (m)."""

    width: float
    height: float
    cx: float = 0.0
    cy: float = 0.0

    def contains(self, x: float, y: float) -> bool:
        return abs(x - self.cx) <= 0.5 * self.width and abs(y - self.cy) <= 0.5 * self.height


class Sampler:
    """A sample clock on a fixed grid: :meth:`due` is true once per period.

    The grid starts at the first call's ``now`` and advances by whole periods, so
    the samples do not drift however the calls jitter; a long gap yields one
    sample, not a burst.
    """

    def __init__(self, rate: float):
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"sample rate must be a positive number of Hz, not {rate!r}")
        self.period = 1.0 / rate
        self._eps = 1e-6 * self.period
        self._next: float | None = None

    def due(self, now: float) -> bool:
        if self._next is None:
            self._next = now + self.period
            return True
        if now + self._eps < self._next:
            return False
        self._next += self.period
        if self._next <= now + self._eps:  # fell behind by more than a period: re-anchor
            self._next = now + self.period
        return True

    def reset(self) -> None:
        self._next = None


class _Normal:
    """Standard normal draws taken from ``rng`` in blocks (cheap per sample)."""

    def __init__(self, rng: np.random.Generator, width: int, block: int = 1024):
        self._rng = rng
        self._shape = (block, width)
        self._rows: list[list[float]] = []
        self._index = 0

    def draw(self) -> list[float]:
        if self._index >= len(self._rows):
            self._rows = self._rng.standard_normal(self._shape).tolist()
            self._index = 0
        row = self._rows[self._index]
        self._index += 1
        return row


class Imu:
    """Gyro and two accelerometers with white noise and constant bias.

    Parameters
    ----------
    rate : float
        Samples per second, Hz (the caller schedules with :attr:`sampler`).
    gyro_noise, gyro_bias : float
        1-sigma white noise per sample and constant bias, rad/s.
    accel_noise : float
        1-sigma white noise per sample, m/s^2.
    accel_bias : tuple of float
        Constant bias along body x and y, m/s^2.
    rng : numpy.random.Generator
        Noise source.
    """

    def __init__(
        self,
        rate: float,
        gyro_noise: float,
        gyro_bias: float,
        accel_noise: float,
        accel_bias: tuple[float, float],
        rng: np.random.Generator,
    ):
        self.rate = rate
        self.sampler = Sampler(rate)
        self.gyro_noise = gyro_noise
        self.gyro_bias = gyro_bias
        self.accel_noise = accel_noise
        self.accel_bias = accel_bias
        self._normal = _Normal(rng, 3)

    def measure(self, omega: float, ax: float, ay: float) -> ImuSample:
        """A sample of the true rate ``omega`` (rad/s) and body specific force (m/s^2)."""
        n = self._normal.draw()
        return ImuSample(
            omega + self.gyro_bias + self.gyro_noise * n[0],
            ax + self.accel_bias[0] + self.accel_noise * n[1],
            ay + self.accel_bias[1] + self.accel_noise * n[2],
        )


class Vision:
    """Pose fixes with white noise inside the coverage rectangle.

    Parameters
    ----------
    rate : float
        Fixes per second, Hz.
    position_noise : float
        1-sigma noise of x and y, m.
    heading_noise : float
        1-sigma noise of the heading, rad.
    coverage : Coverage
        Where the cameras see the platform.
    rng : numpy.random.Generator
        Noise source.
    """

    def __init__(
        self,
        rate: float,
        position_noise: float,
        heading_noise: float,
        coverage: Coverage,
        rng: np.random.Generator,
    ):
        self.rate = rate
        self.sampler = Sampler(rate)
        self.position_noise = position_noise
        self.heading_noise = heading_noise
        self.coverage = coverage
        self._normal = _Normal(rng, 3)

    def measure(self, x: float, y: float, heading: float) -> Pose | None:
        """A noisy pose (rates zero) of the true ``x``, ``y`` (m), ``heading`` (rad),
        or None outside the coverage."""
        n = self._normal.draw()  # drawn even without a fix, so noise streams stay aligned
        if not self.coverage.contains(x, y):
            return None
        return Pose(
            x + self.position_noise * n[0],
            y + self.position_noise * n[1],
            wrap_angle(heading + self.heading_noise * n[2]),
        )
