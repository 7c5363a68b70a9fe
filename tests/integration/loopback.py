"""Handles on real fedlab processes on loopback, for the integration tests.

The ``labs`` fixture (tests/integration/conftest.py) gives a :class:`Labs`; its
factories write the command lines of ``fedlab router``, ``fedlab link`` and
``fedlab agent`` (this module is the one place they are written) and return
handles that know their endpoint, status file and process name::

    pair = labs.pair()                       # kiruna listens, rome dials it
    leader = labs.leader(pair.kiruna)        # kiruna/knatte
    follower = labs.follower(pair.rome, "--clock-offset", "26.42")
    follower.wait_samples(LEADER, 20, timeout=15)

Every wait is bounded and fails with the agent's last status line; every process
runs in the test's :class:`Fleet`, which stops it by pid at teardown and prints
its log when the test fails.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import zenoh

from federation.core import wire
from federation.fleet.launch import Fleet, free_port, wait_for
from federation.report.status import last_status, read_status

T = TypeVar("T")

__all__ = [
    "FLOAT_SLACK",
    "FOLLOWER",
    "LEADER",
    "Agent",
    "Host",
    "LabPair",
    "Labs",
    "Link",
    "PoseTap",
    "Router",
    "Tap",
    "client_config",
    "offset_error",
]

LEADER = "kiruna/knatte"
FOLLOWER = "rome/pinocchio"
STATUS_PERIOD = 0.5  # s between status lines: waits see progress twice a second


def client_config(endpoint: str) -> zenoh.Config:
    """A Zenoh client dialling only ``endpoint`` (no multicast scouting)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


class Tap(Generic[T]):
    """What is published on a key, as Zenoh delivers it, decoded by ``decode``
    (at most 10 000 samples)."""

    def __init__(self, endpoint: str, key: str, decode: Callable[[bytes], T]):
        self.samples: list[T] = []
        self._decode = decode
        self._lock = threading.Lock()
        self.session = zenoh.open(client_config(endpoint))
        self.sub = self.session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            if len(self.samples) < 10_000:
                self.samples.append(self._decode(sample.payload.to_bytes()))

    def received(self) -> list[T]:
        with self._lock:
            return list(self.samples)

    def close(self) -> None:
        self.sub.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


class PoseTap(Tap[wire.PoseSample]):
    """The pose samples published on a key."""

    def __init__(self, endpoint: str, key: str):
        super().__init__(endpoint, key, wire.decode_pose)


@dataclass
class Process:
    """One ``fedlab`` child process of a :class:`Fleet`, started again with the same arguments."""

    fleet: Fleet
    name: str
    args: list[str]

    def start(self) -> None:
        """(Re)start it; a router comes back on the same port."""
        self.fleet.start(self.name, self.args)

    def stop(self) -> int | None:
        """SIGTERM (SIGKILL after a grace period); the exit code."""
        return self.fleet.stop(self.name)

    def kill(self) -> None:
        """SIGKILL, as a crash would."""
        self.fleet.kill(self.name)

    def alive(self) -> bool:
        return self.fleet.alive(self.name)

    def log(self) -> str:
        path = self.fleet.log_path(self.name)
        return path.read_text() if path.exists() else ""


@dataclass
class Router(Process):
    """A lab's ``fedlab router``; ``endpoint`` is where it listens (dial this)."""

    lab: str = ""
    endpoint: str = ""


@dataclass
class Link(Process):
    """A ``fedlab link`` emulator: listens on ``endpoint``, relays to ``to``."""

    endpoint: str = ""
    to: str = ""


@dataclass
class LabPair:
    """Two lab routers: ``kiruna`` listens, ``rome`` dials it (through ``link`` if any)."""

    kiruna: Router
    rome: Router
    link: Link | None = None


