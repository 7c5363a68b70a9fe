"""``fedlab emulate-device``: a simulated platform's avionics behind a pseudo-terminal.

The emulator speaks the serial protocol (``docs/serial-protocol.md``) on the
master side of a pseudo-terminal; a host opens the slave side (``/dev/pts/N``)
as it would open a real platform's USB serial port. Behind it runs a planar
rigid body pushed by eight on/off thrusters, in real time.

Layers
------
:func:`dynamics` and :func:`rk4_step` are the physics, ``f(t, x, u, params)``
style and free of I/O (a minimal stand-in until ``agents/dynamics.py`` exists).
:class:`EmulatedDevice` is the avionics, also free of I/O: bytes and ``now`` go
in (:meth:`~EmulatedDevice.receive`), frames come out
(:meth:`~EmulatedDevice.poll`). :func:`run_emulator` only moves bytes between it
and the pseudo-terminal.

Thrusters
---------
Valve ``i`` opens thruster ``i``, which pushes with ``F`` (``--thrust``) along a
body axis at a lever arm ``r = tau_pair / (2 F)`` (0.08 m for KNATTE's 0.20 N
and 0.032 Nm per pair):

=====  =========  ==========  =========
valve  force x    force y     torque
=====  =========  ==========  =========
0      +F         0           -F r
1      +F         0           +F r
2      -F         0           +F r
3      -F         0           -F r
4      0          +F          +F r
5      0          +F          -F r
6      0          -F          -F r
7      0          -F          +F r
=====  =========  ==========  =========

This is the geometry of ``agents/dynamics.py`` (``THRUSTERS``, ``PAIRS``), kept
identical so that its controllers drive this emulator. Valves {0, 1} push +x
with 2F and no torque ({2, 3}: -x, {4, 5}: +y, {6, 7}: -y), while {1, 2} turn
the platform with +tau_pair and no net force, and {0, 3} with -tau_pair. Forces
are in the body frame (x forward, y left, heading counter-clockwise from the
table's x axis).

Dynamics
--------
State ``(x, y, psi, vx, vy, omega)``, positions and velocities in the table frame:

.. math::

    \\dot x = v_x, \\quad \\dot y = v_y, \\quad \\dot\\psi = \\omega, \\quad
    m \\dot{\\mathbf v} = R(\\psi) \\mathbf F_b, \\quad I \\dot\\omega = \\tau

Failsafe
--------
The device holds every valve closed from its start until the first HEARTBEAT,
and again whenever no HEARTBEAT has arrived for ``heartbeat_timeout`` seconds.
VALVES commands received meanwhile are ignored; after heartbeats resume the
valves stay closed until the next VALVES command. Each failsafe change sends a
STATUS frame at once.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import random
import select
import signal
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import IO, Any

from agents.serial.protocol import (
    FLAG_FAILSAFE,
    FLAG_HEARTBEAT_SEEN,
    HOST_TO_DEVICE,
    FrameDecoder,
    Heartbeat,
    Status,
    Valves,
    encode_imu,
    encode_pose,
    encode_status,
)
from federation.core.wire import Pose

__all__ = [
    "THRUSTERS",
    "BodyParams",
    "EmulatedDevice",
    "SensorNoise",
    "dynamics",
    "register",
    "rk4_step",
    "run_emulator",
    "thruster_wrench",
]

log = logging.getLogger("fedlab.emulate_device")

THRUSTERS: tuple[tuple[int, int, int], ...] = (
    (1, 0, -1),
    (1, 0, 1),
    (-1, 0, 1),
    (-1, 0, -1),
    (0, 1, 1),
    (0, 1, -1),
    (0, -1, -1),
    (0, -1, 1),
)
"""Per valve: signs of body force x, body force y and torque (see the module table)."""

State = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class BodyParams:
    """Rigid body and thrusters; defaults are KNATTE's operating point (paper section 2)."""

    mass: float = 10.0  # kg
    inertia: float = 0.160  # kg m^2, about the vertical axis
    thrust: float = 0.20  # N per thruster
    torque_pair: float = 0.032  # Nm from two thrusters firing as a couple

    def __post_init__(self) -> None:
        for name in ("mass", "inertia", "thrust", "torque_pair"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, not {value!r}")

    @property
    def arm(self) -> float:
        """Lever arm of each thruster, m: ``torque_pair / (2 thrust)``."""
        return self.torque_pair / (2.0 * self.thrust)


def thruster_wrench(mask: int, params: BodyParams) -> tuple[float, float, float]:
    """Body force x, y (N) and torque (Nm) of the open valves in ``mask``."""
    fx = fy = tau = 0.0
    for i, (sx, sy, st) in enumerate(THRUSTERS):
        if mask >> i & 1:
            fx += sx
            fy += sy
            tau += st
    f = params.thrust
    return fx * f, fy * f, tau * f * params.arm


def dynamics(t: float, x: State, u: int, params: BodyParams) -> State:
    """Time derivative of the state ``x`` under valve mask ``u`` (constant in time)."""
    del t
    fx, fy, tau = thruster_wrench(u, params)
    c, s = math.cos(x[2]), math.sin(x[2])
    m = params.mass
    return (x[3], x[4], x[5], (c * fx - s * fy) / m, (s * fx + c * fy) / m, tau / params.inertia)


def rk4_step(x: State, u: int, dt: float, params: BodyParams, t: float = 0.0) -> State:
    """One classical Runge-Kutta step of :func:`dynamics` over ``dt`` seconds."""

    def shift(k: State, h: float) -> State:
        a = x
        return (
            a[0] + h * k[0],
            a[1] + h * k[1],
            a[2] + h * k[2],
            a[3] + h * k[3],
            a[4] + h * k[4],
            a[5] + h * k[5],
        )

    k1 = dynamics(t, x, u, params)
    k2 = dynamics(t + dt / 2, shift(k1, dt / 2), u, params)
    k3 = dynamics(t + dt / 2, shift(k2, dt / 2), u, params)
    k4 = dynamics(t + dt, shift(k3, dt), u, params)
    return (
        x[0] + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
        x[1] + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]),
        x[2] + dt / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2]),
        x[3] + dt / 6 * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3]),
        x[4] + dt / 6 * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4]),
        x[5] + dt / 6 * (k1[5] + 2 * k2[5] + 2 * k3[5] + k4[5]),
    )


