"""Adaptive gains (the paper's future work): a follower schedules its heading gains
from the leader's dynamic range, estimated from the samples it receives.

The leader's peak heading rate over the last ``window`` seconds of received samples,
:math:`\\hat\\omega_{peak}`, sets a frequency scale against the rate the preset's
gains were tuned for (``nominal_rate_deg``):

.. math::

    s = \\mathrm{clip}(\\hat\\omega_{peak} / \\omega_{nominal},\\ 1,\\ s_{max})

and the PID's gains follow it so that the closed loop's natural frequency scales by
:math:`s` and its damping stays (:math:`J\\ddot\\psi + K_d\\dot\\psi + K_p\\psi = 0`
has :math:`\\omega_n = \\sqrt{K_p/J}`, :math:`\\zeta = K_d / (2\\sqrt{K_p J})`):

.. math::

    K_p' = s^2 K_p, \\qquad K_d' = s K_d, \\qquad K_i' = s^3 K_i

A quiet leader keeps the preset's gains (:math:`s = 1`); a brisk one stiffens the
follower, so it lags less, at the cost of more valve time (the report shows both).
The torque saturation is the thrusters' and stays.
"""

from __future__ import annotations

import math
from collections import deque

from agents.control import HeadingPid
from schemas.scenario import AdaptiveConfig

__all__ = ["AdaptiveGains"]


class AdaptiveGains:
    """Schedules ``pid``'s gains from the received leader samples (:meth:`observe`)."""

    def __init__(self, config: AdaptiveConfig, pid: HeadingPid):
        self.config = config
        self.pid = pid
        self.base = (pid.kp, pid.ki, pid.kd)
        self.nominal = math.radians(config.nominal_rate_deg)
        self.scale = 1.0
        self.peak = 0.0
        self._seen: deque[tuple[float, float]] = deque()  # (stamp, |rate|)
        self._last_stamp: float | None = None

    def observe(self, stamp: float, rate: float) -> float:
        """A received leader sample: its stamp (s, any one clock) and heading rate
        (rad/s). Returns the scale now in force."""
        if self._last_stamp is not None and stamp <= self._last_stamp:
            return self.scale  # the same sample again, or an old one
        self._last_stamp = stamp
        seen = self._seen
        while seen and seen[-1][1] <= abs(rate):  # a monotonic queue: the window's peak
            seen.pop()
        seen.append((stamp, abs(rate)))
        while seen and seen[0][0] < stamp - self.config.window:
            seen.popleft()
        self.peak = seen[0][1]
        self.set_scale(min(max(self.peak / self.nominal, 1.0), self.config.max_scale))
        return self.scale

    def set_scale(self, scale: float) -> None:
        """Gains for frequency scale ``scale`` (1: the preset's)."""
        self.scale = scale
        kp, ki, kd = self.base
        self.pid.kp, self.pid.ki, self.pid.kd = scale**2 * kp, scale**3 * ki, scale * kd
