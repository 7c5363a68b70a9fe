"""``fedlab bridge udp``: join an unchanged legacy agent that speaks the paper's UDP
packets to the federation (the library: :mod:`federation.bridge.udp`); ``fedlab bridge
ros2``: the federation's poses on ROS 2, and a ROS 2 platform in the federation (the
library: :mod:`federation.bridge.ros2`)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_timeout_flag,
    add_zenoh_flags,
    agent_id,
    check_agent_identity,
    federation_name,
    integer_in,
    open_interruptible,
    open_session,
    positive,
    stop_on_signals,
    zenoh_options,
)
from federation.core.estimators import ESTIMATORS
from schemas.bridge import UdpBridgeConfig
from schemas.config import AgentConfig, validate

__all__ = ["add", "run"]

_EXAMPLE = (
    "Example:\n"
    "  fedlab bridge udp --as rome/pinocchio --listen 0.0.0.0:9000 --peer 192.0.2.7:9001 \\\n"
    "      --request-port 9001 --follow kiruna/knatte -e tcp/127.0.0.1:7448"
)

# UdpBridgeConfig field -> the flag's destination, where they differ.
_DESTS = {"agent": "as_agent", "listen": "udp_listen"}


def _default(field: str) -> Any:
    """The default of a UdpBridgeConfig field: kept there, shown in --help."""
    return UdpBridgeConfig.model_fields[field].default


def _seconds(p: argparse.ArgumentParser, flag: str, help_text: str) -> None:
    """A duration flag whose default is its UdpBridgeConfig field's."""
    field = flag.removeprefix("--").replace("-", "_")
    p.add_argument(flag, type=float, default=_default(field), metavar="S", help=help_text)


def add(sub: Subparsers) -> None:
    """Add ``bridge`` and its kinds, ``bridge udp`` and ``bridge ros2``."""
    bridge = sub.add_parser(
        "bridge",
        help="join a legacy agent (the paper's UDP packets) or ROS 2 to the federation",
        formatter_class=Formatter,
        description="Bridges that let an unchanged legacy agent or ROS 2 join the federation.",
        epilog=_EXAMPLE + "\n" + _ROS2_EXAMPLE,
    )
    kinds = bridge.add_subparsers(dest="bridge", required=True, metavar="KIND")
    p = kinds.add_parser(
        "udp",
        help="a legacy agent speaking the paper's UDP packets (8-byte request, 64-byte reply)",
        formatter_class=Formatter,
        description=(
            "Join an unchanged legacy agent that speaks the paper's UDP packets to the\n"
            "federation as LAB/NAME. Its 8-byte requests to --listen get 64-byte replies\n"
            "with t2 on the reference (leader's) clock and the followed agent's pose. The\n"
            "bridge's own requests to --peer (every --sync-period) give the legacy agent's\n"
            "clock and pose, served to the federation as LAB/NAME's sync, pose and status.\n"
            "The first request opens the firewall flow; the requests keep it open.\n"
            "Only requests from --peer's host are answered (--request-port: from that\n"
            "port only), at most --request-rate-limit a second; replies only from --peer.\n\n"
            "Zenoh's own listen endpoint is -l here; --listen is the UDP address."
        ),
        epilog=_EXAMPLE,
        conflict_handler="resolve",  # --listen is the UDP address; Zenoh keeps -l
    )
    add_zenoh_flags(p)
    add_timeout_flag(p, service=True)
    p.add_argument(
        "--as", dest="as_agent", required=True, metavar="LAB/NAME",
        help="the legacy agent's name in the federation",
    )  # fmt: skip
    p.add_argument(
        "--listen", dest="udp_listen", required=True, metavar="HOST:PORT",
        help="UDP address the legacy agent sends its requests to (and that sends ours)",
    )  # fmt: skip
    p.add_argument(
        "--peer", required=True, metavar="HOST:PORT",
        help="the legacy agent's UDP address: where the bridge's requests go",
    )  # fmt: skip
    p.add_argument(
        "--follow", metavar="LAB/NAME",
        help="agent whose clock and pose the legacy agent receives; "
        "none: the federation's leader, found by its status",
    )  # fmt: skip
    p.add_argument(
        "--role", choices=["follower", "leader"], default=_default("role"),
        help="leader: the legacy agent's clock is the reference time",
    )  # fmt: skip
    p.add_argument("--federation", default=_default("federation"), help="federation name")
    _seconds(p, "--sync-period", "seconds between requests")
    _seconds(p, "--sync-timeout", "reply timeout")
    _seconds(p, "--sync-window", "offset averaging window")
    p.add_argument(
        "--estimator", choices=list(ESTIMATORS), default=_default("estimator"),
        help="offset estimator for both links",
    )  # fmt: skip
    _seconds(
        p, "--legacy-timeout", "seconds without a reply before the legacy agent counts as gone"
    )
    _seconds(
        p, "--stale-after",
        "seconds after which the followed pose is too old to send (no reply: it holds)",
    )  # fmt: skip
    p.add_argument(
        "--request-port", type=int, metavar="PORT",
        help="take the legacy agent's requests only from this port of --peer's host "
        "(none: from any port of it, so from any process there too)",
    )  # fmt: skip
    p.add_argument(
        "--reply-port", type=int, metavar="PORT",
        help="the port of --peer's host the legacy agent's replies come from (default: "
        "--peer's own; replies from any other port are dropped)",
    )  # fmt: skip
    p.add_argument(
        "--request-rate-limit", type=float, default=_default("request_rate_limit"),
        metavar="HZ", help="legacy agent's requests answered a second at most, on average "
        "(the paper's agents send 10); more get no reply",
    )  # fmt: skip
    p.add_argument(
        "--request-burst", type=int, default=_default("request_burst"), metavar="N",
        help="legacy agent's requests answered at once before --request-rate-limit applies",
    )  # fmt: skip
    _seconds(p, "--status-period", "seconds between status")
    p.add_argument("--status-json", type=Path, metavar="FILE", help="append status lines here")
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    p.set_defaults(func=run)
    _add_ros2(kinds)