def _wrap(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the white noise on what the device reports."""

    gyro: float = 0.001  # rad/s
    accel: float = 0.005  # m/s^2
    position: float = 0.001  # m
    heading: float = 0.001  # rad
    velocity: float = 0.001  # m/s

    def scaled(self, factor: float) -> SensorNoise:
        return SensorNoise(*(factor * getattr(self, n) for n in self.__dataclass_fields__))


class EmulatedDevice:
    """The platform's avionics and physics; no I/O, ``now`` always passed in.

    Parameters
    ----------
    start : float
        Host clock reading that is device time 0 (s); ``now`` uses the same clock.
    params : BodyParams
        Rigid body and thrusters.
    heartbeat_timeout : float
        Heartbeat silence (s) after which every valve is closed.
    imu_rate, pose_rate, status_rate : float
        Frames per second of each kind.
    noise : SensorNoise
        Sensor noise; draws come from ``rng``.
    rng : random.Random
        Seeded for a repeatable run.
    max_dt : float
        Longest integration step, s.
    inject_garbage, inject_bad_crc : float
        Probability, per frame sent, of prepending 1 to 16 garbage bytes, and of
        corrupting the frame's CRC (fault injection for tests of the host).
    on_event : callable, optional
        Called with a JSON-ready dict on each valve command change and each
        failsafe change (for ``--record``).
    """

    def __init__(
        self,
        start: float,
        params: BodyParams | None = None,
        *,
        heartbeat_timeout: float = 0.2,
        imu_rate: float = 100.0,
        pose_rate: float = 20.0,
        status_rate: float = 10.0,
        noise: SensorNoise | None = None,
        rng: random.Random | None = None,
        max_dt: float = 0.001,
        inject_garbage: float = 0.0,
        inject_bad_crc: float = 0.0,
        initial: Pose | None = None,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ):
        for name, value in (
            ("heartbeat_timeout", heartbeat_timeout),
            ("imu_rate", imu_rate),
            ("pose_rate", pose_rate),
            ("status_rate", status_rate),
            ("max_dt", max_dt),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, not {value!r}")
        for name, value in (("inject_garbage", inject_garbage), ("inject_bad_crc", inject_bad_crc)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], not {value!r}")
        self.start = start
        self.params = params or BodyParams()
        self.heartbeat_timeout = heartbeat_timeout
        self.periods = (1.0 / imu_rate, 1.0 / pose_rate, 1.0 / status_rate)
        self.noise = noise or SensorNoise()
        self.rng = rng or random.Random(0)
        self.max_dt = max_dt
        self.inject_garbage = inject_garbage
        self.inject_bad_crc = inject_bad_crc
        self.on_event = on_event
        p = initial or Pose()
        self.state: State = (p.x, p.y, p.heading, p.vx, p.vy, p.omega)
        self.t = 0.0  # device time, s
        self.decoder = FrameDecoder(HOST_TO_DEVICE)
        self.applied = 0  # valve mask driving the thrusters
        self.commanded = 0  # last VALVES mask received
        self.valves_seq = 0
        self.heartbeat_seq = 0
        self.last_heartbeat: float | None = None  # device time
        self.failsafe = True  # until the first heartbeat
        self.failsafe_trips = 0
        self.valves_ignored = 0
        self.frames_sent = 0
        self.injected_garbage_bytes = 0
        self.injected_bad_crc = 0
        self._due = [0.0, 0.0, 0.0]  # next IMU, POSE, STATUS (device time)
        self._status_now = False

    # -- inputs ----------------------------------------------------------------
    def receive(self, data: bytes, now: float) -> None:
        """Bytes from the host at ``now``: physics runs up to ``now``, then commands apply.

        Bytes count as arriving at ``now``: an emulator stalled past the heartbeat
        timeout trips its failsafe even if heartbeats were waiting, as firmware that
        polls its UART would.
        """
        self._advance(now)
        for message in self.decoder.feed(data):
            if isinstance(message, Heartbeat):
                self.heartbeat_seq = message.seq
                self.last_heartbeat = self.t
                if self.failsafe:
                    self.failsafe = False
                    self._status_now = True
                    self._event("failsafe", active=False)
            elif isinstance(message, Valves):
                self.valves_seq = message.seq
                if message.mask != self.commanded:
                    self._event(
                        "valves", seq=message.seq, mask=message.mask, applied=not self.failsafe
                    )
                self.commanded = message.mask
                if self.failsafe:
                    self.valves_ignored += 1
                else:
                    self.applied = message.mask

    # -- outputs ---------------------------------------------------------------
    def poll(self, now: float) -> bytes:
        """Advance to ``now`` and return the frames due (at most one of each kind)."""
        self._advance(now)
        out = bytearray()
        t = self.t
        for kind in range(3):
            forced = kind == 2 and self._status_now
            if t < self._due[kind] and not forced:
                continue
            period = self.periods[kind]
            self._due[kind] += period
            if self._due[kind] <= t:  # fell behind (or first frame): restart the grid here
                self._due[kind] = t + period
            out += self._frame(kind)
        self._status_now = False
        return bytes(out)

    def next_deadline(self) -> float:
        """Next time (host clock) at which :meth:`poll` has something to do."""
        due = min(self._due)
        if self._status_now:
            due = self.t
        elif not self.failsafe and self.last_heartbeat is not None:
            due = min(due, self.last_heartbeat + self.heartbeat_timeout)
        return self.start + due

    @property
    def pose(self) -> Pose:
        """True pose, heading wrapped to [-pi, pi)."""
        s = self.state
        return Pose(s[0], s[1], _wrap(s[2]), s[3], s[4], s[5])

    def status(self) -> Status:
        flags = (FLAG_FAILSAFE if self.failsafe else 0) | (
            FLAG_HEARTBEAT_SEEN if self.last_heartbeat is not None else 0
        )
        d = self.decoder
        return Status(
            t=self.t,
            valves=self.applied,
            flags=flags,
            heartbeat_timeout_ms=round(self.heartbeat_timeout * 1000),
            valves_seq=self.valves_seq,
            heartbeat_seq=self.heartbeat_seq,
            frames_ok=d.frames_ok,
            bad_checksum=d.bad_checksum,
            garbage_bytes=d.garbage_bytes,
            failsafe_trips=self.failsafe_trips,
        )

    @property
    def counters(self) -> dict[str, int]:
        """Receive counters of host frames plus the device's own."""
        return {
            **{f"rx_{k}": v for k, v in self.decoder.counters.items()},
            "frames_sent": self.frames_sent,
            "failsafe_trips": self.failsafe_trips,
            "valves_ignored": self.valves_ignored,
            "injected_garbage_bytes": self.injected_garbage_bytes,
            "injected_bad_crc": self.injected_bad_crc,
        }

    # -- internals -------------------------------------------------------------
    def _advance(self, now: float) -> None:
        target = now - self.start
        while True:
            self._check_heartbeat()
            if self.t >= target:
                return
            t_next = min(target, self.t + self.max_dt)
            if not self.failsafe and self.last_heartbeat is not None:
                # Stop exactly at the failsafe deadline, so the valves close on time.
                deadline = self.last_heartbeat + self.heartbeat_timeout
                if self.t < deadline < t_next:
                    t_next = deadline
            self.state = rk4_step(self.state, self.applied, t_next - self.t, self.params, self.t)
            self.t = t_next

    def _check_heartbeat(self) -> None:
        if self.failsafe or self.last_heartbeat is None:
            return
        if self.t - self.last_heartbeat >= self.heartbeat_timeout:
            self.failsafe = True
            self.failsafe_trips += 1
            self.applied = 0
            self._status_now = True
            self._event("failsafe", active=True, silent=self.t - self.last_heartbeat)

    def _event(self, name: str, **fields: Any) -> None:
        if self.on_event is not None:
            self.on_event({"t": round(self.t, 6), "event": name, **fields})

    def _frame(self, kind: int) -> bytes:
        gauss = self.rng.gauss
        n = self.noise
        if kind == 0:
            fx, fy, _ = thruster_wrench(self.applied, self.params)
            m = self.params.mass
            frame = encode_imu(
                self.t,
                self.state[5] + gauss(0.0, n.gyro),
                fx / m + gauss(0.0, n.accel),
                fy / m + gauss(0.0, n.accel),
            )
        elif kind == 1:
            x, y, psi, vx, vy, omega = self.state
            pose = Pose(
                x + gauss(0.0, n.position),
                y + gauss(0.0, n.position),
                _wrap(psi + gauss(0.0, n.heading)),
                vx + gauss(0.0, n.velocity),
                vy + gauss(0.0, n.velocity),
                omega + gauss(0.0, n.gyro),
            )
            frame = encode_pose(self.t, pose)
        else:
            frame = encode_status(self.status())
        self.frames_sent += 1
        if self.inject_bad_crc and self.rng.random() < self.inject_bad_crc:
            self.injected_bad_crc += 1
            frame = frame[:-1] + bytes((frame[-1] ^ 0x01,))
        if self.inject_garbage and self.rng.random() < self.inject_garbage:
            # 0xA5 left out: injected noise never starts a false sync, so counts stay exact.
            junk = bytes(self.rng.choice(_JUNK) for _ in range(self.rng.randint(1, 16)))
            self.injected_garbage_bytes += len(junk)
            frame = junk + frame
        return frame


_JUNK = bytes(b for b in range(256) if b != 0xA5)


# -- real time on a pseudo-terminal ----------------------------------------------
_TX_CAP = 1024  # bytes queued for a host that is not reading; newer frames are dropped


def run_emulator(
    device_factory: Callable[[float], EmulatedDevice],
    stop: threading.Event,
    *,
    ready: Callable[[str], None] | None = None,
    link: Path | None = None,
    duration: float | None = None,
) -> EmulatedDevice:
    """Serve a device on a new pseudo-terminal until ``stop`` is set or ``duration`` passes.

    ``device_factory(start)`` builds the device with its time origin; ``ready`` gets
    the slave path once the terminal is open; ``link`` becomes a symlink to it.
    Returns the device, for its counters.
    """
    master, slave = os.openpty()
    link_made = False
    try:
        tty.setraw(slave)  # 8-bit clean: no echo, no CR/LF translation, no line editing
        os.set_blocking(master, False)
        path = os.ttyname(slave)
        if link is not None:
            tmp = link.with_name(f".{link.name}.{os.getpid()}")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(path)
            tmp.replace(link)
            link_made = True
        if ready is not None:
            ready(path)
        start = time.monotonic()
        device = device_factory(start)
        end = math.inf if duration is None else start + duration
        tx = bytearray()
        tx_dropped = 0
        while not stop.is_set():
            now = time.monotonic()
            if now >= end:
                break
            wait = min(device.next_deadline(), end) - now
            readable, _, _ = select.select([master], [], [], min(max(wait, 0.0), 0.01))
            now = time.monotonic()
            if readable:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                if data:
                    device.receive(data, now)
            out = device.poll(now)
            if out:
                if len(tx) + len(out) <= _TX_CAP:
                    tx += out
                else:
                    tx_dropped += len(out)
            if tx:
                with contextlib.suppress(BlockingIOError):
                    del tx[: os.write(master, tx)]
        log.info("device stopped at t=%.3f s; %d bytes dropped unread", device.t, tx_dropped)
        return device
    finally:
        os.close(master)
        os.close(slave)
        if link_made and link is not None:
            with contextlib.suppress(FileNotFoundError):
                link.unlink()


# -- command line ----------------------------------------------------------------
def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, not {text!r}")
    return value


def _nonneg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, not {text!r}")
    return value


def _probability(text: str) -> float:
    value = _nonneg(text)
    if value > 1:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1], not {text!r}")
    return value


