"""The leader's role as one agent keeps it, in an experiment that names a stand-in: the
role messages heard and sent, the decision of :mod:`federation.core.standin` applied.

Who takes part (:func:`role_kind`): the experiment's leader, its stand-in, and the
followers of the leader. Each publishes its :class:`~federation.core.standin.Claim`
on ``fedlab/<federation>/<lab>/<agent>/role`` every :data:`~federation.core.standin.PERIOD`
(and in its status, ``claim``) and hears every other agent's (Zenoh's thread keeps the
newest of each; the loop decides at every control step).

- The leader flies only while it holds the role (acknowledged by the stand-in, not
  deposed): otherwise the ``role`` hold (:mod:`federation.core.holds`) keeps every
  valve closed, and its status says why.
- The stand-in's platform is a :class:`~federation.runtime.agent.twin.Twin`: nothing
  exists to move until it claims. It joins the run under way as any agent does
  (:mod:`federation.runtime.agent.rejoining`, ``auto``) to know the run's time; when
  the core lets it claim, its twin starts at the leader's last shared pose and
  velocity and flies the experiment's maneuver on run time, its reference captured
  from there (:mod:`federation.core.capture`). Released (a handback), the twin is
  dropped.
- A follower follows the agent the core chooses (``owner.follow``: its poses are the
  only ones its stale-link watch counts); nobody chosen, the ``role`` hold stands.
  When it follows again, or another agent, its heading reference is captured from
  the last one it had, so it has no step.

The error bound an agent gives the core is its reference time's: zero on the
reference itself, else the one-way delay to it plus its estimate's bound, grown by
:data:`DRIFT_BOUND` for every second since the last exchange answered (the leader
lost, its clock is extrapolated).
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

import zenoh

from federation.core import keys, wire
from federation.core.capture import Capture
from federation.core.holds import Hold, Trigger
from federation.core.keys import AgentId
from federation.core.standin import PERIOD, Choice, Claim, Keeper, Kind, Terms, choose
from federation.runtime.agent.rejoining import MAX_STEP, Rejoining, limits_of
from federation.runtime.agent.twin import Twin
from schemas.experiment import load_experiment

if TYPE_CHECKING:
    from federation.runtime.agent.commands import RunControl
    from federation.runtime.agent.peers import PeerTable
    from federation.runtime.agent.services import AgentServices
    from schemas.config import AgentConfig
    from schemas.experiment import ExperimentConfig

__all__ = ["DRIFT_BOUND", "ROLE_TOPIC", "RoleKeeping", "role_kind"]

log = logging.getLogger("fedlab.agent")

ROLE_TOPIC = "role"
"""The topic of an agent's role messages."""
DRIFT_BOUND = 1e-4
"""s/s: how fast the error of a clock estimate may grow with no exchange answered."""


def role_kind(config: AgentConfig, experiment: ExperimentConfig | None) -> Kind | None:
    """This agent's part in the leader's role, or None (no stand-in named, or an agent
    the role does not concern: a follower of a follower, a member)."""
    if experiment is None or experiment.stand_in is None:
        return None
    me, leader = str(config.agent), str(experiment.leader)
    if me == leader:
        return "leader"
    if me == experiment.stand_in.agent:
        return "stand-in"
    if config.role == "follower" and config.follow == leader:
        return "follower"
    return None


