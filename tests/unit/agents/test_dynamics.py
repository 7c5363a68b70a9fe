"""Rigid-body dynamics and thruster geometry (agents/dynamics.py)."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import control as ct
import numpy as np
import pytest

from agents.dynamics import (
    GRAVITY,
    PAIRS,
    THRUSTERS,
    BodyParams,
    SlopeField,
    f,
    step,
    wrench,
)
from schemas.platform import load_platform

KNATTE = load_platform("knatte")
BODY = BodyParams.from_config(KNATTE)
F, A = KNATTE.thrust, KNATTE.moment_arm
REST = np.zeros(6)


def valves(*open_: int) -> list[int]:
    return [1 if i in open_ else 0 for i in range(8)]


def run(
    x: np.ndarray,
    u: list[int],
    seconds: float,
    dt: float = 0.01,
    disturbance: SlopeField | None = None,
) -> np.ndarray:
    for _ in range(round(seconds / dt)):
        x = step(x, u, dt, BODY, disturbance)
    return x


# ---------------------------------------------------------------- geometry


def test_knatte_moment_arm_from_the_papers_numbers() -> None:
    # 0.032 Nm / 0.20 N; the maxima agree: 0.102 / 0.64 = 0.159
    assert pytest.approx(0.16) == A
    assert KNATTE.max_torque / KNATTE.max_thrust == pytest.approx(A, rel=0.01)


@pytest.mark.parametrize(
    ("pair", "expected"),
    [
        ("+x", (2 * F, 0.0, 0.0)),
        ("-x", (-2 * F, 0.0, 0.0)),
        ("+y", (0.0, 2 * F, 0.0)),
        ("-y", (0.0, -2 * F, 0.0)),
        ("+torque", (0.0, 0.0, 2 * F * A)),
        ("-torque", (0.0, 0.0, -2 * F * A)),
    ],
)
def test_pairs_give_pure_force_or_torque(pair: str, expected: tuple[float, float, float]) -> None:
    assert wrench(valves(*PAIRS[pair]), BODY) == pytest.approx(expected, abs=1e-15)


def test_each_thruster_as_documented() -> None:
    torques = [-1, +1, +1, -1, +1, -1, -1, +1]  # the module docstring's table
    for i, thruster in enumerate(THRUSTERS):
        fx, fy, tau = wrench(valves(i), BODY)
        assert (fx, fy) == pytest.approx((F * thruster.dx, F * thruster.dy))
        assert abs(tau) == pytest.approx(F * A)
        assert tau == pytest.approx(torques[i] * F * A)


def test_all_valves_cancel() -> None:
    assert wrench([1] * 8, BODY) == pytest.approx((0.0, 0.0, 0.0), abs=1e-15)


def test_matrix_matches_wrench() -> None:
    u = np.array(valves(0, 4, 5, 7), dtype=float)
    assert BODY.matrix @ u == pytest.approx(wrench(u, BODY))


def test_valve_count_checked() -> None:
    with pytest.raises(ValueError, match="8 valve states"):
        wrench([1, 0, 1], BODY)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_bad_params(bad: float) -> None:
    with pytest.raises(ValueError, match="mass"):
        BodyParams(bad, 0.16, 0.2, 0.16)


# ---------------------------------------------------------------- open loop


def test_torque_pulse_rotation_matches_inertia() -> None:
    """Done-when 1: omega = tau dt / I and the heading that follows, within 1 %."""
    tau = KNATTE.pair_torque  # 0.064 Nm
    pulse, coast = 0.5, 2.0
    x = run(REST, valves(*PAIRS["+torque"]), pulse)
    x = run(x, valves(), coast)
    omega = tau * pulse / KNATTE.inertia
    heading = 0.5 * (tau / KNATTE.inertia) * pulse**2 + omega * coast
    print(
        f"\n[open loop] KNATTE torque pulse {tau} Nm x {pulse} s: "
        f"omega {x[5]:.6f} rad/s (predicted {omega:.6f}, error {abs(x[5] / omega - 1):.2e}); "
        f"heading after {coast} s coast {x[2]:.6f} rad "
        f"(predicted {heading:.6f}, error {abs(x[2] / heading - 1):.2e})"
    )
    assert x[5] == pytest.approx(omega, rel=0.01)
    assert x[2] == pytest.approx(heading, rel=0.01)
    assert x[[0, 1, 3, 4]] == pytest.approx(np.zeros(4), abs=1e-12)  # a pure torque
    # the other way round, on the other preset
    pinocchio = load_platform("pinocchio")
    body = BodyParams.from_config(pinocchio)
    y = step(REST, valves(*PAIRS["-torque"]), pulse, body)
    assert y[5] == pytest.approx(-pinocchio.pair_torque * pulse / pinocchio.inertia, rel=0.01)


def test_force_pair_accelerates_in_the_lab_frame() -> None:
    # heading 90 deg: body +x points along lab +y
    x0 = np.array([0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.0])
    x = run(x0, valves(*PAIRS["+x"]), 2.0)
    a = 2 * F / KNATTE.mass
    assert x[4] == pytest.approx(a * 2.0, rel=1e-9)
    assert x[1] == pytest.approx(0.5 * a * 4.0, rel=1e-9)
    assert x[[0, 3, 5]] == pytest.approx(np.zeros(3), abs=1e-12)
    assert x[2] == pytest.approx(math.pi / 2)


def test_body_force_turns_with_the_body() -> None:
    # spinning at 1 rad/s while pushing along body +x: the mean push nearly cancels
    x0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    x = run(x0, valves(*PAIRS["+x"]), 2 * math.pi, dt=2 * math.pi / 6000)
    assert math.hypot(x[3], x[4]) < 1e-9
    assert x[2] == pytest.approx(2 * math.pi)


def test_f_is_the_derivative() -> None:
    x = np.array([0.3, -0.2, 0.4, 0.01, -0.02, 0.05])
    u = valves(1, 2, 4, 5)
    dx = f(0.0, x, u, BODY)
    fx, fy, tau = wrench(u, BODY)
    c, s = math.cos(0.4), math.sin(0.4)
    expected = [0.01, -0.02, 0.05, (c * fx - s * fy) / 10.0, (s * fx + c * fy) / 10.0, tau / 0.16]
    assert dx == pytest.approx(expected)
    h = 1e-4
    assert (step(x, u, h, BODY) - x) / h == pytest.approx(dx, rel=1e-3, abs=1e-9)


def test_rk4_agrees_with_python_control() -> None:
    """f(t, x, u, params) drops into python-control; its adaptive solver agrees with step."""
    system = ct.nlsys(lambda t, x, u, params: f(t, x, u, BODY), None, states=6, inputs=8, outputs=6)
    times = np.linspace(0.0, 3.0, 301)
    u = valves(0, 1, 2)  # +x pair and +torque pair, sharing valve 1
    inputs = np.tile(np.array(u, dtype=float)[:, None], (1, len(times)))
    x0 = np.array([0.1, 0.2, 0.3, 0.0, 0.01, 0.05])
    reference = ct.input_output_response(
        system, times, inputs, x0, solve_ivp_kwargs={"rtol": 1e-10, "atol": 1e-12}
    )
    assert run(x0, u, 3.0) == pytest.approx(reference.states[:, -1], abs=1e-9)


# ---------------------------------------------------------------- table disturbance


def test_slope_field_is_repeatable_and_smooth() -> None:
    field = SlopeField.random(seed=1, slope=1e-4, wavelength=1.5, components=3)
    assert field == SlopeField.random(seed=1, slope=1e-4, wavelength=1.5, components=3)
    assert field != SlopeField.random(seed=2, slope=1e-4, wavelength=1.5, components=3)
    for a, kx, ky, _ in field.terms:
        assert a * math.hypot(kx, ky) == pytest.approx(1e-4)  # each sinusoid's peak slope
    h = 1e-6
    for x, y in [(0.0, 0.0), (0.7, -0.3), (-1.2, 0.5)]:
        gx, gy = field.gradient(x, y)
        assert gx == pytest.approx((field.height(x + h, y) - field.height(x - h, y)) / (2 * h))
        assert gy == pytest.approx((field.height(x, y + h) - field.height(x, y - h)) / (2 * h))
        assert math.hypot(gx, gy) <= 3e-4


def test_slope_pushes_downhill_and_does_not_turn() -> None:
    field = SlopeField.random(seed=1, slope=1e-4, wavelength=1.5)
    gx, gy = field.gradient(0.0, 0.0)
    dx = f(0.0, REST, valves(), BODY, field)
    assert dx[3:5] == pytest.approx([-GRAVITY * gx, -GRAVITY * gy])  # -m g grad h / m
    x = run(REST, valves(), 20.0, disturbance=field)
    drift = math.hypot(x[0], x[1])
    print(f"\n[disturbance] KNATTE table, seed 1: drift {drift * 100:.1f} cm in 20 s at rest")
    assert drift > 0.01
    assert x[2] == 0.0 and x[5] == 0.0


def test_slope_field_rejects_nonsense() -> None:
    with pytest.raises(ValueError, match="components"):
        SlopeField.random(0, 1e-4, 1.5, components=0)
    with pytest.raises(ValueError, match="wavelength"):
        SlopeField.random(0, 1e-4, 0.0)


# ---------------------------------------------------------------- purity


@pytest.mark.parametrize(
    "module",
    [
        "dynamics",
        "sensors",
        "navigation",
        "control",
        "gnc",
        "simulated",
        "guidance",
        "serial/protocol",
        "serial/emulator",
    ],
)
def test_pure_modules_import_no_io_or_clock(module: str) -> None:
    path = Path(__file__).resolve().parents[3] / "agents" / f"{module}.py"
    imported = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert not imported & {
        "zenoh", "socket", "time", "datetime", "asyncio", "serial", "os", "select", "threading",
    }  # fmt: skip