def cmd_emulate_device(args: argparse.Namespace) -> int:
    """``fedlab emulate-device``: serve until SIGINT, SIGTERM or ``--duration``."""
    stop = threading.Event()

    def handler(signum: int, frame: FrameType | None) -> None:
        log.info("received %s, stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)

    params = BodyParams(args.mass, args.inertia, args.thrust, args.torque_pair)
    record: IO[str] | None = None
    if args.record is not None:
        record = args.record.open("a", encoding="utf-8")

    def on_event(event: dict[str, Any]) -> None:
        if record is not None:
            record.write(json.dumps(event) + "\n")
            record.flush()

    def factory(start: float) -> EmulatedDevice:
        return EmulatedDevice(
            start,
            params,
            heartbeat_timeout=args.heartbeat_timeout_ms / 1000.0,
            imu_rate=args.imu_rate,
            pose_rate=args.pose_rate,
            status_rate=args.status_rate,
            noise=SensorNoise().scaled(args.noise),
            rng=random.Random(args.seed),
            inject_garbage=args.inject_garbage,
            inject_bad_crc=args.inject_bad_crc,
            on_event=on_event,
        )

    def ready(path: str) -> None:
        print(f"device on {path}", flush=True)

    try:
        device = run_emulator(factory, stop, ready=ready, link=args.link, duration=args.duration)
        counters = device.counters
        on_event({"t": round(device.t, 6), "event": "exit", **counters})
        print(
            "fedlab emulate-device: stopped; " + ", ".join(f"{k}={v}" for k, v in counters.items()),
            flush=True,
        )
    finally:
        if record is not None:
            record.close()
    return 0


def register(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser],
    formatter_class: type[argparse.HelpFormatter],
    add_zenoh_flags: Callable[[argparse.ArgumentParser], None],
) -> None:
    """Add the ``emulate-device`` command. It opens no Zenoh session: no Zenoh flags."""
    del add_zenoh_flags
    p = subparsers.add_parser(
        "emulate-device",
        help="a simulated platform's avionics on a pseudo-terminal (serial protocol)",
        formatter_class=formatter_class,
        description=(
            "Open a pseudo-terminal, print its path ('device on /dev/pts/N') and run a\n"
            "simulated platform behind it in real time, speaking docs/serial-protocol.md:\n"
            "IMU and POSE streamed out, VALVES applied, all valves closed when HEARTBEATs stop."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab emulate-device --link /tmp/knatte-tty --heartbeat-timeout-ms 200\n"
            "  fedlab emulate-device --mass 16.55 --inertia 0.4002 --duration 60 --seed 1\n"
            "  fedlab emulate-device --inject-garbage 0.05 --inject-bad-crc 0.05 --record dev.jsonl"
        ),
    )
    p.add_argument(
        "--link", type=Path, metavar="FILE", help="make FILE a symlink to the pty (removed at exit)"
    )
    p.add_argument("--duration", type=_positive, metavar="S", help="stop after S seconds (never)")
    p.add_argument(
        "--heartbeat-timeout-ms",
        type=_positive,
        default=200.0,
        metavar="MS",
        help="heartbeat silence after which all valves close",
    )
    p.add_argument("--seed", type=int, default=0, metavar="N", help="sensor noise seed")
    g = p.add_argument_group("platform (KNATTE defaults)")
    g.add_argument("--mass", type=_positive, default=10.0, metavar="KG", help="mass")
    g.add_argument("--inertia", type=_positive, default=0.160, metavar="KGM2", help="inertia")
    g.add_argument("--thrust", type=_positive, default=0.20, metavar="N", help="per thruster")
    g.add_argument(
        "--torque-pair", type=_positive, default=0.032, metavar="NM", help="per thruster couple"
    )
    s = p.add_argument_group("streams")
    s.add_argument("--imu-rate", type=_positive, default=100.0, metavar="HZ", help="IMU frames")
    s.add_argument("--pose-rate", type=_positive, default=20.0, metavar="HZ", help="POSE frames")
    s.add_argument(
        "--status-rate", type=_positive, default=10.0, metavar="HZ", help="STATUS frames"
    )
    s.add_argument(
        "--noise", type=_nonneg, default=1.0, metavar="K", help="sensor noise scale (0: none)"
    )
    f = p.add_argument_group("fault injection")
    f.add_argument(
        "--inject-garbage",
        type=_probability,
        default=0.0,
        metavar="P",
        help="per frame: prepend 1-16 garbage bytes",
    )
    f.add_argument(
        "--inject-bad-crc", type=_probability, default=0.0, metavar="P", help="per frame: bad CRC"
    )
    f.add_argument(
        "--record", type=Path, metavar="FILE", help="append valve and failsafe events (JSONL)"
    )
    p.set_defaults(func=cmd_emulate_device)