@dataclass
class Agent(Process):
    """A ``fedlab agent`` writing status lines to ``status`` (and, if started with
    ``record=True``, its recording to ``record``)."""

    who: str = ""
    status: Path = field(default_factory=Path)
    record: Path = field(default_factory=Path)

    def lines(self) -> list[dict[str, Any]]:
        """Every complete status line so far."""
        return read_status(self.status)

    def last(self) -> dict[str, Any] | None:
        """The last status line, or None before the first."""
        return last_status(self.status)

    def latest(self) -> dict[str, Any]:
        """The last status line; fails if there is none."""
        line = self.last()
        assert line is not None, f"{self.who} wrote no status line\n{self.log()[-2000:]}"
        return line

    def peer(self, agent: str) -> dict[str, Any] | None:
        """This agent's view of ``agent`` (offset, delay, samples...) in its last line."""
        line = self.last()
        return None if line is None else line["peers"].get(agent)

    def samples(self, agent: str) -> int:
        """Sync exchanges with ``agent`` so far (0 before any)."""
        view = self.peer(agent)
        return 0 if view is None else int(view.get("samples", 0))

    def until(
        self, condition: Callable[[dict[str, Any]], object], timeout: float, what: str = ""
    ) -> dict[str, Any]:
        """Wait (at most ``timeout`` s) until ``condition`` holds for the last status line;
        returns that line, or fails with the last line seen."""
        seen: list[dict[str, Any]] = []

        def met() -> bool:
            line = self.last()
            if line is None:
                return False
            seen[:] = [line]
            return bool(condition(line))

        assert wait_for(met, timeout), (
            f"{self.who}: {what or 'condition'} not met within {timeout} s; "
            f"last status {seen[0] if seen else None}"
        )
        return seen[0]

    def wait_status(self, timeout: float) -> dict[str, Any]:
        """Wait for the first status line (written once the session is open)."""
        return self.until(lambda line: True, timeout, "a status line")

    def wait_samples(self, agent: str, n: int, timeout: float) -> dict[str, Any]:
        """Wait until at least ``n`` sync exchanges with ``agent`` are counted."""
        return self.until(
            lambda line: line["peers"].get(agent, {}).get("samples", 0) >= n,
            timeout,
            f"{n} sync samples with {agent}",
        )


@dataclass
class Host(Process):
    """A ``fedlab host`` of several agents: ``agents[who]`` reads each one's status lines
    (its own :class:`Agent` view, never started or stopped on its own)."""

    agents: dict[str, Agent] = field(default_factory=dict)


