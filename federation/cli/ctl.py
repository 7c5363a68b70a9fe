"""``fedlab ctl start|freeze|resume|abort|reset|admit|status``: execution control.

Parses, calls :func:`federation.runtime.control.issue` (or
:func:`~federation.runtime.control.status`) and prints who confirmed, who is
missing what, and why an agent did not confirm.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_federation_flag,
    add_timeout_flag,
    add_zenoh_flags,
    agent_id,
    client_conf,
    nonnegative,
    open_session,
    positive,
    run_id,
    stop_on_signals,
)
from federation.core import keys
from federation.core.preflight import CHECKS, DEFAULT_MAX_BOUND, Row, blocking
from federation.runtime import control

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "ctl",
        help="start, freeze, resume, abort or reset a run; admit an agent into one under "
        "way; hand the leader's role back; status: who is ready",
        formatter_class=Formatter,
        description=(
            "start checks every participant first (present, waiting, synchronized with the\n"
            "reference, platform ready, recording) and starts nothing unless all pass (exit\n"
            "code 1 and a table of who misses what; --force overrides). It names the run\n"
            "(--run-id, default <experiment>-<UTC time>), syncs with the reference agent (the\n"
            "experiment's leader) and announces a start --in seconds ahead; every agent begins\n"
            "when its own synchronized clock reaches that instant and is done (valves closed,\n"
            "recording finalized) after the experiment's duration. abort is sent at once and\n"
            "puts every platform in safe hold; reset brings aborted agents back to waiting.\n"
            "freeze and resume sync with the run's reference and are announced --in seconds\n"
            "ahead (default: the least that reaches every participant, from the one-way\n"
            "delays they report): every agent freezes (resumes) at that instant, at the same\n"
            "run time (one receiving a resume over 1 s late ignores it; a freeze late freezes\n"
            "at once). admit LAB/NAME lets an agent (re)started mid-run whose rejoin policy is\n"
            "operator join the run under way. handback LAB/NAME hands the leader's role back\n"
            "to a leader its stand-in deposed (it holds until then) and waits until it holds\n"
            "it again. status prints the preflight table (and who\n"
            "waits to be admitted). Exit code 1\n"
            "if an agent did not confirm (the table says why) or the router is unreachable."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab ctl status --experiment deploy/experiments/attitude-tracking.toml \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl start --experiment deploy/experiments/attitude-tracking.toml \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl freeze --experiment deploy/experiments/attitude-tracking.toml \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl abort -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl admit rome/pinocchio -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl handback kiruna/knatte -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl reset --experiment deploy/experiments/attitude-tracking.toml \\\n"
            "      -e tcp/127.0.0.1:7447"
        ),
    )
    p.add_argument(
        "action",
        choices=[*control.ACTIONS, "admit", "handback", "status"],
        help="start, freeze or resume at a common instant; abort, reset on receipt; admit "
        "LAB/NAME into the run under way; handback LAB/NAME (the leader); status",
    )
    p.add_argument(
        "agents",
        nargs="*",
        type=agent_id,
        metavar="LAB/NAME",
        help="admit: the agents to let rejoin the run under way (their rejoin policy is "
        "operator, a real platform's default; ctl status shows who waits for it); handback: "
        "the one leader to hand its role back to",
    )
    p.add_argument("--experiment", type=Path, metavar="FILE", help="experiment file (TOML)")
    add_federation_flag(p, "federation name (an experiment's own wins)")
    p.add_argument(
        "--reference", type=agent_id, metavar="LAB/NAME", help="agent whose clock is reference time"
    )
    p.add_argument(
        "--in",
        dest="start_in",
        type=nonnegative,
        metavar="S",
        help=f"start this many seconds ahead, at least {control.START_IN_MIN:g}, or freeze or "
        "resume (default: for a start the experiment's start_delay, else "
        f"{control.DEFAULT_START_IN:g}; for a freeze or resume the least that reaches every "
        "participant, from their one-way delays to the reference)",
    )
    p.add_argument("--run-id", type=run_id, metavar="ID", help="name of the run (start)")
    p.add_argument(
        "--duration",
        type=positive,
        metavar="S",
        help="s of run time until done (default: the experiment's duration)",
    )
    p.add_argument(
        "--force", action="store_true", help="start even if preflight fails (says what it overrode)"
    )
    p.add_argument(
        "--max-bound",
        type=positive,
        default=DEFAULT_MAX_BOUND,
        metavar="S",
        help="largest error bound of an agent's estimate of the reference clock for a start",
    )
    p.add_argument(
        "--wait", type=nonnegative, default=5.0, metavar="S", help="confirmation timeout"
    )
    p.add_argument(
        "--discover",
        type=nonnegative,
        default=1.5,
        metavar="S",
        help=(
            "at most S s to collect statuses (with --experiment: until each participant's is "
            "in); start then waits S s at most for every preflight check to pass"
        ),
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    add_timeout_flag(p)
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def preflight_table(rows: list[Row], title: str) -> Any:
    """The preflight rows as a rich table: one column per check, failures in red."""
    from rich.table import Table

    table = Table(title=title)
    table.add_column("agent")
    table.add_column("mode")
    for name in CHECKS:
        table.add_column(name)
    for row in rows:
        cells = []
        for name in CHECKS:
            check = row.checks.get(name)
            if check is None:
                cells.append("")
            elif check.ok:
                shown = check.detail if name in ("synced", "recording") else ""
                cells.append(f"[green]ok[/green] {shown}".strip())
            else:
                cells.append(f"[red]{check.detail}[/red]")
        agent = row.agent if row.participant else f"{row.agent} (not a participant)"
        mode = row.mode or "-"
        if row.admit_run is not None:
            mode = f"[yellow]{mode}: to be admitted to {row.admit_run} (ctl admit)[/yellow]"
        table.add_row(agent, mode, *cells)
    return table


def _agents_wrong(action: str, agents: list[Any]) -> str | None:
    """Why the agents named do not fit ``action`` (None: they do)."""
    if agents and action not in ("admit", "handback"):
        return f"{action} names no agents (only admit and handback do)"
    if action == "admit" and not agents:
        return "admit names the agents to admit: fedlab ctl admit LAB/NAME"
    if action == "handback" and len(agents) != 1:
        return "handback names one leader: fedlab ctl handback LAB/NAME"
    return None


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from schemas.experiment import load_experiment

    console = Console(stderr=args.json, width=max(Console().width, 120))
    experiment = load_experiment(args.experiment) if args.experiment else None
    wrong = _agents_wrong(args.action, args.agents)
    if wrong is not None:
        console.print(f"[red]{wrong}[/red]")
        return 2
    session = open_session(args, stop_on_signals())
    if session is None:
        return 0
    with session:
        if args.action == "admit":
            return run_admit(args, session, experiment, console)
        if args.action == "handback":
            return run_handback(args, session, experiment, console)
        if args.action == "status":
            rows = control.status(
                session, federation=args.federation, experiment=experiment,
                discover=args.discover, max_bound=args.max_bound,
            )  # fmt: skip
            ready = not blocking(rows) and any(r.participant for r in rows)
            if args.json:
                print(json.dumps({"ready": ready, "agents": [r.as_json() for r in rows]}, indent=1))
            else:
                console.print(preflight_table(rows, "ready" if ready else "not ready"))
            return 0 if ready else 1
        try:
            result = control.issue(
                session,
                args.action,
                federation=args.federation,
                experiment=experiment,
                reference=args.reference,
                start_in=args.start_in,
                wait=args.wait,
                discover=args.discover,
                run_id=args.run_id,
                duration=args.duration,
                force=args.force,
                max_bound=args.max_bound,
                progress=console.print,
            )
        except control.PreflightFailed as failed:
            if args.json:
                rows_json = [r.as_json() for r in failed.rows]
                print(json.dumps({"ok": False, "started": False, "preflight": rows_json}, indent=1))
            else:
                console.print(preflight_table(failed.rows, "not started: preflight failed"))
                console.print("nothing was started; fix the above or use --force")
            return 1
    federation = experiment.federation if experiment is not None else args.federation
    hint = None if result.ok else refused_hint(args, federation, result)
    if args.json:
        print(json.dumps(result.as_json() | ({"hint": hint} if hint else {}), indent=1))
    else:
        print_result(console, args.action, result, hint)
    return 0 if result.ok else 1


def run_admit(args: argparse.Namespace, session: Any, experiment: Any, console: Any) -> int:
    """``fedlab ctl admit LAB/NAME...``: who rejoined, and why the others did not."""
    from rich.table import Table

    from federation.runtime.admit import admit

    federation = experiment.federation if experiment is not None else args.federation
    result = admit(
        session, args.agents, federation=federation, wait=max(args.wait, 1.0),
        discover=args.discover, progress=console.print,
    )  # fmt: skip
    if args.json:
        print(json.dumps(result.as_json(), indent=1))
        return 0 if result.ok else 1
    table = Table(title=f"fedlab ctl admit ({result.elapsed:.2f} s)")
    for column in ("agent", "mode", "rejoined at run time", "why not"):
        table.add_column(column)
    for agent, mode in result.modes.items():
        joined = result.joined.get(agent)
        at = "" if joined is None else f"{joined:.3f} s"
        table.add_row(agent, mode, at, result.reasons.get(agent, ""))
    console.print(table)
    return 0 if result.ok else 1


def run_handback(args: argparse.Namespace, session: Any, experiment: Any, console: Any) -> int:
    """``fedlab ctl handback LAB/NAME``: whether the leader holds its role again, and why
    not."""
    from federation.runtime.handback import handback
    from federation.runtime.session import ConnectError

    federation = experiment.federation if experiment is not None else args.federation
    try:
        result = handback(
            session, args.agents[0], federation=federation, wait=max(args.wait, 3.0),
            discover=args.discover, progress=console.print,
        )  # fmt: skip
    except ConnectError as error:
        console.print(f"[red]{error}[/red]")
        return 1
    if args.json:
        print(json.dumps(result.as_json(), indent=1))
    elif result.ok:
        console.print(
            f"{result.leader} holds the leader's role again (epoch {result.epoch}; "
            f"{result.stand_in or 'its stand-in'} released it) after {result.elapsed:.2f} s"
        )
    else:
        console.print(f"[red]{result.leader} does not hold the role: {result.why}[/red]")
    return 0 if result.ok else 1


def print_result(
    console: Any, action: str, result: control.ControlResult, hint: str | None
) -> None:
    """The command's outcome as tables: the preflight, who confirmed, why not, and why
    no agent may have seen it (``hint``)."""
    from rich.table import Table

    if result.preflight:
        console.print(preflight_table(result.preflight, "preflight"))
    for line in result.overridden:
        console.print(f"[yellow]overridden by --force: {line}[/yellow]")
    run_id = result.command.run_id
    title = f"fedlab ctl {action}{' ' + run_id if run_id else ''} ({result.elapsed:.2f} s)"
    table = Table(title=title)
    table.add_column("agent")
    table.add_column("mode")
    table.add_column("applied at (reference time, run time)")
    table.add_column("why not confirmed")
    for agent, mode in result.modes.items():
        table.add_row(
            agent, mode, applied_at(result.applied.get(agent)), result.reasons.get(agent, "")
        )
    console.print(table)
    if hint:
        console.print(f"[red]{hint}[/red]")


def applied_at(transition: dict[str, Any] | None) -> str:
    """An agent's last transition as the table shows it: ``frozen 1234.567 s, 12.345 s``."""
    if not transition or transition.get("at") is None:
        return ""
    run_time = transition.get("run_time")
    text = f"{transition.get('event')} {transition['at']:.3f} s"
    return text + ("" if run_time is None else f", {run_time:.3f} s")


def refused_hint(
    args: argparse.Namespace, federation: str, result: control.ControlResult
) -> str | None:
    """Why no agent saw the command, when a router's access control likely dropped it:
    Zenoh drops a denied put without telling the sender (:func:`refused_commands`)."""
    from federation.core.authfail import refused_commands
    from federation.runtime.identity import IdentityError, identities

    conf, source = client_conf(args)
    try:
        proved = identities(conf, source)
    except IdentityError:
        proved = {}
    reasons = {a: result.reasons.get(a, "") for a in result.pending}
    key = keys.control_key(federation)
    return refused_commands(key, proved, source, reasons, frozenset(result.modes))
