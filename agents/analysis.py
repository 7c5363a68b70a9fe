"""Heading-loop margins: how much link delay the loop can bear.

The heading loop of one platform, with pulse-width modulation taken as its
average torque (valid when the PWM period is short against the loop's time
constants):

.. math::

    P(s) = \\frac{1}{I s^2}, \\qquad
    C(s) = K_p + \\frac{K_i}{s} + K_d s \\quad \\text{(Eq. 2)}, \\qquad
    L(s) = C(s) P(s)

On :math:`s = j\\omega`, :math:`L = -(K_p + j(K_d\\omega - K_i/\\omega)) / (I\\omega^2)`,
so the margins have closed forms (python-control's ``stability_margins`` gives the same
to 1e-12, tests/unit/agents/test_analysis.py; an agent does not import it, whose
scipy and matplotlib cost a second of start-up): the gain crossovers
:math:`|L| = 1` are the positive roots :math:`u = \\omega^2` of
:math:`I^2u^3 - K_d^2u^2 + (2K_dK_i - K_p^2)u - K_i^2 = 0`, the phase margin there is
:math:`\\operatorname{atan2}(K_d\\omega - K_i/\\omega, K_p)` (the smallest, if several),
and the phase crosses -180 degrees at :math:`\\omega^2 = K_i/K_d`, where the gain margin
is :math:`I K_i / (K_d K_p)` (none without an integral or a derivative term: infinite).
The delay margin is the phase margin over the crossover frequency,
:math:`\\tau_m = \\phi_m / \\omega_c`: the pure delay that, added in the loop, takes
it to the edge of instability. A link delay above a quarter of it is flagged.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

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
    """The margins of ``config``'s heading loop (the module says how); ValueError when
    the loop has no gain crossover."""
    c, inertia = config.control, config.inertia
    kp, ki, kd = c.kp, c.ki, c.kd
    roots = np.roots([inertia * inertia, -kd * kd, 2 * kd * ki - kp * kp, -ki * ki])
    crossovers = [math.sqrt(r.real) for r in roots if r.real > 0 and abs(r.imag) <= 1e-9 * abs(r)]
    if not crossovers or kp <= 0:
        raise ValueError(f"{config.name}: the heading loop has no gain crossover (check gains)")
    margins = [(math.degrees(math.atan2(kd * w - ki / w, kp)), w) for w in crossovers]
    pm, wgc = min(margins, key=lambda m: abs(m[0]))
    gm = inertia * ki / (kd * kp) if ki > 0 and kd > 0 else math.inf
    return Margins(
        platform=config.name,
        kp=kp,
        ki=ki,
        kd=kd,
        inertia=inertia,
        gain_margin=gm,
        phase_margin_deg=pm,
        crossover_rad_s=wgc,
        delay_margin_s=math.radians(pm) / wgc,
    )
