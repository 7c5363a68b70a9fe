"""Heading-loop margins against a hand calculation and python-control's."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import control
import numpy as np
import pytest

from agents.analysis import WARN_FRACTION, heading_margins
from schemas.platform import load_platform


def hand_margins(kp: float, ki: float, kd: float, inertia: float) -> tuple[float, float]:
    """Crossover (|L(jw)| = 1, by bisection) and phase margin of PID / (I s^2)."""

    def loop(w: float) -> complex:
        s = 1j * w
        return complex((kp + ki / s + kd * s) / (inertia * s * s))

    lo, hi = 1e-3, 1e3  # |L| falls monotonically through 1 here
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if abs(loop(mid)) > 1 else (lo, mid)
    wc = math.sqrt(lo * hi)
    phase = math.degrees(np.angle(loop(wc)))
    return wc, 180.0 + phase


@pytest.mark.parametrize("preset", ["knatte", "pinocchio"])
def test_margins_match_hand_calculation(preset: str) -> None:
    config = load_platform(preset)
    m = heading_margins(config)
    wc, pm = hand_margins(config.control.kp, config.control.ki, config.control.kd, config.inertia)
    assert m.crossover_rad_s == pytest.approx(wc, rel=1e-4)
    assert m.phase_margin_deg == pytest.approx(pm, abs=0.01)
    assert m.delay_margin_s == pytest.approx(math.radians(pm) / wc, rel=1e-4)
    print(f"{preset}: wc {wc:.3f} rad/s, PM {pm:.1f} deg, delay margin {m.delay_margin_s:.3f} s")


def _gains() -> list[tuple[float, float, float, float]]:
    """Every preset's (kp, ki, kd, inertia), and 40 drawn at random (some unstable,
    some without an integral term)."""
    presets = [load_platform(name) for name in ("knatte", "pinocchio", "generic")]
    rng = np.random.default_rng(7)
    drawn = [
        (rng.uniform(0.01, 5.0), rng.uniform(0.0, 1.0) * (k % 5 != 0), rng.uniform(0.01, 5.0),
         rng.uniform(0.1, 10.0))
        for k in range(40)
    ]  # fmt: skip
    return [(p.control.kp, p.control.ki, p.control.kd, p.inertia) for p in presets] + drawn


@pytest.mark.parametrize("gains", _gains())
def test_closed_forms_match_python_control(gains: tuple[float, float, float, float]) -> None:
    kp, ki, kd, inertia = gains
    config = load_platform("generic")
    config = config.model_copy(
        update={
            "inertia": inertia,
            "control": config.control.model_copy(update={"kp": kp, "ki": ki, "kd": kd}),
        }
    )
    m = heading_margins(config)
    s = control.tf("s")
    gm, pm, _sm, _wpc, wgc, _wms = control.stability_margins(
        (kp + ki / s + kd * s) / (inertia * s**2)
    )
    assert m.phase_margin_deg == pytest.approx(pm, rel=1e-9, abs=1e-9)
    assert m.crossover_rad_s == pytest.approx(wgc, rel=1e-9)
    assert m.gain_margin == pytest.approx(gm, rel=1e-9)  # inf without an integral term


def test_warning_at_a_quarter_of_the_delay_margin() -> None:
    m = heading_margins(load_platform("pinocchio"))
    line = WARN_FRACTION * m.delay_margin_s
    assert m.warn(line * 0.99) is None
    warning = m.warn(line * 1.01)
    assert warning is not None and "delay margin" in warning


def test_cli_json_is_finite() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "federation", "analyze", "--platform", "pinocchio", "--json",
         "--delay", "0.2"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    for key in ("gain_margin", "phase_margin_deg", "crossover_rad_s", "delay_margin_s"):
        assert math.isfinite(data[key]), key
    assert data["warning"] is not None  # 200 ms is beyond a quarter of ~570 ms
