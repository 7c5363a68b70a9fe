"""``fedlab link``: relay traffic between two routers, delayed like an internet path.

The flags are the fields of :class:`schemas.link.LinkOptions` (``--delay-ms`` is
``delay_ms``), and take their defaults from it. A bad value fails naming the flag.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any, get_args

from pydantic import ValidationError

from federation.cli.common import Formatter, Subparsers
from schemas.config import ConfigError
from schemas.link import DEFAULT_BURST_DURATION, JitterDist, LinkOptions, LinkProtocol

__all__ = ["add", "options_from_args", "run"]


# A flag left out is not passed on: LinkOptions gives the default (or the other
# direction's value). The defaults shown in the help are LinkOptions'.
_UNSET: dict[str, Any] = {"default": argparse.SUPPRESS}


def _default(field: str) -> Any:
    return LinkOptions.model_fields[field].default


def _number(group: argparse._ArgumentGroup, flag: str, metavar: str, text: str) -> None:
    """A float flag defaulting to its LinkOptions field's default (shown), or unset."""
    default = _default(flag.removeprefix("--").replace("-", "_"))
    shown = _UNSET if default is None else {"default": default}
    group.add_argument(flag, type=float, **shown, metavar=metavar, help=text)


def add(sub: Subparsers) -> None:
    """Add the ``link`` command. It opens no Zenoh session, so takes no Zenoh flags."""
    p = sub.add_parser(
        "link",
        help="emulate an internet path (delay, jitter, loss) between two lab routers",
        formatter_class=Formatter,
        description=(
            "Relay traffic from --listen to --to, delayed and jittered per direction like\n"
            "netem. forward: from clients of --listen towards --to; backward: the replies.\n"
            "TCP (Zenoh router links) gets delay, jitter, bursts and loss as retransmission\n"
            "delay (--rto-ms), never reordering;\n"
            "UDP also gets loss and reordering. --asymmetry-ms slows the backward direction\n"
            "only: an offset estimate is then off by half of it, and cannot tell."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab link --listen tcp/127.0.0.1:7450 --to tcp/127.0.0.1:7447 \\\n"
            "      --delay-ms 40 --jitter-ms 5 --burst-every 180 --burst-extra-ms 20\n"
            "  fedlab router --lab rome -l tcp/127.0.0.1:7448 -e tcp/127.0.0.1:7450\n"
            "  fedlab link --listen udp/[::1]:9000 --to udp/[::1]:9001 --loss 0.01 --reorder 0.02"
        ),
    )
    for flag, example in (("--listen", "7450"), ("--to", "7447")):
        p.add_argument(
            flag, required=True, **_UNSET, metavar="ENDPOINT", help=f"e.g. tcp/127.0.0.1:{example}"
        )
    p.add_argument(
        "--protocol",
        choices=get_args(LinkProtocol),
        **_UNSET,
        help="default: from the endpoints, else tcp",
    )

    g = p.add_argument_group("path (both directions unless --backward-*)")
    _number(g, "--delay-ms", "D", "base one-way delay")
    _number(g, "--jitter-ms", "J", "jitter scale")
    g.add_argument(
        "--jitter-dist",
        choices=get_args(JitterDist),
        default=_default("jitter_dist"),
        help="normal: |N(0,J)|; exp: mean J; pareto: heavy tail, mean J",
    )
    _number(g, "--asymmetry-ms", "A", "added to backward only")
    _number(
        g,
        "--loss",
        "P",
        "loss: udp drops the datagram; tcp delivers it one --rto-ms late (retransmission)",
    )
    _number(g, "--rto-ms", "MS", "tcp retransmission timeout")
    _number(g, "--reorder", "P", "reorder (udp)")
    _number(g, "--reorder-extra-ms", "D", "how long a reordered datagram is held back")
    _number(g, "--backward-delay-ms", "D", "backward base delay (--delay-ms)")
    _number(g, "--backward-jitter-ms", "J", "backward jitter (--jitter-ms)")
    _number(g, "--backward-loss", "P", "backward loss (--loss)")
    b = p.add_argument_group("bursts (the paper saw larger deviations every ~3 minutes)")
    _number(b, "--burst-every", "S", "seconds between bursts")
    _number(b, "--burst-duration", "S", f"burst length ({DEFAULT_BURST_DURATION:g} s)")
    _number(b, "--burst-extra-ms", "D", "extra delay in a burst (0)")
    _number(b, "--burst-jitter-factor", "F", "jitter multiplier in a burst")
    r = p.add_argument_group("run")
    r.add_argument("--seed", type=int, **_UNSET, metavar="N", help="random seed (fresh)")
    _number(r, "--duration", "S", "stop after S seconds (never)")
    r.add_argument(
        "--stats-json",
        type=Path,
        **_UNSET,
        metavar="FILE",
        help="write the counters here every second and at exit",
    )
    _number(r, "--max-queue-mib", "M", "per-direction queue above which a side stops being read")
    _number(r, "--udp-idle", "S", "forget idle UDP clients")
    p.set_defaults(func=run)


def _flag(field: str) -> str:
    return "--" + field.replace("_", "-")


def _as_flags(text: str) -> str:
    """The library quotes option names (``'burst_every'``); a person typed flags."""
    fields = LinkOptions.model_fields
    return re.sub(r"'([a-z_]+)'", lambda m: _flag(m[1]) if m[1] in fields else m[0], text)


def _flag_errors(error: ValidationError) -> str:
    lines = []
    for item in error.errors():
        msg = _as_flags(item["msg"].removeprefix("Value error, "))
        if not item["loc"]:
            lines.append(msg)
            continue
        got = item["input"]
        shown = got is None or repr(got) in msg or str(got) in msg
        lines.append(f"{_flag(str(item['loc'][0]))}: {msg}" + ("" if shown else f" (got {got!r})"))
    return "\n".join(lines)


def options_from_args(args: argparse.Namespace) -> LinkOptions:
    """Validate the parsed flags; a ConfigError names the flag and the reason."""
    data = {
        name: getattr(args, name)
        for name in LinkOptions.model_fields
        if getattr(args, name, None) is not None
    }
    try:
        return LinkOptions.model_validate(data)
    except ValidationError as error:
        raise ConfigError(_flag_errors(error)) from None


def run(args: argparse.Namespace) -> int:
    """Validate the flags, run the link until a signal or ``--duration``, print the counters."""
    from federation.link import run_link, summary

    options = options_from_args(args)

    def ready(endpoint: str) -> None:
        print(f"fedlab link: listening on {endpoint} -> {options.to}", flush=True)

    try:
        snap = run_link(options, ready)
    except ConfigError as error:
        raise ConfigError(_as_flags(str(error))) from None
    print(summary(snap), flush=True)
    return 0
