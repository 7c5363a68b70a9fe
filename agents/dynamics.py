"""Planar rigid-body dynamics of an air-bearing platform with eight on/off thrusters.

Pure functions in python-control's style, ``f(t, x, u, params)``; no I/O, no clock.

State, lab (inertial) frame:

.. math::

    x = [x,\\ y,\\ \\psi,\\ v_x,\\ v_y,\\ \\omega]
    \\quad (\\mathrm{m, m, rad, m/s, m/s, rad/s})

Input: the eight valve states :math:`u_i \\in \\{0, 1\\}`. Valve :math:`i` gives a
body-frame force :math:`F\\,\\mathbf{d}_i` at :math:`a\\,\\mathbf{p}_i`, where
:math:`F` is the thrust of one thruster and :math:`a` the moment arm:

.. math::

    \\mathbf{f}_b = F \\sum_i u_i \\mathbf{d}_i, \\qquad
    \\tau = F a \\sum_i u_i (p_{i,x} d_{i,y} - p_{i,y} d_{i,x})

    \\dot{x} = \\begin{bmatrix} v_x \\\\ v_y \\\\ \\omega \\\\
        \\frac{1}{m} R(\\psi) \\mathbf{f}_b - g \\nabla h(x, y) \\\\
        \\tau / I \\end{bmatrix}

with :math:`R(\\psi)` the body-to-lab rotation and :math:`h` the table's height
field (the surface anomalies; zero on a perfect table). The slope force
:math:`-m g \\nabla h` acts through the centre of mass: it pushes, it does not turn,
and the accelerometers, lying in the tilted plane, do not measure it.

Thruster geometry (body frame; positions in units of the moment arm ``a``, so each
line of action passes at ``a`` from the centre; torque positive counter-clockwise):

=====  ==========  =========  ===========
valve  position    force      torque
=====  ==========  =========  ===========
0      (-a, +a)    +x         -F a
1      (-a, -a)    +x         +F a
2      (+a, +a)    -x         +F a
3      (+a, -a)    -x         -F a
4      (+a, -a)    +y         +F a
5      (-a, -a)    +y         -F a
6      (+a, +a)    -y         -F a
7      (-a, +a)    -y         +F a
=====  ==========  =========  ===========

Pairs (:data:`PAIRS`): ``+x`` = 0, 1; ``-x`` = 2, 3; ``+y`` = 4, 5; ``-y`` = 6, 7 each
give :math:`2F` with no torque; ``+torque`` = 1, 2 and ``-torque`` = 0, 3 each give
:math:`\\pm 2 F a` with no force.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from schemas.platform import PlatformConfig

__all__ = [
    "GRAVITY",
    "PAIRS",
    "THRUSTERS",
    "BodyParams",
    "SlopeField",
    "Thruster",
    "f",
    "step",
    "wrench",
]

GRAVITY = 9.80665  # m/s^2


class Thruster(NamedTuple):
    """One thruster: position in units of the moment arm, unit force direction (body frame)."""

    px: float
    py: float
    dx: float
    dy: float


THRUSTERS: tuple[Thruster, ...] = (
    Thruster(-1.0, +1.0, +1.0, 0.0),
    Thruster(-1.0, -1.0, +1.0, 0.0),
    Thruster(+1.0, +1.0, -1.0, 0.0),
    Thruster(+1.0, -1.0, -1.0, 0.0),
    Thruster(+1.0, -1.0, 0.0, +1.0),
    Thruster(-1.0, -1.0, 0.0, +1.0),
    Thruster(+1.0, +1.0, 0.0, -1.0),
    Thruster(-1.0, +1.0, 0.0, -1.0),
)

PAIRS: dict[str, tuple[int, int]] = {
    "+x": (0, 1),
    "-x": (2, 3),
    "+y": (4, 5),
    "-y": (6, 7),
    "+torque": (1, 2),
    "-torque": (0, 3),
}

State = npt.NDArray[np.float64]


@dataclass(frozen=True)
class BodyParams:
    """Rigid body and thrusters: mass (kg), inertia (kg m^2), thrust of one thruster (N),
    moment arm (m)."""

    mass: float
    inertia: float
    thrust: float
    arm: float
    matrix: npt.NDArray[np.float64] = field(init=False, repr=False, compare=False)
    """3 x 8: body force x (N), body force y (N) and torque (Nm) per open valve."""
    columns: tuple[tuple[float, float, float], ...] = field(init=False, repr=False, compare=False)
    """The same per valve, as floats (the fast path)."""

    def __post_init__(self) -> None:
        for name in ("mass", "inertia", "thrust", "arm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, not {value!r}")
        m = np.array(
            [
                [t.dx for t in THRUSTERS],
                [t.dy for t in THRUSTERS],
                [self.arm * (t.px * t.dy - t.py * t.dx) for t in THRUSTERS],
            ],
            dtype=np.float64,
        )
        m *= self.thrust
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)
        columns = tuple((float(a), float(b), float(c)) for a, b, c in m.T)
        object.__setattr__(self, "columns", columns)

    @classmethod
    def from_config(cls, config: PlatformConfig) -> BodyParams:
        return cls(config.mass, config.inertia, config.thrust, config.moment_arm)


def wrench(u: Sequence[float] | npt.NDArray[np.float64], params: BodyParams) -> tuple[float, ...]:
    """Body force x, y (N) and torque (Nm) of the valve states ``u`` (eight 0/1 values)."""
    if len(u) != len(THRUSTERS):
        raise ValueError(f"expected {len(THRUSTERS)} valve states, got {len(u)}")
    fx = fy = tau = 0.0
    for on, (a, b, c) in zip(u, params.columns, strict=True):
        if on:
            fx += a
            fy += b
            tau += c
    return fx, fy, tau


@dataclass(frozen=True)
class SlopeField:
    """Table height as a sum of sinusoids (the paper's surface anomalies).

    .. math::

        h(x, y) = \\sum_k A_k \\sin(k_{x,k} x + k_{y,k} y + \\varphi_k), \\qquad
        \\nabla h = \\sum_k A_k \\cos(\\cdot) \\, (k_{x,k}, k_{y,k})

    Heights in m, wave numbers in rad/m, phases in rad.
    """

    terms: tuple[tuple[float, float, float, float], ...]
    """(amplitude A, kx, ky, phase) per sinusoid."""

    @classmethod
    def random(cls, seed: int, slope: float, wavelength: float, components: int = 3) -> SlopeField:
        """A repeatable field: random directions and phases, wavelengths within +/-50 % of
        ``wavelength`` (m), each sinusoid's peak slope :math:`A_k |k_k|` equal to ``slope``."""
        if components < 1:
            raise ValueError(f"components must be at least 1, not {components}")
        if not wavelength > 0:
            raise ValueError(f"wavelength must be positive metres, not {wavelength!r}")
        rng = np.random.default_rng(seed)
        terms = []
        for _ in range(components):
            k = 2.0 * math.pi / (wavelength * float(rng.uniform(0.5, 1.5)))
            direction = float(rng.uniform(0.0, 2.0 * math.pi))
            phase = float(rng.uniform(0.0, 2.0 * math.pi))
            terms.append((slope / k, k * math.cos(direction), k * math.sin(direction), phase))
        return cls(tuple(terms))

    def height(self, x: float, y: float) -> float:
        """Surface height at (x, y), m."""
        return sum(a * math.sin(kx * x + ky * y + p) for a, kx, ky, p in self.terms)

    def gradient(self, x: float, y: float) -> tuple[float, float]:
        """Slope (dh/dx, dh/dy) at (x, y), dimensionless."""
        gx = gy = 0.0
        for a, kx, ky, p in self.terms:
            c = a * math.cos(kx * x + ky * y + p)
            gx += c * kx
            gy += c * ky
        return gx, gy


def _rates(
    s: Sequence[float],
    fx: float,
    fy: float,
    tau: float,
    params: BodyParams,
    disturbance: SlopeField | None,
) -> tuple[float, float, float, float, float, float]:
    c = math.cos(s[2])
    sn = math.sin(s[2])
    ax = (c * fx - sn * fy) / params.mass
    ay = (sn * fx + c * fy) / params.mass
    if disturbance is not None:
        gx, gy = disturbance.gradient(s[0], s[1])
        ax -= GRAVITY * gx
        ay -= GRAVITY * gy
    return s[3], s[4], s[5], ax, ay, tau / params.inertia


def f(
    t: float,
    x: State,
    u: Sequence[float] | npt.NDArray[np.float64],
    params: BodyParams,
    disturbance: SlopeField | None = None,
) -> State:
    """State derivative :math:`\\dot{x} = f(t, x, u)` (time-invariant: ``t`` is unused)."""
    fx, fy, tau = wrench(u, params)
    return np.array(_rates(x.tolist(), fx, fy, tau, params, disturbance), dtype=np.float64)


def step(
    x: State,
    u: Sequence[float] | npt.NDArray[np.float64],
    dt: float,
    params: BodyParams,
    disturbance: SlopeField | None = None,
) -> State:
    """State after ``dt`` seconds with the valves ``u`` held (classic Runge-Kutta, RK4).

    .. math::

        x_{k+1} = x_k + \\tfrac{\\Delta t}{6}(k_1 + 2 k_2 + 2 k_3 + k_4)

    A pure torque from rest is integrated exactly (the rates are polynomial in time).
    """
    fx, fy, tau = wrench(u, params)
    s = x.tolist()
    h = dt
    k1 = _rates(s, fx, fy, tau, params, disturbance)
    k2 = _rates(
        [a + 0.5 * h * b for a, b in zip(s, k1, strict=True)], fx, fy, tau, params, disturbance
    )
    k3 = _rates(
        [a + 0.5 * h * b for a, b in zip(s, k2, strict=True)], fx, fy, tau, params, disturbance
    )
    k4 = _rates([a + h * b for a, b in zip(s, k3, strict=True)], fx, fy, tau, params, disturbance)
    return np.array(
        [
            a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
            for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4, strict=True)
        ],
        dtype=np.float64,
    )