class RoleKeeping:
    """The leader's role as ``owner`` keeps it (``kind`` None: it keeps none)."""

    def __init__(
        self,
        owner: AgentServices,
        peer_table: PeerTable,
        commands: RunControl,
        rejoining: Rejoining,
    ):
        self.owner = owner
        self.peer_table = peer_table
        self.commands = commands
        self.rejoining = rejoining
        cfg = owner.config
        experiment = None if cfg.experiment is None else load_experiment(cfg.experiment)
        self.kind = role_kind(cfg, experiment)
        if cfg.role == "stand-in" and self.kind != "stand-in":
            raise ValueError(f"{owner.me}: its experiment names another stand-in (stand_in.agent)")
        self.keeper: Keeper | None = None
        self.leader: AgentId | None = None
        self.stand_in: AgentId | None = None
        self.terms = Terms()
        self.limits = limits_of(cfg.platform, cfg.platform_preset)
        self._lock = threading.Lock()
        self._heard: dict[str, Claim] = {}  # the newest claim of each agent
        self._news: list[Claim] = []  # heard since the last step, in order (the keeper's)
        self.sent: Claim | None = None
        self.choice: Choice | None = None
        self._next_send = 0.0
        self._publisher: zenoh.Publisher | None = None
        self.leader_pose: wire.PoseSample | None = None  # a stand-in's: the last shared
        self.capture: Capture | None = None
        self._last_host: float | None = None
        self._last_t_sim: float | None = None  # reference time at the last step
        # Called when a follower follows another agent: its samples are on another
        # clock, so what was estimated from the last one's is forgotten.
        self.switched: Callable[[], None] = lambda: None
        if self.kind is None or experiment is None or experiment.stand_in is None:
            return
        self.leader = experiment.leader
        self.stand_in = AgentId.parse(experiment.stand_in.agent)
        self.terms = Terms(after=experiment.stand_in.after, skew=experiment.stand_in.skew)
        if self.kind != "follower":
            self.keeper = Keeper(str(owner.me), self.kind, str(self.leader), self.terms)
        if self.kind == "follower":  # the stand-in's clock is read on its every pose
            table = peer_table.explicit_sync or peer_table.close_sync
            table.add(self.stand_in)

    @property
    def active(self) -> bool:
        return self.kind is not None

    # -- Zenoh -----------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> list[object]:
        """Declare the role's publisher and subscribers; what to undeclare at close."""
        if self.kind is None:
            return []
        owner, fed = self.owner, self.owner.config.federation
        callback = _callback
        self._publisher = session.declare_publisher(owner.key(owner.me, ROLE_TOPIC))
        declared: list[object] = [
            self._publisher,
            session.declare_subscriber(keys.all_of(fed, ROLE_TOPIC), callback(self.on_role)),
        ]
        if self.kind == "stand-in":
            assert self.leader is not None
            key = owner.key(self.leader, "pose")
            declared.append(session.declare_subscriber(key, callback(self.on_leader_pose)))
        return declared

    def on_role(self, sample: zenoh.Sample) -> None:
        """Another agent's role message (Zenoh's thread: never raises). An agent speaks
        for itself only: a claim whose ``agent`` is not its key's sender is refused."""
        try:
            parsed = keys.parse_agent_key(self.owner.config.federation, str(sample.key_expr))
            if parsed is None or parsed[0] == self.owner.me:
                return
            claim = Claim.from_dict(json.loads(sample.payload.to_bytes()))
            if claim.agent != str(parsed[0]):
                raise ValueError(f"a claim for {claim.agent} sent under {parsed[0]}")
        except Exception as error:  # another agent's fault: said, not raised
            self.owner.reject("role message", f"{sample.key_expr}: {error}")
            return
        with self._lock:
            old = self._heard.get(claim.agent)
            if old is None or claim.at >= old.at or claim.epoch > old.epoch:
                self._heard[claim.agent] = claim
            self._news.append(claim)

    def on_leader_pose(self, sample: zenoh.Sample) -> None:
        """The leader's pose (a stand-in's subscriber): the last one shared is where its
        twin starts."""
        try:
            decoded = wire.decode_pose(sample.payload.to_bytes())
        except Exception as error:
            self.owner.reject("leader pose", f"{sample.key_expr}: {error}")
            return
        last = self.leader_pose
        if last is None or decoded.t > last.t:
            self.leader_pose = decoded

    # -- the loop's side -------------------------------------------------------------
    def bound(self, t_exec: float) -> float | None:
        """The error bound of this agent's reference time now (s), None if unknown."""
        owner = self.owner
        if owner.reference == owner.me:
            return 0.0
        client = self.peer_table.client_of(owner.reference)
        if client is None or client.delay is None or client.last is None:
            return None
        spread = client.estimator.bound or 0.0
        return client.delay + spread + DRIFT_BOUND * max(0.0, t_exec - client.last.t3)

    def step(self, t_exec: float, host: float, t_sim: float | None) -> None:
        """Decide at this control step: the role held or not, whom to follow; hold or
        release as decided; send the role message when due."""
        if self.kind is None:
            return
        bound = self.bound(t_exec)
        if t_sim is not None:
            last, self._last_t_sim = self._last_t_sim, t_sim
            if last is not None and t_sim < last - self.terms.skew:
                self._time_restarted(last, t_sim)
        with self._lock:
            news, self._news = self._news, []
            heard = tuple(self._heard.values())
            keeper = self.keeper
            if keeper is not None:
                for claim in news:
                    keeper.hear(claim)
                running = self.commands.run_state.mode in ("running", "frozen")
                claim = keeper.tick(t_sim, bound, running, self.leader_pose is not None)
            else:
                choice = choose(heard, t_sim, bound, self.terms)
                top = max((c.top for c in heard), default=0)
                claim = Claim(
                    str(self.owner.me), "follower", choice.epoch,
                    0.0 if t_sim is None else t_sim, False, top=top,
                    follows=choice.holder, why=choice.why,
                )  # fmt: skip
        previous, self.sent = self.sent, claim
        if self.kind == "follower":
            self._follow(choice, t_exec, host)
        elif self.kind == "leader":
            self._lead(claim, previous, t_exec, host)
        else:
            self._stand_in(claim, previous, t_exec, host)
        if previous is None or (claim.holding, claim.follows, claim.epoch) != (
            previous.holding,
            previous.follows,
            previous.epoch,
        ):
            log.info("role: %s", claim.why)
            self.owner.event("role", t_exec, host, claim.why)
            self.commands.status_now = True
        if host >= self._next_send and self._publisher is not None:
            self._next_send = host + PERIOD
            self._publisher.put(json.dumps(claim.as_dict()))

    def _time_restarted(self, last: float, now: float) -> None:
        """Reference time went back (the reference restarted): every instant heard is on
        another time base, forgotten (:meth:`~federation.core.standin.Keeper.time_restarted`)."""
        log.warning(
            "role: reference time went back from %.3f to %.3f s: claims heard forgotten", last, now
        )
        with self._lock:
            self._heard.clear()
            self._news.clear()
            if self.keeper is not None:
                self.keeper.time_restarted()

    def _hold(self, held: bool, t_exec: float, host: float, why: str) -> bool:
        """The ``role`` hold set (``held``) or lifted; True if it was just lifted."""
        safety = self.owner.safety
        if held and not safety.holds(Hold.ROLE):
            safety.apply(Trigger.ROLE_LOST)
            log.warning("role: safe hold: %s", why)
        elif not held and safety.holds(Hold.ROLE):
            safety.apply(Trigger.ROLE_HELD)
            return True
        return False

    def _follow(self, choice: Choice, t_exec: float, host: float) -> None:
        owner = self.owner
        holder = None if choice.holder is None else AgentId.parse(choice.holder)
        switched = holder is not None and holder != owner.follow
        if switched:
            log.warning("role: following %s (%s)", holder, choice.why)
            owner.follow = holder
            self.switched()
        lifted = self._hold(holder is None, t_exec, host, choice.why)
        if (lifted or switched) and holder is not None:
            # From the reference it had last, so the new holder's brings no step.
            heading, rate = owner.guidance
            self._begin_capture(heading, rate, host)

    def _lead(self, claim: Claim, previous: Claim | None, t_exec: float, host: float) -> None:
        if self._hold(not claim.holding, t_exec, host, claim.why):
            # Held, the platform drifted from the maneuver: its reference starts from it.
            pose = self.owner.pose
            self._begin_capture(pose.heading, pose.omega, host)

    def _stand_in(self, claim: Claim, previous: Claim | None, t_exec: float, host: float) -> None:
        owner = self.owner
        twin = owner.platform
        assert isinstance(twin, Twin)
        self.rejoining.capture = None  # its start is the role's capture, not the rejoin's
        was = previous is not None and previous.holding
        if claim.holding and not was:
            start = self.leader_pose
            assert start is not None  # the core claims only with a pose to start from
            twin.start_from(start.pose)
            self._begin_capture(start.pose.heading, start.pose.omega, host)
        elif was and not claim.holding:
            twin.stop()
            self.capture = None

    def _begin_capture(self, heading: float, rate: float, host: float) -> None:
        self.capture = Capture(heading, rate, self.limits)
        self._last_host = host

    def guidance(self, heading: float, rate: float, host: float) -> tuple[float, float]:
        """The heading reference to fly: the scenario's, captured after a switch."""
        capture = self.capture
        if capture is None:
            return heading, rate
        last, self._last_host = self._last_host, host
        dt = 0.0 if last is None else min(MAX_STEP, max(0.0, host - last))
        out = capture.step(heading, rate, dt)
        if capture.captured:
            log.info("role: reference captured")
            self.capture = None
        return out

    def pause(self, host: float) -> None:
        """A step not flown on the capture (the run frozen): it resumes from here."""
        if self.capture is not None:
            self._last_host = host

    def holder(self) -> str | None:
        """Who flies the pose this agent's reference comes from (recorded with it): a
        follower's holder, the leader or stand-in itself while it holds; None: nobody."""
        sent = self.sent
        if sent is None:
            return None
        if self.kind == "follower":
            return sent.follows
        return sent.agent if sent.holding else None

    # -- the operator ----------------------------------------------------------------
    def handback(self, leader: str, t_exec: float) -> str | None:
        """An operator hands the role back to ``leader`` (Zenoh's thread): why nothing
        changed here, or None."""
        keeper = self.keeper
        if keeper is None:
            return "this agent keeps no leader's role with a stand-in"
        with self._lock:
            return keeper.hand_back(leader, self.owner.sim_time(t_exec))

    def concerns(self, leader: str) -> bool:
        """Whether a handback to ``leader`` is this agent's business (its leader or its
        stand-in)."""
        return self.keeper is not None and self.leader is not None and str(self.leader) == leader

    def report(self) -> dict[str, object]:
        """The status's ``claim``."""
        sent = self.sent
        return {"claim": None if sent is None else sent.as_dict()}


def _callback(handler: Callable[[zenoh.Sample], None]) -> zenoh.handlers.Callback[zenoh.Sample]:
    return zenoh.handlers.Callback(handler, indirect=False)
