"""Heading-loop margins with python-control: how much link delay the loop can bear.

The heading loop of one platform, with pulse-width modulation taken as its
average torque (valid when the PWM period is short against the loop's time
constants):

.. math::

    P(s) = \\frac{1}{I s^2}, \\qquad
    C(s) = K_p + \\frac{K_i}{s} + K_d s \\quad \\text{(Eq. 2)}, \\qquad
    L(s) = C(s) P(s)

Gain and phase margins come from :func:`control.stability_margins`; the delay
margin is the phase margin over the crossover frequency, :math:`\\tau_m = \\phi_m / \\omega_c`:
the pure delay that, added in the loop, takes it to the edge of instability.
A link delay above a quarter of it is flagged.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import control

from schemas.platform import PlatformConfig

__all__ = ["WARN_FRACTION", "Margins", "heading_margins"]

WARN_FRACTION = 0.25  # link delay / delay margin above which fedlab warns


@dataclass(frozen=True)
class Margins:
    platform: str
    kp: float
    ki: float
    kd: float
    inertia: float
    gain_margin: float  # ratio (inf: the phase never reaches -180 degrees)
    phase_margin_deg: float
    crossover_rad_s: float
    delay_margin_s: float

    def warn(self, delay: float) -> str | None:
        """A warning if a one-way link delay (s) exceeds a quarter of the delay margin."""
        if delay > WARN_FRACTION * self.delay_margin_s:
            return (
                f"link delay {delay * 1e3:.0f} ms is more than a quarter of {self.platform}'s "
                f"heading-loop delay margin ({self.delay_margin_s * 1e3:.0f} ms): "
                "expect oscillation; lower the gains or compensate the delay"
            )
        return None

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if math.isinf(self.gain_margin):
            d["gain_margin"] = None  # JSON has no infinity: none means unbounded
        return d


def heading_margins(config: PlatformConfig) -> Margins:
    c = config.control
    s = control.tf("s")
    loop = (c.kp + c.ki / s + c.kd * s) / (config.inertia * s**2)
    gm, pm, _sm, _wpc, wgc, _wms = control.stability_margins(loop)
    if not (math.isfinite(pm) and wgc > 0):
        raise ValueError(f"{config.name}: the heading loop has no gain crossover (check gains)")
    return Margins(
        platform=config.name,
        kp=c.kp,
        ki=c.ki,
        kd=c.kd,
        inertia=config.inertia,
        gain_margin=float(gm),
        phase_margin_deg=float(pm),
        crossover_rad_s=float(wgc),
        delay_margin_s=math.radians(pm) / float(wgc),
    )
