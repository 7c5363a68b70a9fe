"""``fedlab analyze``: heading-loop margins of a platform and the link delay it bears."""

from __future__ import annotations

import argparse
import json

from federation.cli.common import Formatter, Subparsers, nonnegative

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "analyze",
        help="heading-loop gain, phase and delay margins of a platform",
        formatter_class=Formatter,
        description=(
            "Gain, phase and delay margins of a platform's heading loop (PID on 1/(I s^2), PWM\n"
            "as its average torque), and a warning when a link delay exceeds a quarter of the\n"
            "delay margin."
        ),
        epilog="Example: fedlab analyze --platform pinocchio --delay 0.04 --json",
    )
    p.add_argument("--platform", required=True, metavar="PRESET", help="preset name or TOML file")
    p.add_argument("--delay", type=nonnegative, metavar="S", help="one-way link delay to check, s")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from agents.analysis import heading_margins
    from schemas.platform import load_platform

    margins = heading_margins(load_platform(args.platform))
    warning = margins.warn(args.delay) if args.delay is not None else None
    if args.json:
        print(json.dumps(margins.as_dict() | {"delay_s": args.delay, "warning": warning}))
        return 0
    console = Console()
    gm = "unbounded" if margins.gain_margin == float("inf") else f"{margins.gain_margin:.3f}"
    console.print(
        f"{margins.platform}: kp {margins.kp} Nm/rad, ki {margins.ki} Nm/(rad s), "
        f"kd {margins.kd} Nm s/rad, I {margins.inertia} kg m^2\n"
        f"  crossover       {margins.crossover_rad_s:.3f} rad/s\n"
        f"  phase margin    {margins.phase_margin_deg:.1f} deg\n"
        f"  gain margin     {gm} (below 1: the loop tolerates gain down to that factor)\n"
        f"  delay margin    {margins.delay_margin_s * 1e3:.0f} ms"
    )
    if warning:
        console.print(f"[yellow]warning: {warning}[/yellow]")
    elif args.delay is not None:
        console.print(f"  a {args.delay * 1e3:.0f} ms link delay is within a quarter of it")
    return 0
