"""``fedlab router``: run a lab's Zenoh router."""

from __future__ import annotations

import argparse

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_cpus_flag,
    add_zenoh_flags,
    stop_on_signals,
    zenoh_options,
)

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "router",
        help="run a lab's Zenoh router",
        formatter_class=Formatter,
        description="Run a lab's Zenoh router: the only fedlab process that crosses the firewall.",
        epilog=(
            "Examples:\n"
            "  fedlab router -c /etc/fedlab/routers/kiruna.json5   # fedlab deploy generate's\n"
            "  fedlab router --lab rome -l tcp/127.0.0.1:7448 -e tcp/kiruna.example.org:7447\n"
            "  fedlab router -c deploy/routers/kiruna.json5        # a rehearsal on one host\n"
            "  fedlab router --lab kiruna -l tcp/0.0.0.0:7447 --open --cpus 0   # a testbed"
        ),
    )
    p.add_argument("--lab", help="lab name (else metadata.lab in the config file)")
    p.add_argument(
        "--open",
        action="store_true",
        help="listen beyond this host without access control (a lab network you trust, a "
        "testbed); otherwise refused: whoever reaches the port could move a platform",
    )
    add_cpus_flag(
        p, "run on these cores only, e.g. 0 or 2-3 (Linux): on a host shared with agents, "
        "give it a core they do not use (their --cpus): each pose is spared a wait for one "
        "(docs/deploy.md)",
    )  # fmt: skip
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from federation.runtime.cpus import pin_process
    from federation.runtime.router import load_router_config, run_router

    settings, conf = load_router_config(zenoh_options(args), args.lab, open_=args.open)
    if args.cpus is not None:
        pin_process(args.cpus, "--cpus")  # before the session: Zenoh's threads inherit it
    run_router(settings, conf, stop_on_signals())
    return 0
