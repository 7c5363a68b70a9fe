"""The SDK: a third-party virtual agent in a few lines.

::

    from federation import Agent, Pose

    def where(t: float) -> Pose:          # t: simulation time (s)
        return Pose(x=0.5 * t, heading=0.1 * t)

    with Agent("lab3/ghost", where, connect=["tcp/127.0.0.1:7447"]) as ghost:
        time.sleep(10)
        print(ghost.others())             # {"kiruna/knatte": (t_sim, Pose(...)), ...}

In a federation whose routers check who speaks (``fedlab deploy``), give the Zenoh
configuration that proves the agent's name: ``config="lab3-ghost.json5"`` (its
certificate's Common Name, or its user name, is ``lab3/ghost``). One proving another
name is refused before any session opens (its router would drop what it sends).

The agent joins by name, answers sync queries, publishes its pose at ``rate`` Hz
(stamped with its reference time) and status once a second, exactly like ``fedlab
agent``; it runs in a background thread until the ``with`` block ends. Given a
``reference`` (the federation's reference agent, e.g. the leader) it syncs with that
agent only and places every other agent's pose by the reference stamp the pose
carries; without one it is its own reference and syncs with every agent alive.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, cast

import zenoh

from agents.guidance import Track
from agents.kinematic import KinematicPlatform
from federation.core.wire import Pose
from federation.runtime.agent import AgentRuntime
from federation.runtime.identity import check_identity
from federation.runtime.router import refuse_reachable_agent
from federation.runtime.session import (
    DEFAULT_TIMEOUT,
    build_config,
    connect_error,
    endpoints,
    fail_fast,
)
from schemas.config import AgentConfig, ZenohOptions, validate

__all__ = ["Agent", "PoseSource"]

LOCAL_ROUTER = "tcp/127.0.0.1:7447"
"""Where an agent given no endpoint dials: its lab's router on this host."""


class _HasPose(Protocol):
    def pose(self, t: float) -> Pose: ...


PoseSource = Callable[[float], Pose] | _HasPose
"""A function of simulation time giving the pose, or an object with ``pose(t)``."""


class _SourcePlatform(KinematicPlatform):
    """A pose source as a platform: guidance is ignored, the source decides.

    Holding, releasing and closing are the kinematic platform's; held, the last
    pose stays as it was.
    """

    def __init__(self, source: PoseSource, rate: float, clock: Callable[[float], float | None]):
        super().__init__(rate=rate)
        method = getattr(source, "pose", None)
        self.source = cast(Callable[[float], Pose], method if callable(method) else source)
        self.sim_time = clock

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        if not self.held:
            t_sim = self.sim_time(t)
            self.pose = Pose(*self.source(t if t_sim is None else t_sim))
        return self.pose


class Agent:
    """A virtual agent. ``name`` is ``"lab/name"``; ``pose`` its pose source.

    ``reference``: the agent whose clock is simulation time (default: the agent's
    own). ``timeout``: seconds to reach the router before ``with`` raises
    :class:`~federation.runtime.session.ConnectError` naming each endpoint and why
    (refused, unreachable, TLS). ``config``: a Zenoh json5 configuration file (TLS
    certificates, user and password, its router's endpoints), whose identity must be
    ``name``: else ``with`` raises :class:`~federation.runtime.identity.IdentityError`
    naming both. ``connect``: endpoints to dial instead of the file's (default: the
    file's, or ``tcp/127.0.0.1:7447`` without one). Further
    keyword arguments are :class:`schemas.config.AgentConfig` fields.
    """

    def __init__(
        self,
        name: str,
        pose: PoseSource,
        connect: Sequence[str] | None = None,
        federation: str = "default",
        reference: str | None = None,
        rate: float = 20.0,
        timeout: float = DEFAULT_TIMEOUT,
        config: str | Path | None = None,
        **settings: Any,
    ):
        lab, _, agent = name.partition("/")
        data: dict[str, Any] = {
            "federation": federation, "lab": lab, "name": agent, "role": "member"
        }  # fmt: skip
        data |= {"reference": reference, "pose_rate": rate, "watch_all": True, **settings}
        self.config = validate(AgentConfig, data, f"Agent({name!r})")
        if connect is None:  # the config file's endpoints, else a router on this host
            connect = [] if config is not None else [LOCAL_ROUTER]
        options = {"connect": list(connect), "config": config}
        self.options = validate(ZenohOptions, options, f"Agent({name!r})")
        self._source = pose
        self.timeout = timeout
        self._stop = threading.Event()
        self._session: zenoh.Session | None = None
        self._thread: threading.Thread | None = None
        self.runtime: AgentRuntime | None = None

    def __enter__(self) -> Agent:
        conf = build_config(self.options, default_mode="client")
        if not endpoints(conf):  # a file with credentials only: a router on this host
            conf.insert_json5("connect/endpoints", json.dumps([LOCAL_ROUTER]))
        me = f"{self.config.lab}/{self.config.name}"
        source = str(self.options.config) if self.options.config else f"Agent({me!r})"
        check_identity(conf, me, source)  # identity = name: refused before a session
        refuse_reachable_agent(conf, source)
        fail_fast(conf, self.timeout)
        try:
            self._session = zenoh.open(conf)
        except zenoh.ZError as error:
            raise connect_error(conf, error, self.timeout) from None
        runtime = AgentRuntime(self.config, self._session, platform=None)
        runtime.platform = _SourcePlatform(self._source, self.config.pose_rate, runtime.sim_time)
        try:
            runtime.start()
        except Exception:
            runtime.close()
            self._session.close()
            raise
        self.runtime = runtime
        self._thread = threading.Thread(target=runtime.run, args=(self._stop,), daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10)
        if self.runtime is not None:
            self.runtime.close()
        if self._session is not None:
            self._session.close()

    def _running(self) -> AgentRuntime:
        if self.runtime is None:
            raise RuntimeError("use the agent inside `with Agent(...) as agent:`")
        return self.runtime

    def others(self) -> dict[str, tuple[float, Pose]]:
        """Every other agent's latest pose on simulation time: {"lab/name": (t, Pose)};
        ``t`` is the sender's own reference stamp when it shares this agent's reference,
        else its clock mapped through this agent's pairwise offset estimate."""
        return self._running().others()

    def offset(self, agent: str) -> float | None:
        """Estimated clock offset of ``agent`` minus this agent's clock (s)."""
        runtime = self._running()
        for peer_id in list(runtime.peers):  # liveliness may add one meanwhile
            if str(peer_id) == agent:
                return runtime.timebase.offset(peer_id, runtime.clock.now())
        return None

    @property
    def time(self) -> float | None:
        """Simulation time now (s); None until synchronized with the reference."""
        runtime = self._running()
        return runtime.sim_time(runtime.clock.now())
