"""Platform descriptions (paper section 2): physical data, not code, so a lab adds
its own platform with a file under deploy/platforms/.

A preset is a TOML file; tables group the sensors, the controller and the table
disturbance. Units are in every field's description. Defaults are KNATTE's where
the paper gives a number, so the smallest valid file is ``name``, ``mass`` and
``inertia``::

    name = "knatte"
    mass = 10.0        # kg
    inertia = 0.160    # kg m^2
    thrust = 0.20      # N, one thruster
    torque = 0.032     # Nm, one thruster

    [vision]
    width = 3.0        # m
    height = 1.7       # m

Thruster geometry (see :mod:`agents.dynamics`): eight thrusters whose lines of
action pass at ``torque / thrust`` metres from the centre; a pair of them gives a
pure force (+/-x or +/-y, body frame, ``2 * thrust``) or a pure torque
(``2 * torque``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Protocol, runtime_checkable

from pydantic import Field, model_validator

from schemas.base import ConfigError, load_model
from schemas.base import Model as _Model
from schemas.base import name as _name
from schemas.registry import Registry, RegistryError

__all__ = [
    "DEFAULT_KIND",
    "PLATFORMS",
    "PLATFORMS_DIR",
    "ControlConfig",
    "DisturbanceConfig",
    "ImuConfig",
    "NavigationConfig",
    "PlatformConfig",
    "PlatformKind",
    "TableConfig",
    "VisionConfig",
    "load_platform",
    "platform_kind",
    "validate_platform_spec",
]

PLATFORMS_DIR = Path(__file__).resolve().parents[1] / "deploy" / "platforms"


class ImuConfig(_Model):
    """Inertial measurement unit: a gyro about the vertical axis, two body accelerometers."""

    rate: float = Field(100.0, gt=0, le=10_000, description="samples per second, Hz")
    gyro_noise: float = Field(
        0.002, ge=0, description="gyro white noise per sample (1 sigma), rad/s"
    )
    gyro_bias: float = Field(
        0.005, allow_inf_nan=False, description="constant gyro bias, rad/s (unknown to the filter)"
    )
    accel_noise: float = Field(
        0.01, ge=0, description="accelerometer white noise per sample (1 sigma), m/s^2"
    )
    accel_bias: tuple[float, float] = Field(
        (0.002, -0.001),
        description="constant accelerometer bias along body x and y, m/s^2 (unknown to the filter)",
    )
    gyro_range: float = Field(
        8.7,
        gt=0,
        le=100,
        description="largest gyro reading the sensor can give, rad/s (500 deg/s): a sample "
        "beyond it is a fault, dropped and counted",
    )
    accel_range: float = Field(
        39.2,
        gt=0,
        le=2000,
        description="largest accelerometer reading the sensor can give, m/s^2 (4 g): a sample "
        "beyond it is a fault, dropped and counted",
    )


class VisionConfig(_Model):
    """External metrology (camera or Vicon): pose fixes inside a rectangle of the table."""

    rate: float = Field(20.0, gt=0, le=1000, description="fixes per second, Hz")
    position_noise: float = Field(0.005, ge=0, description="position noise (1 sigma), m")
    heading_noise: float = Field(0.0087, ge=0, description="heading noise (1 sigma), rad")
    width: float = Field(3.0, gt=0, description="coverage along lab x, m")
    height: float = Field(1.7, gt=0, description="coverage along lab y, m")
    origin: tuple[float, float] = Field(
        (0.0, 0.0), description="centre of the coverage rectangle in the lab frame (x, y), m"
    )
    latency_max: float = Field(
        0.25,
        ge=0,
        le=10,
        description="oldest a fix may be when it reaches the GNC chain, s (by the device's "
        "clock: its POSE's time against its IMU's): older, it is rejected (fix_late), since "
        "no metrology is that late and the device's time is wrong",
    )
    fix_margin: float = Field(
        0.2,
        ge=0,
        le=10,
        description="how far outside the table and the coverage (where both overlap) a fix "
        "may lie, m (noise and calibration): a fix beyond it is a fault, dropped and counted",
    )


class TableConfig(_Model):
    """The lab's table (its own frame) and the margin that makes the usable area: the
    table and the vision coverage, both shrunk by ``margin``."""

    width: float = Field(3.1, gt=0, description="table size along its x, m")
    height: float = Field(3.4, gt=0, description="table size along its y, m")
    origin: tuple[float, float] = Field(
        (0.0, 0.0), description="centre of the table in the table frame (x, y), m"
    )
    margin: float = Field(
        0.15,
        ge=0,
        description="distance kept from the edges of the table and of the coverage "
        "(the body's half-size and a stopping distance), m",
    )


class NavigationConfig(_Model):
    """Kalman filter tuning beyond the sensor noise (process noise the sensors don't explain)."""

    unmodelled_accel: float = Field(
        0.003,
        gt=0,
        description="acceleration the accelerometers cannot see (table slope), 1 sigma, m/s^2",
    )
    gyro_bias_walk: float = Field(
        1e-5, ge=0, description="gyro bias random walk, rad/s per sqrt(s)"
    )
    accel_bias_walk: float = Field(
        1e-4, ge=0, description="accelerometer bias random walk, m/s^2 per sqrt(s)"
    )
    fix_gate: float = Field(
        6.0,
        ge=3,
        le=1000,
        description="largest distance of a fix from the estimate, in sigmas of the filter's "
        "innovation covariance (x, y and heading together, Mahalanobis): a fix beyond it is "
        "an outlier, dropped and counted",
    )
    fixes_to_start: int = Field(
        3,
        ge=1,
        le=1000,
        description="fixes in a row, consistent with one another, that an estimate takes "
        "before control starts on it: at the first fix, and after a gap longer than "
        "control.fix_timeout (1: the first fix alone)",
    )
    start_velocity_sigma: float = Field(
        0.02,
        gt=0,
        le=1,
        description="velocity uncertainty (1 sigma, m/s) an estimate just acquired must come "
        "under, taking the fixes that follow, before control starts on it (settling): three "
        "fixes 0.1 s apart leave it at 0.06 m/s, and valves had opened on a velocity 0.05 to "
        "0.15 m/s wrong (or on a glitch as the third fix)",
    )
    outliers_to_restart: int = Field(
        5,
        ge=2,
        le=1000,
        description="consecutive outlier fixes, consistent with one another, after which the "
        "estimate restarts from them (the platform is elsewhere, or the metrology restarted)",
    )


class ControlConfig(_Model):
    """Heading PID (Eq. 1 and 2), pulse-width modulation, optional position hold."""

    rate: float = Field(100.0, gt=0, le=10_000, description="control steps per second, Hz")
    kp: float = Field(0.23, ge=0, description="proportional gain, Nm/rad")
    ki: float = Field(0.03, ge=0, description="integral gain, Nm/(rad s)")
    kd: float = Field(0.35, ge=0, description="derivative gain, Nm s/rad")
    integral_limit: float = Field(
        0.01, ge=0, description="largest torque the integral term may contribute, Nm"
    )
    pwm_period: float = Field(0.1, gt=0, le=10, description="pulse-width modulation period, s")
    min_on_time: float = Field(0.01, ge=0, description="shortest valve opening, s")
    position_hold: bool = Field(False, description="hold the starting x, y with a PD on position")
    kp_position: float = Field(2.5, ge=0, description="position-hold proportional gain, N/m")
    kd_position: float = Field(9.0, ge=0, description="position-hold derivative gain, N s/m")
    fix_timeout: float = Field(
        0.5,
        gt=0,
        le=10,
        description="seconds without a metrology (vision) fix after which every valve closes",
    )
    imu_timeout: float = Field(
        0.1,
        gt=0,
        le=10,
        description="seconds without an IMU sample after which every valve closes (the "
        "filter would predict on the last gyro reading)",
    )

    @model_validator(mode="after")
    def _pwm(self) -> ControlConfig:
        if self.min_on_time >= self.pwm_period:
            raise ValueError(
                f"min_on_time ({self.min_on_time} s) must be shorter than "
                f"pwm_period ({self.pwm_period} s)"
            )
        if self.pwm_period * self.rate < 1.0 - 1e-9:
            raise ValueError(
                f"pwm_period ({self.pwm_period} s) is shorter than one control step "
                f"(1/rate = {1.0 / self.rate} s)"
            )
        return self


class DisturbanceConfig(_Model):
    """The table's surface anomalies as a smooth height field of a few sinusoids."""

    enabled: bool = Field(False, description="apply the slope force in simulation")
    slope: float = Field(
        1e-4, ge=0, le=0.01, description="peak slope of each sinusoid, rad (m of rise per m)"
    )
    wavelength: float = Field(1.5, gt=0, description="mean wavelength of the sinusoids, m")
    components: int = Field(3, ge=1, le=32, description="number of sinusoids")
    seed: int = Field(0, ge=0, description="seed of the field (the table's shape, not the noise)")


class PlatformConfig(_Model):
    """Physical description of a platform (paper section 2) and its GNC settings."""

    name: Annotated[str, _name("platform name")]
    mass: float = Field(gt=0, allow_inf_nan=False, description="kg")
    inertia: float = Field(
        gt=0, allow_inf_nan=False, description="moment of inertia about the vertical axis, kg m^2"
    )
    max_rate: float = Field(
        0.5,
        gt=0,
        allow_inf_nan=False,
        description="largest heading rate a reference may ask, rad/s (a leader's shared "
        "rate is limited to it)",
    )
    thrust: float = Field(
        0.20, gt=0, allow_inf_nan=False, description="force of one thruster as operated, N"
    )
    max_thrust: float = Field(
        0.64, gt=0, allow_inf_nan=False, description="largest force of one thruster, N"
    )
    torque: float = Field(
        0.032,
        gt=0,
        allow_inf_nan=False,
        description="torque of one thruster as operated, Nm (moment arm = torque / thrust)",
    )
    max_torque: float = Field(
        0.102, gt=0, allow_inf_nan=False, description="largest torque of one thruster, Nm"
    )
    physics_rate: float = Field(
        100.0, ge=100, le=100_000, description="simulation integration steps per second, Hz"
    )
    imu: ImuConfig = Field(default_factory=ImuConfig, description="IMU model")
    vision: VisionConfig = Field(default_factory=VisionConfig, description="vision model")
    navigation: NavigationConfig = Field(
        default_factory=NavigationConfig, description="Kalman filter tuning"
    )
    control: ControlConfig = Field(default_factory=ControlConfig, description="PID and PWM")
    disturbance: DisturbanceConfig = Field(
        default_factory=DisturbanceConfig, description="table slope field"
    )
    table: TableConfig = Field(default_factory=TableConfig, description="the table and margin")

    @model_validator(mode="after")
    def _limits(self) -> PlatformConfig:
        if self.thrust > self.max_thrust:
            raise ValueError(f"thrust {self.thrust} N exceeds max_thrust {self.max_thrust} N")
        if self.torque > self.max_torque:
            raise ValueError(f"torque {self.torque} Nm exceeds max_torque {self.max_torque} Nm")
        x0, x1, y0, y1 = self.usable_area
        if not (x0 < x1 and y0 < y1):
            raise ValueError(
                f"no usable area: the table and the vision coverage, less table.margin "
                f"({self.table.margin} m), do not overlap"
            )
        if self.control.fix_timeout * self.vision.rate < 1.0:
            raise ValueError(
                f"control.fix_timeout ({self.control.fix_timeout} s) is shorter than one vision "
                f"period (1/vision.rate = {1.0 / self.vision.rate} s): no valve would ever open"
            )
        room = self.control.fix_timeout - 2.0 / self.vision.rate
        if self.vision.latency_max > room:
            raise ValueError(
                f"vision.latency_max ({self.vision.latency_max} s) leaves less than two vision "
                f"periods inside control.fix_timeout ({self.control.fix_timeout} s): fixes that "
                f"late would each come after the last went stale; at most {max(0.0, room):g} s"
            )
        if self.control.imu_timeout * self.imu.rate < 1.0:
            raise ValueError(
                f"control.imu_timeout ({self.control.imu_timeout} s) is shorter than one IMU "
                f"period (1/imu.rate = {1.0 / self.imu.rate} s): no valve would ever open"
            )
        return self

    def _area(self, inset: float) -> tuple[float, float, float, float]:
        """The table and the vision coverage overlap, less ``inset`` on each side."""
        t, v, m = self.table, self.vision, inset
        return (
            max(t.origin[0] - t.width / 2, v.origin[0] - v.width / 2) + m,
            min(t.origin[0] + t.width / 2, v.origin[0] + v.width / 2) - m,
            max(t.origin[1] - t.height / 2, v.origin[1] - v.height / 2) + m,
            min(t.origin[1] + t.height / 2, v.origin[1] + v.height / 2) - m,
        )

    @property
    def usable_area(self) -> tuple[float, float, float, float]:
        """Where the platform's centre may go, table frame: (x_min, x_max, y_min, y_max), m:
        the table and the vision coverage overlap, less ``table.margin``."""
        return self._area(self.table.margin)

    @property
    def fix_area(self) -> tuple[float, float, float, float]:
        """Where a metrology fix may lie, table frame: (x_min, x_max, y_min, y_max), m: the
        table and the vision coverage overlap, grown by ``vision.fix_margin``."""
        return self._area(-self.vision.fix_margin)

    @property
    def moment_arm(self) -> float:
        """Distance from the centre to each thruster's line of action, m."""
        return self.torque / self.thrust

    @property
    def pair_torque(self) -> float:
        """Pure torque of one thruster pair: the controller's saturation, Nm."""
        return 2.0 * self.torque

    @property
    def pair_force(self) -> float:
        """Pure force of one thruster pair along a body axis, N."""
        return 2.0 * self.thrust


def load_platform(name_or_path: str | Path) -> PlatformConfig:
    """A preset by name (``knatte``, ``pinocchio``: deploy/platforms/NAME.toml) or a file.

    Raises
    ------
    ConfigError
        Unknown name, unreadable file or a bad field; the message names the file and
        the field.
    """
    text = str(name_or_path)
    looks_like_path = (
        isinstance(name_or_path, Path)
        or "/" in text
        or "\\" in text
        or text.endswith((".toml", ".json"))
    )
    if looks_like_path:
        return load_model(PlatformConfig, Path(name_or_path))
    path = PLATFORMS_DIR / f"{text}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in PLATFORMS_DIR.glob("*.toml"))
        raise ConfigError(
            f"unknown platform {text!r}: no {path}; presets: {', '.join(known) or 'none'}"
        )
    return load_model(PlatformConfig, path)


@runtime_checkable
class PlatformKind(Protocol):
    """What configuration reads of a registered platform kind (a platform class: its
    own module's :class:`~agents.interface.Platform`, as
    :class:`~agents.kinematic.KinematicPlatform`).

    An agent's ``platform`` spec names a kind as ``KIND`` or ``KIND:ARGUMENT``
    (``kinematic``, ``serial:/dev/ttyUSB0``); a spec that names no registered kind is
    a preset or a platform file, the argument of the ``simulated`` kind.
    """

    @property
    def kind(self) -> str:
        """The kind's name, as specs give it."""
        ...

    @property
    def argument(self) -> str | None:
        """What follows ``KIND:`` in a spec, for help and messages (``PORT``); None: the
        kind takes no argument."""
        ...

    @property
    def hardware(self) -> bool:
        """Whether it drives a real platform's valves: it flies only runs an operator
        starts (``wait_start``), in a process of its own, and takes a GNC preset
        (``platform_preset``)."""
        ...

    def check_spec(self, argument: str | None) -> None:
        """Check a spec's argument at config load (a port given, a preset that loads);
        ValueError saying what is wrong."""
        ...

    def from_spec(
        self, argument: str | None, *, seed: int, rate: float, preset: str | None
    ) -> object:
        """The platform a spec names: ``seed`` of a simulated one's noise, ``rate`` of a
        kinematic one's steps (Hz), ``preset`` the GNC preset of a hardware one."""
        ...


def _accept_kind(name: str, obj: object) -> PlatformKind:
    if not isinstance(obj, type) or not isinstance(obj, PlatformKind):
        raise TypeError(
            f"{obj!r} is not a platform class with kind, argument, hardware, check_spec "
            "and from_spec"
        )
    if obj.kind != name:
        raise TypeError(f"{obj.__qualname__} says its kind is {obj.kind!r}")
    return obj


PLATFORMS: Registry[PlatformKind] = Registry(
    "platform kind",
    "fedlab.platforms",
    {
        "kinematic": "agents.kinematic:KinematicPlatform",
        "simulated": "agents.simulated:SimulatedPlatform",
        "serial": "agents.serial.platform:SerialPlatform",
    },
    _accept_kind,
)
"""Platform kinds by name: the built-ins and any a plug-in registers
(:func:`agents.registry.register_platform`, or the ``fedlab.platforms`` entry points)."""

DEFAULT_KIND = "simulated"
"""The kind of a spec that names none: a preset name or a platform file."""


def platform_kind(spec: str) -> tuple[PlatformKind, str | None]:
    """The kind ``spec`` names and its argument (``KIND``, ``KIND:ARGUMENT``, else a
    preset or file for :data:`DEFAULT_KIND`).

    Raises
    ------
    schemas.registry.RegistryError
        The kind's code does not load, or two distributions claim its name.
    """
    name, sep, argument = spec.partition(":")
    if sep and name in PLATFORMS:
        return PLATFORMS.get(name), argument
    if not sep and spec in PLATFORMS:
        return PLATFORMS.get(spec), None
    return PLATFORMS.get(DEFAULT_KIND), spec


def _other_choices() -> str:
    out = []
    for name in PLATFORMS.names():
        if name == DEFAULT_KIND:
            continue
        try:
            argument = PLATFORMS.get(name).argument
        except RegistryError:  # said when a spec names it; here only listed
            argument = None
        out.append(name if argument is None else f"{name}:{argument}")
    return ", ".join(out)


def validate_platform_spec(spec: str) -> str:
    """Check an agent's pose source at config load: a registered kind (``kinematic``,
    ``serial:PORT``, a plug-in's) or a preset name or platform file (a missing preset,
    a missing port, a plug-in that does not load fail here).

    Raises
    ------
    ValueError
        What the kind finds wrong with its argument (no port after ``serial:``; a preset
        that :func:`load_platform` cannot load, naming the file and the field, and the
        other choices), or a :class:`~schemas.registry.RegistryError`.
    """
    kind, argument = platform_kind(spec)
    try:
        kind.check_spec(argument)
    except ValueError as error:
        if kind.kind != DEFAULT_KIND or argument is None:
            raise
        raise ValueError(f"{error} (other choices: {_other_choices()})") from None
    return spec
