"""Several agents in one process: one Zenoh session, one loop thread, shared work.

A lab that flies many virtual platforms (a formation rehearsal, a scale test) runs
them in one process rather than one process each (``fedlab host``; ``fedlab bench
scale`` measures its workers this way). The agents share:

- one Zenoh session: one connection to the lab's router;
- one loop thread (:func:`federation.runtime.loop.run_together`), ticking in groups;
- one subscription per key (:class:`~federation.runtime.fanout.Fanout`): a pose that
  several of them follow is read once;
- one clock per distinct clock setting, so that agents on one clock share one sync
  exchange per peer they query (:class:`~federation.runtime.links.SyncLinks`).

What is not shared is each agent's own: its platform, its hold, its counters, its
status and its recording. :func:`check_hosted` refuses what must not be hosted: two
agents with one name, two federations on one session, and real platforms
(``serial:``), which run in a process of their own so that their steps never wait
behind other agents' work. An agent whose duration has passed is closed (it leaves
the federation) while the others fly on. A failure in any agent's loop closes every
agent (:meth:`~federation.runtime.agent.AgentRuntime.close` holds each platform's
valves closed): one agent's fault stops the host, it does not leave the others flying
without a loop.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import zenoh

from federation.core import keys
from federation.core.holds import Trigger
from federation.runtime.agent import AgentRuntime, NameTaken
from federation.runtime.clock import ExecClock
from federation.runtime.fanout import Fanout
from federation.runtime.links import SyncLinks
from federation.runtime.loop import run_together
from federation.runtime.routerwatch import watch_routers
from federation.runtime.session import undeclare_all
from schemas.config import AgentConfig, ConfigError

__all__ = [
    "Hosted",
    "check_hosted",
    "close_all",
    "host",
    "refuse_taken_names",
    "shared_clocks",
]

log = logging.getLogger("fedlab.host")

Hosted = tuple[str, AgentConfig]
"""An agent to host: where its settings came from (a file's name, for errors) and them."""


def check_hosted(hosted: Sequence[Hosted]) -> None:
    """Refuse (ConfigError, naming the file and the field) what one process must not
    host: no agent, one name twice, more than one federation, two agents writing one
    status or recording file, a real platform."""
    if not hosted:
        raise ConfigError("no agent to host: give at least one agent file")
    first_source, first = hosted[0]
    seen: dict[str, str] = {}
    files: dict[Path, str] = {}
    for source, config in hosted:
        name = str(config.agent)
        if name in seen:
            raise ConfigError(f"{source}: lab/name {name} is also {seen[name]}'s")
        seen[name] = source
        if config.federation != first.federation:
            raise ConfigError(
                f"{source}: federation: {config.federation!r}, but {first_source}'s is "
                f"{first.federation!r}: the agents of one host share one session, so one "
                f"federation"
            )
        for field, path in (("status_json", config.status_json), ("record", config.record)):
            if path is None:
                continue
            other = files.get(Path(path).resolve())
            if other is not None:
                raise ConfigError(
                    f"{source}: {field}: {path} is also {other}'s: two agents would write "
                    f"into one file"
                )
            files[Path(path).resolve()] = f"{source} ({field})"
        if config.hardware:
            raise ConfigError(
                f"{source}: platform: {config.platform} is a real platform: run it as its "
                f"own `fedlab agent`, so that its control steps never wait behind other "
                f"agents' work"
            )


def shared_clocks(configs: Sequence[AgentConfig]) -> list[ExecClock]:
    """One clock per agent, the same object for agents with the same clock settings
    (so they share their sync exchanges); an agent that rehearses a clock step gets
    one of its own (the step moves its clock only)."""
    clocks: dict[tuple[float, float], ExecClock] = {}
    out = []
    for config in configs:
        if config.clock_step is not None:
            out.append(ExecClock(config.clock_offset, config.clock_drift_ppm))
            continue
        setting = (config.clock_offset, config.clock_drift_ppm)
        clock = clocks.get(setting)
        if clock is None:
            clock = clocks[setting] = ExecClock(*setting)
        out.append(clock)
    return out


def refuse_taken_names(session: zenoh.Session, configs: Sequence[AgentConfig]) -> None:
    """Raise NameTaken, naming them, if any of ``configs``' agents is already alive in
    the federation: one liveliness query for all, before any of them is declared.

    Each agent asks again as it starts (:meth:`AgentRuntime.start`), but once a first
    agent of the session has declared its liveliness subscriber, a later agent's query
    on the same session was answered at once and empty while another process held its
    name (seen with three hosted agents): the check for all comes first. Two processes
    that start one name within the same moment both pass, as two ``fedlab agent`` do;
    each agent then finds the other answering its sync key when it looks again
    (:meth:`AgentRuntime._check_name_again`) and holds for good, and the agents that
    follow it hold as the name is contested (two sources)."""
    if not configs:
        return
    federation = configs[0].federation
    mine = {c.agent for c in configs}
    taken = set()
    for reply in session.liveliness().get(keys.all_agents(federation), timeout=1.0):
        if reply.ok is not None:
            parsed = keys.parse_agent_key(federation, str(reply.ok.key_expr))
            if parsed is not None and parsed[1] is None and parsed[0] in mine:
                taken.add(str(parsed[0]))
    if taken:
        raise NameTaken(
            f"{', '.join(sorted(taken))} already in federation {federation}: stop "
            f"{'it' if len(taken) == 1 else 'them'} first or host other names"
        )


def host(
    configs: Sequence[AgentConfig],
    session: zenoh.Session,
    stop: threading.Event,
    group: int = 1,
    spread: float | None = None,
    on_started: Callable[[], None] | None = None,
) -> None:
    """Start ``configs``' agents on ``session`` and run them on this thread until
    ``stop`` is set or every one's duration has passed; then close every one (each
    platform held). Agents tick in groups of ``group``, the groups spread over
    ``spread`` seconds (default: the shortest pose period). ``on_started`` is called
    once every agent is up, before the first tick. Raises ConfigError for what one
    process must not host (:func:`check_hosted`), before anything is declared, and
    what an agent raises (NameTaken at start, a platform's error in the loop) after
    closing them all."""
    if group < 1:
        raise ValueError(f"group must be at least 1 agent, not {group!r}")
    check_hosted([(str(config.agent), config) for config in configs])
    if spread is None:
        spread = 1.0 / max(c.pose_rate for c in configs) if configs else 0.0
    refuse_taken_names(session, configs)
    fanout, links = Fanout(session), SyncLinks()
    runtimes: list[AgentRuntime] = []
    listeners = watch_routers(session, f"host of {len(configs)} agent(s)")
    ended: list[AgentRuntime] = []

    def retire(runtime: AgentRuntime) -> None:
        # An agent whose duration has passed leaves the federation as a process of its
        # own would: its token, queryables and subscriptions go (its followers see it
        # gone and hold) while the other agents of the host fly on. Its recording
        # finishes on a thread of its own: the loop that steps the others waits for no
        # disk (a manifest's checksum of a large file had stalled them for seconds).
        ended.append(runtime)
        close_all([runtime], wait=False)

    try:
        for config, clock in zip(configs, shared_clocks(configs), strict=True):
            runtime = AgentRuntime(config, session, clock, fanout=fanout, links=links)
            runtimes.append(runtime)  # closed below even if it fails to start
            runtime.start()
        if on_started is not None:
            on_started()
        run_together(runtimes, stop, spread=spread, group=group, on_end=retire)
    finally:
        close_all([runtime for runtime in runtimes if runtime not in ended])
        undeclare_all(listeners)
        for runtime in ended:  # their recordings finished before the session closes
            for thread in runtime.finishing:
                thread.join(FINISH_TIMEOUT)


FINISH_TIMEOUT = 60.0
"""s to wait, as a host stops, for an ended agent's recording to finish."""


def close_all(runtimes: Sequence[AgentRuntime], wait: bool = True) -> None:
    """Hold every agent's platform (all valves closed) first, then close each (``wait``:
    see :meth:`AgentRuntime.close`): one that fails to hold or close is logged and the
    others still are."""
    for runtime in runtimes:
        try:
            runtime.safety.apply(Trigger.ENDED)  # every valve closed, for good
        except Exception:
            log.exception("%s: holding the platform failed", runtime.me)
    for runtime in runtimes:
        try:
            runtime.close(wait=wait)
        except Exception:
            log.exception("%s: closing failed", runtime.me)
