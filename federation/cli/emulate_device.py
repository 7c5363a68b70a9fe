"""``fedlab emulate-device``: a platform's avionics on a pseudo-terminal, for ``serial:PORT``.

The device (:class:`agents.serial.emulator.EmulatedDevice`) is the simulated platform's
plant behind the serial protocol, configured by a platform preset; the flags override
the preset. It opens no Zenoh session: no Zenoh flags.
"""

from __future__ import annotations

import argparse
import json
import random
from pathlib import Path
from typing import IO, Any

from federation.cli.common import (
    Formatter,
    Subparsers,
    nonnegative,
    positive,
    probability,
    stop_on_signals,
)

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "emulate-device",
        help="a simulated platform's avionics on a pseudo-terminal (serial protocol)",
        formatter_class=Formatter,
        description=(
            "Open a pseudo-terminal, print its path ('device on /dev/pts/N') and run a\n"
            "simulated platform behind it in real time, speaking docs/serial-protocol.md:\n"
            "IMU and POSE (metrology fixes) streamed out, VALVES applied, all valves closed\n"
            "when HEARTBEATs stop. --platform picks the preset (the same dynamics and\n"
            "sensors as a simulated platform of that preset); the other flags override it."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab emulate-device --link /tmp/knatte-tty --heartbeat-timeout-ms 200\n"
            "  fedlab emulate-device --platform pinocchio --duration 60 --seed 1\n"
            "  fedlab emulate-device --mass 16.55 --inertia 0.4002 --torque-pair 0.1\n"
            "  fedlab emulate-device --inject-garbage 0.05 --inject-bad-crc 0.05 --record dev.jsonl"
        ),
    )
    p.add_argument(
        "--platform",
        default="knatte",
        metavar="PRESET",
        help="platform preset: knatte, pinocchio or a platform TOML file",
    )
    p.add_argument(
        "--link", type=Path, metavar="FILE", help="make FILE a symlink to the pty (removed at exit)"
    )
    p.add_argument("--duration", type=positive, metavar="S", help="stop after S seconds (never)")
    p.add_argument(
        "--heartbeat-timeout-ms",
        type=positive,
        default=200.0,
        metavar="MS",
        help="heartbeat silence after which all valves close",
    )
    p.add_argument("--seed", type=int, default=0, metavar="N", help="sensor noise seed")
    g = p.add_argument_group("platform overrides (default: the preset's)")
    g.add_argument("--mass", type=positive, metavar="KG", help="mass")
    g.add_argument("--inertia", type=positive, metavar="KGM2", help="moment of inertia")
    g.add_argument("--thrust", type=positive, metavar="N", help="force of one thruster")
    g.add_argument(
        "--torque-pair", type=positive, metavar="NM", help="torque of a thruster couple (two)"
    )
    s = p.add_argument_group("streams")
    s.add_argument("--imu-rate", type=positive, metavar="HZ", help="IMU frames (preset's IMU rate)")
    s.add_argument(
        "--pose-rate", type=positive, metavar="HZ", help="POSE frames (preset's vision rate)"
    )
    s.add_argument("--status-rate", type=positive, default=10.0, metavar="HZ", help="STATUS frames")
    s.add_argument(
        "--noise",
        type=nonnegative,
        default=1.0,
        metavar="K",
        help="factor on the preset's sensor noise and biases (0: perfect sensors)",
    )
    f = p.add_argument_group("fault injection")
    f.add_argument(
        "--inject-garbage",
        type=probability,
        default=0.0,
        metavar="P",
        help="per frame: prepend 1-16 garbage bytes",
    )
    f.add_argument(
        "--inject-bad-crc", type=probability, default=0.0, metavar="P", help="per frame: bad CRC"
    )
    f.add_argument(
        "--record", type=Path, metavar="FILE", help="append valve and failsafe events (JSONL)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Serve until SIGINT, SIGTERM or ``--duration``; a bad preset is a ConfigError."""
    from agents.serial.emulator import EmulatedDevice, device_config
    from agents.serial.pty import run_emulator
    from schemas.platform import load_platform

    config = device_config(
        load_platform(args.platform),
        mass=args.mass,
        inertia=args.inertia,
        thrust=args.thrust,
        torque_pair=args.torque_pair,
        imu_rate=args.imu_rate,
        pose_rate=args.pose_rate,
        noise=args.noise,
    )
    stop = stop_on_signals()
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
            config,
            seed=args.seed,
            heartbeat_timeout=args.heartbeat_timeout_ms / 1000.0,
            status_rate=args.status_rate,
            rng=random.Random(args.seed),
            inject_garbage=args.inject_garbage,
            inject_bad_crc=args.inject_bad_crc,
            on_event=on_event,
        )

    def ready(path: str) -> None:
        print(f"device on {path} ({config.name})", flush=True)

    try:
        device = run_emulator(factory, stop, ready=ready, link=args.link, duration=args.duration)
        counters = device.counters
        on_event({"t": round(device.t, 6), "event": "exit"} | counters)
        print(
            "fedlab emulate-device: stopped; " + ", ".join(f"{k}={v}" for k, v in counters.items()),
            flush=True,
        )
    finally:
        if record is not None:
            record.close()
    return 0