_ROS2_EXAMPLE = (
    "  fedlab bridge ros2 --domain-id 0 -e tcp/127.0.0.1:7447\n"
    "  fedlab bridge ros2 --as ros2lab/rover --odom /rover/odom -e tcp/127.0.0.1:7447\n"
    "  fedlab bridge ros2 --as ros2lab/rover --odom /rover/odom --reference kiruna/knatte \\\n"
    "      --wait-start --runs-dir runs -e tcp/127.0.0.1:7447   # a participant of ctl runs"
)


_ros_domain = integer_in(0, 232, "a ROS 2 domain id")


def _add_ros2(kinds: Any) -> None:
    p = kinds.add_parser(
        "ros2",
        help="every agent's pose as ROS 2 odometry and TF; a ROS 2 platform joins (--as)",
        formatter_class=Formatter,
        description=(
            "Publish every federation agent's pose on ROS 2 (DDS, Cyclone DDS): a\n"
            "nav_msgs/msg/Odometry on /fedlab/LAB/NAME/odom and a transform\n"
            "fedlab_common -> LAB/NAME on /tf, stamped on the federation's reference time\n"
            "mapped to this host's clock. With --as LAB/NAME --odom TOPIC, a ROS 2\n"
            "platform's odometry is that agent's pose: it answers sync, holds a token and\n"
            "publishes pose and status; with no odometry for --odom-timeout seconds it holds\n"
            "(status hold: stale) and publishes no pose. Its actuators are ROS's: the\n"
            "bridge writes /fedlab/LAB/NAME/hold (std_msgs/msg/Bool, true while it must not\n"
            "move: no run running, an abort, a stale link...) and /fedlab/LAB/NAME/run (the\n"
            "run's mode) for the ROS node that moves it. Cyclone DDS reads CYCLONEDDS_URI."
        ),
        epilog="Examples:\n" + _ROS2_EXAMPLE,
    )
    add_zenoh_flags(p)
    add_timeout_flag(p, service=True)
    p.add_argument(
        "--federation", type=federation_name, default="default", metavar="NAME",
        help="federation name",
    )  # fmt: skip
    p.add_argument(
        "--domain-id", type=_ros_domain, default=os.environ.get("ROS_DOMAIN_ID", "0"),
        metavar="N", help="ROS 2 (DDS) domain id; default: ROS_DOMAIN_ID, else 0",
    )  # fmt: skip
    p.add_argument(
        "--as", dest="as_agent", type=agent_id, metavar="LAB/NAME",
        help="join a ROS 2 platform to the federation under this name (needs --odom)",
    )  # fmt: skip
    p.add_argument(
        "--odom", metavar="TOPIC", help="the ROS 2 platform's nav_msgs/msg/Odometry topic"
    )
    p.add_argument(
        "--odom-timeout", type=positive, default=0.5, metavar="S",
        help="seconds without odometry before the joined agent holds",
    )  # fmt: skip
    p.add_argument(
        "--role", choices=["member", "leader"], default="member",
        help="the joined agent's role; leader: its clock is the reference time",
    )  # fmt: skip
    p.add_argument(
        "--reference", type=agent_id, metavar="LAB/NAME",
        help="joined agent: whose clock is reference time (a run's leader; default: its own)",
    )  # fmt: skip
    p.add_argument(
        "--wait-start", action="store_true",
        help="joined agent: wait for fedlab ctl start (else its run starts at reference time 0)",
    )  # fmt: skip
    p.add_argument(
        "--runs-dir", type=Path, metavar="DIR",
        help="joined agent: record each run into DIR/<run-id>/ (what ctl start checks for)",
    )  # fmt: skip
    p.add_argument("--status-period", type=positive, metavar="S", help="joined agent: status (1)")
    p.add_argument(
        "--sync-window", type=positive, metavar="S",
        help="joined agent: seconds of reference time its estimate of the reference clock "
        f"averages, and locks after ({AgentConfig.model_fields['sync_window'].default:g}, the "
        "paper's sync phase)",
    )  # fmt: skip
    p.add_argument(
        "--status-json", type=Path, metavar="FILE", help="joined agent: append status lines here"
    )
    p.add_argument("--duration", type=positive, metavar="S", help="stop after this many seconds")
    p.set_defaults(func=run_ros2)


