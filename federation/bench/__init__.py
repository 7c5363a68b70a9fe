"""``fedlab bench ...``: benchmarks that compare against baselines measured in the same run."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from federation.bench import latency, scale, sync

__all__ = ["register"]


def register(
    sub: Any,
    formatter: type[argparse.HelpFormatter],
    add_zenoh_flags: Callable[[argparse.ArgumentParser], None],
) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks: sync accuracy, latency, scale",
        formatter_class=formatter,
        description="Benchmarks; each prints a table, or JSON with --json.",
        epilog="Example: fedlab bench sync --duration 60 --scenario drift",
    )
    benches = p.add_subparsers(dest="bench", required=True, metavar="BENCH")
    sync.register(benches, formatter)
    latency.register(benches, formatter)
    scale.register(benches, formatter)
