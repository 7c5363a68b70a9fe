"""Platform presets and their schema (schemas/platform.py, deploy/platforms/)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pydantic import BaseModel

from schemas.config import ConfigError
from schemas.platform import PLATFORMS_DIR, PlatformConfig, load_platform


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def load_error(name_or_path: str | Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_platform(name_or_path)
    return str(info.value)


# ---------------------------------------------------------------- the paper's presets


def test_knatte_is_the_papers() -> None:
    k = load_platform("knatte")
    assert (k.name, k.mass, k.inertia) == ("knatte", 10.0, 0.160)
    assert (k.thrust, k.torque, k.max_thrust, k.max_torque) == (0.20, 0.032, 0.64, 0.102)
    assert (k.imu.rate, k.vision.rate) == (100.0, 20.0)
    assert (k.vision.width, k.vision.height) == (3.0, 1.7)
    assert k.moment_arm == pytest.approx(0.16)
    assert k.pair_torque == pytest.approx(0.064)
    assert k.disturbance.enabled  # the paper's table anomalies


def test_pinocchio_is_the_papers() -> None:
    p = load_platform("pinocchio")
    assert (p.name, p.mass, p.inertia) == ("pinocchio", 16.55, 0.4002)
    assert p.vision.position_noise < load_platform("knatte").vision.position_noise  # Vicon
    assert not p.disturbance.enabled
    text = (PLATFORMS_DIR / "pinocchio.toml").read_text(encoding="utf-8")
    assert "not in the paper" in text  # the thrust is our assumption, and says so


def test_presets_dir_is_in_the_repository() -> None:
    repository = Path(__file__).resolve().parents[3]
    assert repository / "deploy" / "platforms" == PLATFORMS_DIR
    assert {p.stem for p in PLATFORMS_DIR.glob("*.toml")} >= {"knatte", "pinocchio"}


def test_load_by_path(tmp_path: Path) -> None:
    path = write(tmp_path, "mine.toml", 'name = "mine"\nmass = 12.0\ninertia = 0.2\n')
    config = load_platform(path)
    assert config.name == "mine"
    assert load_platform(str(path)) == config
    assert load_platform(PLATFORMS_DIR / "knatte.toml") == load_platform("knatte")


def test_minimal_platform_keeps_defaults(tmp_path: Path) -> None:
    data = {"name": "knatte", "mass": 10, "inertia": 0.16}
    config = load_platform(write(tmp_path, "knatte.json", json.dumps(data)))
    assert config.max_rate == 0.5
    assert config.control.rate == 100.0
    assert config.vision.origin == (0.0, 0.0)


def test_every_field_has_units_or_a_description() -> None:
    def walk(model: type[BaseModel]) -> None:
        for name, field in model.model_fields.items():
            assert field.description or name == "name", f"{model.__name__}.{name}"
            sub = field.annotation
            if isinstance(sub, type) and issubclass(sub, BaseModel):
                walk(sub)

    walk(PlatformConfig)


# ---------------------------------------------------------------- bad input

BASE = 'name = "knatte"\nmass = 10.0\ninertia = 0.16\n'


def test_unknown_preset() -> None:
    message = load_error("gustav")
    assert "unknown platform 'gustav'" in message
    assert "knatte" in message and "pinocchio" in message


def test_missing_file(tmp_path: Path) -> None:
    message = load_error(tmp_path / "absent.toml")
    assert "absent.toml" in message
    assert "cannot read" in message


@pytest.mark.parametrize(
    ("extra", "field", "reason"),
    [
        ("mass = 0", "mass", "greater than 0"),
        ("inertia = -0.1", "inertia", "greater than 0"),
        ('mass = "heavy"', "mass", "number"),
        ("thrust = 0.9", "(top level)", "exceeds max_thrust"),
        ("torque = 0.2", "(top level)", "exceeds max_torque"),
        ("physics_rate = 50", "physics_rate", "greater than or equal to 100"),
        ("colour = 1", "colour", "unknown field"),
        ("[control]\nkp = -1", "control.kp", "greater than or equal to 0"),
        ("[control]\nmin_on_time = 0.2", "control", "shorter than pwm_period"),
        ("[control]\npwm_period = 0.005\nmin_on_time = 0", "control", "one control step"),
        ("[imu]\nrate = 0", "imu.rate", "greater than 0"),
        ("[vision]\nwidth = 0", "vision.width", "greater than 0"),
        ("[vision]\norigin = [1.0]", "vision.origin.1", "Field required"),
        ("[disturbance]\ncomponents = 0", "disturbance.components", "greater than or equal"),
        ("[disturbance]\nwobble = 3", "disturbance.wobble", "unknown field"),
        # inf * 0 is NaN, and a NaN demand once latched the valves open at full thrust.
        ("[control]\nkd = inf", "control.kd", "finite number"),
        ("[vision]\nposition_noise = inf", "vision.position_noise", "finite number"),
        ("[imu]\ngyro_noise = nan", "imu.gyro_noise", "finite number"),
        ("[imu]\ngyro_range = 0", "imu.gyro_range", "greater than 0"),
        ("[imu]\nrate = 5.0", "(top level)", "imu_timeout"),
    ],
)
def test_bad_field_names_file_and_field(
    tmp_path: Path, extra: str, field: str, reason: str
) -> None:
    replaced = extra.split(" = ")[0]  # a top-level key given again replaces the base's
    base = [line for line in BASE.splitlines() if not line.startswith(replaced + " =")]
    path = write(tmp_path, "bad.toml", "\n".join([*base, extra, ""]))
    message = load_error(path)
    assert str(path) in message
    assert f"field '{field}'" in message
    assert reason in message


def test_not_toml(tmp_path: Path) -> None:
    message = load_error(write(tmp_path, "broken.toml", "name = \n"))
    assert "broken.toml" in message
    assert "not valid TOML" in message


def test_noise_may_be_zero_but_not_negative(tmp_path: Path) -> None:
    ok = 'name = "p"\nmass = 1\ninertia = 1\n[imu]\ngyro_noise = 0\n'
    assert load_platform(write(tmp_path, "ok.toml", ok)).imu.gyro_noise == 0.0
    bad = write(tmp_path, "bad.toml", ok.replace("= 0\n", "= -1e-3\n"))
    assert "field 'imu.gyro_noise'" in load_error(bad)
    nan = write(tmp_path, "nan.toml", 'name = "p"\nmass = nan\ninertia = 1\n')
    assert "field 'mass'" in load_error(nan)