def ros2_join_config(args: argparse.Namespace) -> Any:
    """The joined agent's AgentConfig from the flags (None without --as); ConfigError naming
    the flag if one is bad."""
    from federation.bridge.ros2_core import ros_topic
    from schemas.config import ConfigError

    if args.as_agent is None:
        if args.odom is not None:
            raise ConfigError("command line: --odom needs --as LAB/NAME (the agent it joins as)")
        return None
    if args.odom is None:
        raise ConfigError("command line: --as needs --odom TOPIC (the platform's odometry)")
    try:
        ros_topic(args.odom)
    except ValueError as error:
        raise ConfigError(f"command line: --odom: {error}") from None
    data: dict[str, Any] = {
        "federation": args.federation, "lab": args.as_agent.lab, "name": args.as_agent.name,
        "role": args.role, "watch_all": False, "status_json": args.status_json,
        "wait_start": args.wait_start, "runs_dir": args.runs_dir,
        "reference": None if args.reference is None else str(args.reference),
    }  # fmt: skip
    if args.status_period is not None:
        data["status_period"] = args.status_period
    if args.sync_window is not None:
        data["sync_window"] = args.sync_window
    return validate(AgentConfig, data, "command line")


def run_ros2(args: argparse.Namespace) -> int:
    import sys

    from cyclonedds.core import DDSException

    from federation.bridge.ros2 import AgentLoopStopped, run_ros2_bridge
    from federation.runtime.agent import NameTaken

    join = ros2_join_config(args)
    if join is not None:
        check_agent_identity(args, join.agent)  # the joined platform's name is its identity
    stop = stop_on_signals()
    session = open_session(args, stop)
    if session is None:
        return 0
    with session:
        try:
            run_ros2_bridge(
                session, stop, args.federation, args.domain_id, join, args.odom,
                args.odom_timeout, args.duration,
            )  # fmt: skip
        except NameTaken as error:
            print(f"fedlab bridge ros2: error: {error}", file=sys.stderr)
            return 2
        except AgentLoopStopped as error:
            print(f"fedlab bridge ros2: error: {error}; ROS told to hold", file=sys.stderr)
            return 1
        except DDSException as error:
            uri = os.environ.get("CYCLONEDDS_URI", "(unset)")
            print(
                f"fedlab bridge ros2: error: DDS domain {args.domain_id} failed: {error} "
                f"(CYCLONEDDS_URI={uri})",
                file=sys.stderr,
            )
            return 1
    return 0


def bridge_config(args: argparse.Namespace) -> UdpBridgeConfig:
    """The bridge's settings from the flags; ConfigError naming the field if one is bad."""
    data = {name: getattr(args, _DESTS.get(name, name)) for name in UdpBridgeConfig.model_fields}
    return validate(UdpBridgeConfig, data, "command line")


def run(args: argparse.Namespace) -> int:
    import zenoh

    from federation.bridge.udp import bind_udp, run_bridge
    from federation.runtime.names import NameTaken
    from federation.runtime.session import build_config, fail_fast

    config = bridge_config(args)
    check_agent_identity(args, config.agent)  # the legacy agent's name is its identity
    conf = build_config(zenoh_options(args), default_mode="client")
    if args.timeout is not None:
        fail_fast(conf, args.timeout)
    sock = bind_udp(config.listen_address)  # a port in use fails now, not after the router
    stop = stop_on_signals()
    try:
        session = open_interruptible(zenoh.open, conf, stop, args.timeout)
    except BaseException:
        sock.close()
        raise
    if session is None:
        sock.close()
        return 0
    with session:
        try:
            run_bridge(config, session, sock, stop)
        except NameTaken as error:
            print(f"fedlab bridge udp: error: {error}", file=sys.stderr)
            return 2
    return 0