@dataclass
class Labs:
    """Factories of routers, links and agents on loopback, all in one :class:`Fleet`."""

    fleet: Fleet
    tmp: Path

    @staticmethod
    def endpoint() -> str:
        """A fresh loopback TCP endpoint."""
        return f"tcp/127.0.0.1:{free_port()}"

    def router(
        self,
        lab: str,
        *extra: str,
        listen: str | None = None,
        connect: str | Router | Link | None = None,
        config: Path | None = None,
    ) -> Router:
        """Start ``fedlab router`` for ``lab`` listening on ``listen`` (a fresh endpoint by
        default), dialling ``connect``; with ``config`` its lab is taken from that file."""
        listen = listen or self.endpoint()
        args = ["router", *(["-c", str(config)] if config else ["--lab", lab]), "-l", listen]
        if connect is not None:
            args += ["-e", connect if isinstance(connect, str) else connect.endpoint]
        router = Router(self.fleet, f"router-{lab}", [*args, *extra], lab=lab, endpoint=listen)
        router.start()
        return router

    def link(self, to: str | Router, *extra: str, listen: str | None = None) -> Link:
        """Start ``fedlab link`` relaying from ``listen`` (fresh by default) to ``to``."""
        listen = listen or self.endpoint()
        target = to if isinstance(to, str) else to.endpoint
        args = ["link", "--listen", listen, "--to", target, *extra]
        link = Link(self.fleet, "link", args, endpoint=listen, to=target)
        link.start()
        return link

    def pair(self, link: bool | Sequence[str] = False) -> LabPair:
        """Kiruna's router listening and Rome's dialling it; with ``link`` (True, or the
        ``fedlab link`` arguments) Rome dials through the link emulator."""
        kiruna = self.router("kiruna")
        via = None
        if link is not False:
            via = self.link(kiruna, *(() if link is True else link))
        return LabPair(kiruna, self.router("rome", connect=via or kiruna), via)

    @staticmethod
    def agent_args(
        who: str,
        at: str | Router | None,
        *extra: str,
        role: str | None = None,
        follow: str | None = None,
    ) -> list[str]:
        """The ``fedlab agent`` arguments for ``who`` (lab/name) dialling ``at``."""
        lab, name = who.split("/")
        args = ["agent"]
        if role is not None:
            args += ["--role", role]
        if follow is not None:
            args += ["--follow", follow]
        args += ["--lab", lab, "--name", name]
        if at is not None:
            args += ["-e", at if isinstance(at, str) else at.endpoint]
        return [*args, *extra]

    def agent(
        self,
        who: str,
        at: str | Router | None,
        *extra: str,
        role: str | None = None,
        follow: str | None = None,
        status_period: float | None = STATUS_PERIOD,
        record: bool = False,
    ) -> Agent:
        """Start ``fedlab agent`` as ``who`` (lab/name) dialling ``at`` (None: ``extra``
        says how, e.g. ``-c FILE``); status lines go to ``<lab>-<name>.jsonl`` and, with
        ``record``, the recording to ``<lab>-<name>.mcap`` in the test's folder."""
        stem = who.replace("/", "-")
        status = self.tmp / f"{stem}.jsonl"
        args = self.agent_args(who, at, role=role, follow=follow)
        args += ["--status-json", str(status)]
        if status_period is not None:
            args += ["--status-period", str(status_period)]
        mcap = self.tmp / f"{stem}.mcap"
        if record:
            args += ["--record", str(mcap)]
        agent = Agent(self.fleet, stem, [*args, *extra], who=who, status=status, record=mcap)
        agent.start()
        return agent

    def host(
        self,
        at: str | Router,
        agents: dict[str, dict[str, Any]],
        *extra: str,
        name: str = "host",
        status_period: float = STATUS_PERIOD,
    ) -> Host:
        """Start ``fedlab host`` dialling ``at`` with one file per agent of ``agents``
        (lab/name -> its other settings, e.g. ``{"role": "follower", "follow": LEADER}``),
        each writing status lines to ``<lab>-<name>.jsonl`` in the test's folder."""
        files, views = [], {}
        for who, settings in agents.items():
            lab, agent_name = who.split("/")
            stem = who.replace("/", "-")
            fields = {"lab": lab, "name": agent_name, "status_period": status_period, **settings}
            path = self.tmp / f"{stem}.toml"
            path.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in fields.items()))
            files.append(str(path))
            views[who] = Agent(self.fleet, name, [], who=who, status=self.tmp / f"{stem}.jsonl")
        endpoint = at if isinstance(at, str) else at.endpoint
        args = ["host", *files, "-e", endpoint, "--status-dir", str(self.tmp), *extra]
        host = Host(self.fleet, name, args, agents=views)
        host.start()
        return host

    def leader(self, at: str | Router | None, *extra: str, who: str = LEADER, **kw: Any) -> Agent:
        """A leader (kiruna/knatte by default); keywords as :meth:`agent`."""
        return self.agent(who, at, *extra, role="leader", **kw)

    def follower(
        self,
        at: str | Router | None,
        *extra: str,
        who: str = FOLLOWER,
        follow: str = LEADER,
        **kw: Any,
    ) -> Agent:
        """A follower (rome/pinocchio by default) tracking ``follow``."""
        return self.agent(who, at, *extra, role="follower", follow=follow, **kw)


def answer_sync(query: zenoh.Query) -> None:
    """A sync reply of the paper's size, as a second process under an agent's name
    answers its sync key (the name checks' tests)."""
    query.reply(query.key_expr, bytes(64))


FLOAT_SLACK = 20e-6
"""Seconds allowed beyond a stated error bound: float rounding of clocks read tens
of seconds from their origins, and the microseconds between two clock reads."""


def offset_error(view: dict[str, Any], truth: float) -> float:
    """The error of a peer's offset estimate (``view``, one entry of a status line's
    ``peers``) against ``truth``, asserted within the bound the estimate states.

    Each exchange's offset is off by at most half its round trip, and the clock
    filter's estimate is a weighted mean of exchanges: it is off by at most half the
    window's fastest round trip (not over the median one-way ``delay``) plus the
    filter's ``bound`` (half the weighted mean excess). That bound is measured in the
    same run, so the claim holds whatever else the cores are doing; on an idle
    loopback it is a few hundred microseconds."""
    error = float(view["offset"]) - truth
    stated = float(view["delay"]) + float(view["bound"])
    assert abs(error) <= stated + FLOAT_SLACK, (
        f"offset error {error * 1e3:+.3f} ms beyond the stated bound {stated * 1e3:.3f} ms "
        f"(delay {view['delay'] * 1e3:.3f} ms + filter bound {view['bound'] * 1e3:.3f} ms)",
        view,
    )
    return error
