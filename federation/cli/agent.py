"""``fedlab agent``: run an agent, a platform taking part in the federation.

Its settings come from ``--agent-config`` (TOML or JSON), then its part in an
``--experiment``, then the flags given (:func:`agent_config`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from federation.cli.common import (
    AGENT_CPUS_HELP,
    Formatter,
    Subparsers,
    add_cpus_flag,
    add_timeout_flag,
    add_zenoh_flags,
    check_agent_identity,
    open_session,
    stop_on_signals,
)
from federation.core import paper
from federation.core.estimators import ESTIMATORS
from schemas.config import AgentConfig, ConfigError, load_model, validate

__all__ = ["add", "agent_config", "run"]

log = logging.getLogger("fedlab")


def _default(field: str) -> object:
    """The default of an AgentConfig field: kept there, shown in --help (a flag left out
    is None here, so that the settings file or the experiment may give the value)."""
    return AgentConfig.model_fields[field].default


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "agent",
        help="run an agent (a platform in the federation)",
        formatter_class=Formatter,
        description="Run an agent: serve sync queries, sync with peers, publish pose and status.",
        epilog=(
            "Examples:\n"
            "  fedlab agent --role leader --lab kiruna --name knatte -e tcp/127.0.0.1:7447\n"
            "  fedlab agent --role follower --lab rome --name pinocchio --follow kiruna/knatte \\\n"
            f"      -e tcp/127.0.0.1:7448 --clock-offset {paper.CLOCK_OFFSET} \\\n"
            "      --status-json rome.jsonl"
        ),
    )
    p.add_argument(
        "--agent-config", type=Path, metavar="FILE", help="agent settings (TOML or JSON)"
    )
    p.add_argument(
        "--experiment",
        type=Path,
        metavar="FILE",
        help="take role, platform and maneuver from an experiment file; wait for ctl start",
    )
    p.add_argument("--federation", help=f"federation name (default: {_default('federation')})")
    p.add_argument("--lab", help="this agent's lab")
    p.add_argument("--name", help="this agent's name")
    p.add_argument(
        "--role",
        choices=["leader", "follower", "member"],
        help="leader runs the maneuver; follower tracks --follow; member only takes part",
    )
    p.add_argument("--follow", metavar="LAB/NAME", help="agent whose heading a follower tracks")
    p.add_argument(
        "--sync-with",
        action="append",
        default=[],
        metavar="LAB/NAME",
        help="sync only with these agents (default: the reference and the followed agent "
        "every --sync-period; the reference, or with --sync-all anyone, also every other "
        "agent alive every --sync-others-period)",
    )
    p.add_argument(
        "--sync-all",
        action="store_const",
        const=True,
        help="sync pairwise with every agent alive, not only with the reference and the "
        "followed agent (others' poses carry their reference time: not needed by default)",
    )
    p.add_argument(
        "--sync-period",
        type=float,
        metavar="S",
        help=f"seconds between sync requests (default: {_default('sync_period')})",
    )
    p.add_argument(
        "--sync-others-period", type=float, metavar="S",
        help="seconds between sync requests to agents neither followed nor the reference "
        f"(default: {_default('sync_others_period')})",
    )  # fmt: skip
    p.add_argument(
        "--sync-timeout",
        type=float,
        metavar="S",
        help=f"sync reply timeout (default: {_default('sync_timeout')})",
    )
    p.add_argument(
        "--sync-window",
        type=float,
        metavar="S",
        help=f"offset averaging window (default: {_default('sync_window')})",
    )
    p.add_argument(
        "--estimator",
        choices=ESTIMATORS,
        help="offset estimator: clockfilter (offset and drift; default) or the paper's mean/median",
    )
    p.add_argument(
        "--four-timestamps",
        action="store_const",
        const=True,
        help="also use the server's send time (for servers with slow turnaround)",
    )
    p.add_argument(
        "--pose-rate",
        type=float,
        metavar="HZ",
        help=f"pose samples per second (default: {_default('pose_rate')})",
    )
    p.add_argument(
        "--status-period",
        type=float,
        metavar="S",
        help=f"seconds between status (default: {_default('status_period')})",
    )
    p.add_argument(
        "--clock-offset",
        type=float,
        metavar="S",
        help=f"skew this agent's clock (s; default: {_default('clock_offset')})",
    )
    p.add_argument(
        "--clock-drift-ppm",
        type=float,
        metavar="PPM",
        help=f"clock rate error (ppm; default: {_default('clock_drift_ppm')})",
    )
    p.add_argument(
        "--platform",
        metavar="SPEC",
        help="pose source: kinematic (default), knatte, pinocchio, a platform TOML, serial:PORT, "
        "or a plug-in's KIND[:ARGUMENT]",
    )
    p.add_argument(
        "--platform-preset",
        metavar="NAME|FILE",
        help="GNC preset of a serial:PORT platform: knatte (default), pinocchio, a platform TOML",
    )
    p.add_argument(
        "--seed",
        type=int,
        help=f"seed of a simulated platform's noise (default: {_default('seed')})",
    )
    p.add_argument(
        "--no-latency-compensation",
        dest="latency_compensation",
        action="store_const",
        const=False,
        help="track the followed pose as received, without dead reckoning",
    )
    p.add_argument(
        "--clock-step",
        type=_clock_step,
        metavar="AT:S",
        help="rehearse a clock step: jump S seconds when the clock reads AT",
    )
    p.add_argument(
        "--stale-after",
        type=float,
        metavar="S",
        help="seconds without the followed pose before safe hold "
        f"(default: {_default('stale_after')})",
    )
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    p.add_argument("--status-json", type=Path, metavar="FILE", help="append status lines here")
    p.add_argument("--record", type=Path, metavar="FILE", help="record everything to one MCAP file")
    p.add_argument(
        "--runs-dir",
        type=Path,
        metavar="DIR",
        help="record each run into DIR/<run-id>/ and serve it to fedlab collect "
        "(default with --experiment: runs)",
    )
    p.add_argument(
        "--wait-start",
        action="store_const",
        const=True,
        help="hold still until a start command (fedlab ctl start) instead of starting at once",
    )
    add_cpus_flag(p, AGENT_CPUS_HELP)
    add_zenoh_flags(p)
    add_timeout_flag(p, service=True)
    p.set_defaults(func=run)


_AGENT_FLAGS = (
    "federation",
    "lab",
    "name",
    "role",
    "follow",
    "sync_with",
    "sync_all",
    "sync_period",
    "sync_others_period",
    "sync_timeout",
    "sync_window",
    "estimator",
    "four_timestamps",
    "pose_rate",
    "status_period",
    "clock_offset",
    "clock_drift_ppm",
    "clock_step",
    "stale_after",
    "duration",
    "status_json",
    "record",
    "runs_dir",
    "wait_start",
    "platform",
    "platform_preset",
    "seed",
    "latency_compensation",
)


def agent_config(args: argparse.Namespace) -> AgentConfig:
    """The agent's file (if any), then its part in an experiment (if any), overlaid
    with the flags given on the command line."""
    flags = {}
    for name in _AGENT_FLAGS:
        value = getattr(args, name)
        if value is not None and value != []:
            flags[name] = value
    return build_agent_config(args.agent_config, args.experiment, flags)


def build_agent_config(
    file: Path | None, experiment: Path | None, flags: dict[str, Any], source: str = "command line"
) -> AgentConfig:
    """An agent's settings: its ``file`` (if any), then its part in ``experiment`` (if
    any, picked by the lab and name in ``flags`` or else the file), then ``flags``
    (given by ``source``, named in errors)."""
    data: dict[str, Any] = {}
    sources = []
    if file is not None:
        base = load_model(AgentConfig, file)
        data = base.model_dump(exclude_unset=True)
        sources.append(str(file))
    if experiment is not None:
        lab, name = flags.get("lab", data.get("lab")), flags.get("name", data.get("name"))
        record = "record" in flags or "record" in data
        part, platform_given = _experiment_part(experiment, lab, name, record=record)
        data = _overlay(data, part, platform_given, file, experiment)
        sources.append(str(experiment))
    return validate(AgentConfig, data | flags, " + ".join([*sources, source]))


def _overlay(
    own: dict[str, Any],
    part: dict[str, Any],
    platform_given: bool,
    file: Path | None,
    experiment: Path,
) -> dict[str, Any]:
    """An agent file's settings with its part in an experiment over them: the experiment
    gives what its participants share (role, follow, maneuver, ...), the file what is
    its host's, and the experiment no longer overrides it: where its runs are recorded
    (``runs_dir``, ``record``), and its real platform (``serial:PORT`` or another
    hardware kind, which flies the experiment's platform as its preset: the real table
    flies, not a simulated one in its place). A preset that is not the experiment's is
    refused (ConfigError naming both files)."""
    part = dict(part)
    if "runs_dir" in own:
        part.pop("runs_dir", None)
    mine = own.get("platform")
    if isinstance(mine, str) and _is_hardware(mine):
        preset = own.get("platform_preset")
        theirs = part.pop("platform")
        if platform_given and theirs != "kinematic":
            if preset is not None and preset != theirs:
                raise ConfigError(
                    f"{file}: field 'platform_preset': {preset!r}, but {experiment} flies "
                    f"this agent as {theirs!r}"
                )
            part["platform_preset"] = theirs
    elif not platform_given:
        part.pop("platform")  # the experiment names none: the file's, or the default
    return own | part


def _experiment_part(
    path: Path, lab: str | None, name: str | None, record: bool
) -> tuple[dict[str, Any], bool]:
    """This agent's settings from an experiment file: role, platform, maneuver, ...
    (every run recorded under ``runs`` unless ``record`` names one file for all), and
    whether the experiment names its platform."""
    from federation.core.keys import AgentId
    from schemas.experiment import load_experiment

    experiment = load_experiment(path)
    if not (lab and name):
        raise ConfigError(f"{path}: give the agent's lab and name (--lab, --name) to pick its part")
    me = AgentId(lab, name)
    part = experiment.participant(me)
    stand_in = experiment.stand_in
    if part is None and stand_in is not None and stand_in.agent == str(me):
        # The leader's stand-in: a twin of its preset (federation.runtime.agent.role) that
        # joins every run under way (rejoin auto) to know its time, and flies only while
        # it holds the leader's role.
        return {
            "federation": experiment.federation,
            "role": "stand-in",
            "platform": stand_in.preset,
            "reference": str(experiment.leader),
            "maneuver": experiment.maneuver.model_dump(),
            "wait_start": True,
            "experiment": str(path),
            "run_duration": experiment.duration,
            "rejoin": "auto",
            **({} if record else {"runs_dir": "runs"}),
        }, True
    if part is None:
        names = ", ".join(p.agent for p in experiment.participants)
        raise ConfigError(f"{path}: {me} does not take part (participants: {names})")
    return {
        "federation": experiment.federation,
        "role": part.role,
        "platform": part.platform,
        "follow": part.follow,
        # Runs start at the leader's time (ctl start's ``at``): every participant's
        # reference is the leader, also a follower of a follower (whose default, the
        # agent it follows, would start it early or late by that agent's clock).
        "reference": str(experiment.leader),
        "latency_compensation": part.latency_compensation,
        "follow_preset": _follow_preset(experiment, part, path),
        "maneuver": experiment.maneuver.model_dump(),
        "wait_start": True,
        "experiment": str(path),
        "run_duration": experiment.duration,
        # The experiment's rejoin, where it says more than the platform's default.
        **({} if experiment.rejoin_of(part) is None else {"rejoin": experiment.rejoin_of(part)}),
        # Every run recorded on this host, unless a recording names one file for all.
        **({} if record else {"runs_dir": "runs"}),
        **_scenario_part(experiment, me),
        **({"seed": part.seed} if part.seed is not None else {}),
    }, "platform" in part.model_fields_set


def _follow_preset(experiment: Any, part: Any, path: Path) -> str | None:
    """The leader's preset for a follower's heading filter (agents.flown), if it loads on
    this host: a leader's platform file that only the leader's host has leaves the
    follower on the maneuver itself, saying so, rather than refusing to start."""
    preset: str | None = experiment.follow_preset(part)
    if preset is None:
        return None
    from schemas.platform import load_platform

    try:
        load_platform(preset)
    except ConfigError as e:
        log.warning(
            "%s: the leader's platform %s does not load here (%s): the heading filter "
            "moves along the maneuver itself",
            path,
            preset,
            e,
        )
        return None
    return preset


def _scenario_part(experiment: Any, me: Any) -> dict[str, Any]:
    """A formation, docking or adaptive-gain part, or a plug-in scenario's (none for plain
    attitude tracking): an agent whose scenario reads every other agent's pose watches
    them all."""
    from agents.registry import scenario_class

    scenario = experiment.part(me)
    if scenario is None:
        return {}
    return {
        "scenario": scenario.model_dump(),
        **({"watch_all": True} if scenario_class(experiment.kind).watch_all else {}),
    }


def _is_hardware(spec: str) -> bool:
    """Whether ``spec`` names a real platform (``serial:PORT``; an unknown kind is not:
    the agent's settings say why when they are checked)."""
    from schemas.platform import platform_kind
    from schemas.registry import RegistryError

    try:
        return platform_kind(spec)[0].hardware
    except RegistryError:
        return False


def _clock_step(text: str) -> tuple[float, float]:
    at, sep, jump = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(at), float(jump)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected AT:SECONDS, e.g. 20:0.5, not {text!r}"
        ) from None


def run(args: argparse.Namespace) -> int:
    from agents.platform import PlatformError
    from federation.runtime.agent import AgentRuntime, NameTaken
    from federation.runtime.heap import freeze_startup_heap

    config = agent_config(args)
    check_agent_identity(args, config.agent)
    if args.cpus is not None:
        from federation.runtime.cpus import pin_process

        pin_process(args.cpus, "--cpus")  # before the session: Zenoh's threads inherit it
    stop = stop_on_signals()
    session = open_session(args, stop)
    if session is None:
        return 0
    with session:
        try:
            runtime = AgentRuntime(config, session)
        except PlatformError as error:
            print(f"fedlab agent: error: {error}", file=sys.stderr)
            return 1
        try:
            runtime.start()
        except NameTaken as error:
            runtime.close()
            print(f"fedlab agent: error: {error}", file=sys.stderr)
            return 2
        except BaseException:  # a port, a file, a signal: closed (valves held) first
            runtime.close()
            raise
        freeze_startup_heap()
        try:
            runtime.run(stop)
        except PlatformError as error:
            print(f"fedlab agent: error: {error}; all valves closed", file=sys.stderr)
            return 1
        finally:
            runtime.close()
    log.info("agent %s stopped", config.agent)
    return 0
