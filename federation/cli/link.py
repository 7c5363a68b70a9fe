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
            "  fedlab link --listen udp/[::1]:9000 --to udp/[::1]:9001 --loss 0.01 --reorder 0.02\n"
            "  fedlab link --tun imp0 --forward-net 203.0.113.0/24 --delay-ms 40 --jitter-ms 3 \\\n"
            "      --loss 0.05 --mtu 576 --no-icmp   # packet mode, in the testbed's WAN"
        ),
    )
    for flag, example in (("--listen", "7450"), ("--to", "7447")):
        p.add_argument(
            flag, **_UNSET, metavar="ENDPOINT", help=f"e.g. tcp/127.0.0.1:{example} (required)"
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
    _add_packet_flags(p)
    p.set_defaults(func=run)


def _add_packet_flags(p: argparse.ArgumentParser) -> None:
    """Packet mode: the stage acts on IP packets on a TUN device (the testbed's WAN)
    instead of relaying TCP or UDP, so the labs' own TCP sees loss and delay."""
    k = p.add_argument_group(
        "packet mode (--tun: IP packets on a TUN device, instead of --listen/--to; "
        "see federation/testbed)"
    )
    k.add_argument("--tun", metavar="DEV", help="attach to this TUN device (made beforehand)")
    k.add_argument(
        "--forward-net",
        metavar="CIDR",
        help="packets to this network take the forward direction, the rest backward",
    )
    k.add_argument(
        "--router", metavar="ADDR", help="source address of the ICMP errors the stage sends"
    )
    k.add_argument(
        "--loss-burst", type=float, default=1.0, metavar="N", help="mean packets per loss run"
    )
    k.add_argument("--rate-kbit", type=float, default=0.0, metavar="R", help="bottleneck (0: none)")
    k.add_argument("--queue-kib", type=float, default=256.0, metavar="Q", help="bottleneck FIFO")
    k.add_argument("--mtu", type=int, default=0, metavar="BYTES", help="largest packet (0: none)")
    k.add_argument(
        "--no-icmp",
        dest="icmp",
        action="store_false",
        help="drop too-big packets silently (a path-MTU black hole)",
    )
    k.add_argument(
        "--cut",
        action="append",
        default=[],
        metavar="AT:FOR",
        help="cut the path FOR s from AT s after start (repeatable); SIGUSR1/SIGUSR2 cut/restore",
    )


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


def packet_options_from_args(args: argparse.Namespace) -> tuple[Any, Any]:
    """Packet mode: (forward, backward) :class:`federation.link.packet.PacketOptions`;
    a ConfigError names the flag."""
    from federation.link.packet import PacketOptions

    def get(name: str, fallback: str | None = None) -> Any:
        value = getattr(args, name, None)
        if value is None and fallback is not None:
            value = getattr(args, fallback, None)
        return value if value is not None else _default(fallback or name)

    try:
        cuts = []
        for text in args.cut:
            at, sep, length = text.partition(":")
            if not sep:
                raise ValueError(f"cuts: {text!r} is not AT:FOR (seconds)")
            cuts.append((float(at), float(length)))
        common: dict[str, Any] = {
            "jitter_dist": args.jitter_dist,
            "loss_burst": args.loss_burst,
            "reorder": get("reorder"),
            "reorder_extra": get("reorder_extra_ms") / 1e3,
            "rate": args.rate_kbit * 1e3 / 8,
            "queue": int(args.queue_kib * 1024),
            "mtu": args.mtu,
            "icmp": args.icmp,
            "cuts": tuple(cuts),
        }
        forward = PacketOptions(
            delay=get("delay_ms") / 1e3, jitter=get("jitter_ms") / 1e3, loss=get("loss"), **common
        )
        backward = PacketOptions(
            delay=get("backward_delay_ms", "delay_ms") / 1e3,
            jitter=get("backward_jitter_ms", "jitter_ms") / 1e3,
            loss=get("backward_loss", "loss"),
            **common,
        )
    except ValueError as error:
        raise ConfigError(_as_flags(f"packet mode: {error}").replace("cuts:", "--cut:")) from None
    return forward, backward


def run_packet(args: argparse.Namespace) -> int:
    """Packet mode: run the stage on ``--tun`` until a signal or ``--duration``."""
    import ipaddress
    import json

    from federation.link.packet import PacketStage
    from federation.link.tun import run_stage

    if not args.forward_net:
        raise ConfigError("--forward-net: required with --tun, e.g. 203.0.113.0/24")
    try:
        ipaddress.IPv4Network(args.forward_net)
        if args.router:
            ipaddress.IPv4Address(args.router)
    except ValueError as error:
        raise ConfigError(f"--forward-net/--router: {error}") from None
    forward, backward = packet_options_from_args(args)
    stage = PacketStage(
        forward,
        backward,
        forward_net=args.forward_net,
        router=args.router,
        seed=getattr(args, "seed", None),
    )

    def ready(device: str) -> None:
        print(f"fedlab link: packet stage on {device}, forward to {args.forward_net}", flush=True)

    try:
        snap = run_stage(
            stage,
            args.tun,
            duration=getattr(args, "duration", None),
            stats_json=getattr(args, "stats_json", None),
            ready=ready,
        )
    except OSError as error:
        raise ConfigError(f"--tun {args.tun}: cannot attach: {error}") from None
    print(json.dumps(snap), flush=True)
    return 0


def run(args: argparse.Namespace) -> int:
    """Validate the flags, run the link until a signal or ``--duration``, print the counters."""
    from federation.link import run_link, summary

    if getattr(args, "tun", None):
        return run_packet(args)
    for flag in ("listen", "to"):
        if getattr(args, flag, None) is None:
            raise ConfigError(f"--{flag}: required (or --tun DEV for packet mode)")
    options = options_from_args(args)

    def ready(endpoint: str) -> None:
        print(f"fedlab link: listening on {endpoint} -> {options.to}", flush=True)

    try:
        snap = run_link(options, ready)
    except ConfigError as error:
        raise ConfigError(_as_flags(str(error))) from None
    print(summary(snap), flush=True)
    return 0
