"""``fedlab report RUN_DIR``: a paper-style report of a recorded run.

A run directory holds one MCAP recording per agent (``<lab>-<name>.mcap``, see
:mod:`federation.runtime.recorder`) and, optionally, the ``run.json`` the demo writes
(roles, followed agents, latency compensation, the emulated link). The report is
``summary.json`` (every number with its unit in its key), PNG figures like the
paper's (figures 8 to 11) and ``report.md`` setting this run beside the paper.

What is measured, and how (the paper's own figures are in :data:`PAPER`):

- **Clock sync**, per client and peer: median and standard deviation of the
  per-exchange offsets (Eq. 4) and delays (Eq. 3). Agents on one host share its
  monotonic clock, and every execution clock is an exact linear function of it
  (:func:`federation.report.status.clock_line`), so the true offset at client time
  :math:`t` is

  .. math::

      \\theta(t) = c_s\\big(h_c^{-1}(t)\\big) - t

  with :math:`h_c^{-1}` the client's clock line inverted (client time to host
  time) and :math:`c_s` the server's. The filtered estimate is scored against it
  after the first ``SYNC_PHASE_S`` seconds of exchanges (median, p95 and max of
  the absolute error). Over a real path the estimate also carries half the path
  asymmetry, which no recording can reveal; the host truth cannot show it either.
- **Received-vs-sent separation**, per follower: the shift :math:`d` that best
  aligns a follower's series with the leader's sent heading on reference time,

  .. math::

      \\hat d = \\arg\\min_d \\sum_i \\big(x_i - \\psi_{sent}(\\tau_i - d)\\big)^2,

  searched on a grid (``SHIFT_MAX_S``, ``SHIFT_STEP_S``, linear interpolation,
  refined by a parabola through the best three points) over the maneuver only
  (where the leader's reference rate is non-zero). For the follower's guidance
  reference (``/reference`` on its own corrected time ``t_sim``) a compensated
  follower should give ~0; the raw received heading (``/pose/received``, mapped
  to reference time with the true offset) gives the one-way delay.
- **Follower lag**: the shift of the peak of the Pearson correlation between the
  leader's heading and the follower's heading on reference time (the paper's
  4 to 5 s came from a badly tuned PID, not the network).
- **Heading RMS error** of each platform: its true heading (``/truth``; else the
  published estimate) against its own guidance reference while running.

Everything below :func:`load_run` takes decoded messages, not files.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from federation.report.status import clock_line
from federation.runtime.recorder import read_messages
from schemas.config import ConfigError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "PAPER",
    "AgentRecording",
    "Run",
    "best_shift",
    "comparison_rows",
    "fit_clock",
    "heading_rms_deg",
    "load_run",
    "register",
    "summarize",
    "summary_table",
    "write_report",
    "xcorr_lag",
]

Array = npt.NDArray[np.float64]
Clock = tuple[float, float]  # (a, b): t_exec = a + b * host_monotonic

# Defaults, in one place.
SYNC_PHASE_S = 10.0  # s of exchanges before the estimate is scored (the paper's sync phase)
SHIFT_MAX_S = 0.5  # s, separation search range (both ways)
SHIFT_STEP_S = 0.0005  # s, separation search step
LAG_MAX_S = 10.0  # s, follower lag search range (both ways)
LAG_STEP_S = 0.005  # s, follower lag search step
ZOOM_HALF_WIDTH_S = 0.3  # s either side of the steepest point in the sent-vs-received figure
DPI = 150

# The paper's figures (NOTES.md): (low, high) in the unit of the key.
PAPER: dict[str, tuple[float, float]] = {
    "offset_std_ms": (5.0, 9.0),
    "delay_median_ms": (39.5, 40.0),
    "delay_std_ms": (5.0, 11.0),
    "separation_ms": (60.0, 100.0),
    "lag_s": (4.0, 5.0),
}


# -- loading -----------------------------------------------------------------------------
@dataclass
class AgentRecording:
    """One agent's decoded recording and what is known of its part in the run."""

    agent: str
    messages: dict[str, list[dict[str, Any]]]
    file: str = ""
    role: str | None = None
    follow: str | None = None
    platform: str | None = None
    latency_compensation: bool | None = None

    def channel(self, topic: str) -> list[dict[str, Any]]:
        return self.messages.get(topic) or []


@dataclass
class Run:
    """Every agent's recording, the demo's ``run.json`` (or None) and what was missing."""

    agents: dict[str, AgentRecording]
    meta: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)
    directory: str = ""

    @property
    def leader(self) -> str | None:
        if self.meta and isinstance(self.meta.get("leader"), str):
            return str(self.meta["leader"])
        leaders = [a for a, r in self.agents.items() if r.role == "leader"]
        return leaders[0] if leaders else None

    @property
    def emulated_delay_s(self) -> float | None:
        link = (self.meta or {}).get("link")
        if isinstance(link, dict) and link.get("delay_ms") is not None:
            return float(link["delay_ms"]) / 1e3
        return None

    @property
    def emulated_jitter_s(self) -> float | None:
        link = (self.meta or {}).get("link")
        if isinstance(link, dict) and link.get("jitter_ms") is not None:
            return float(link["jitter_ms"]) / 1e3
        return None


def agent_from_filename(path: Path) -> str:
    """``rome-pinocchio-raw.mcap`` -> ``rome/pinocchio-raw`` (lab names hold no dash)."""
    lab, _, name = path.stem.partition("-")
    return f"{lab}/{name}" if name else lab


def _read(path: Path) -> tuple[dict[str, list[dict[str, Any]]] | None, str | None]:
    """A recording's messages; from a damaged file (agent killed, or its summary broken),
    every message up to the damage."""
    try:
        return read_messages(path), None
    except Exception as error:  # mcap raises many kinds on a truncated or foreign file
        from mcap.records import Channel, Message
        from mcap.stream_reader import StreamReader

        topics: dict[int, str] = {}
        stamped: dict[str, list[tuple[int, bytes]]] = {}
        try:
            with path.open("rb") as f:
                for record in StreamReader(f).records:
                    if isinstance(record, Channel):
                        topics[record.id] = record.topic
                    elif isinstance(record, Message) and record.channel_id in topics:
                        topic = topics[record.channel_id]
                        stamped.setdefault(topic, []).append((record.log_time, record.data))
        except Exception:  # the damaged part: keep what came before it
            pass
        partial: dict[str, list[dict[str, Any]]] = {}
        try:
            for topic, items in stamped.items():
                items.sort(key=lambda item: item[0])
                partial[topic] = [json.loads(data) for _, data in items]
        except ValueError:
            partial = {}
        count = sum(len(v) for v in partial.values())
        if not count:
            return None, f"{path.name}: unreadable ({type(error).__name__}: {error}); skipped"
        return partial, f"{path.name}: damaged or unfinished recording; {count} messages recovered"


def load_run(run_dir: str | Path) -> Run:
    """Read every ``*.mcap`` of ``run_dir`` and its optional ``run.json``.

    Raises :class:`ConfigError` when the directory is missing or holds no readable
    recording.
    """
    directory = Path(run_dir)
    if not directory.is_dir():
        raise ConfigError(f"{directory}: no such run directory")
    files = sorted(directory.glob("*.mcap"))
    if not files:
        raise ConfigError(f"{directory}: no MCAP recordings (*.mcap) in this run directory")
    notes: list[str] = []
    meta: dict[str, Any] | None = None
    run_json = directory / "run.json"
    if run_json.exists():
        try:
            loaded = json.loads(run_json.read_text(encoding="utf-8"))
            meta = loaded if isinstance(loaded, dict) else None
            if meta is None:
                notes.append("run.json is not a JSON object; ignored")
        except (OSError, json.JSONDecodeError) as error:
            notes.append(f"run.json unreadable ({error}); ignored")
    else:
        notes.append("no run.json: roles from the recordings, no emulated link to compare with")
    agents: dict[str, AgentRecording] = {}
    for path in files:
        messages, note = _read(path)
        if note:
            notes.append(note)
        if messages is None:
            continue
        status = messages.get("/status") or []
        agent = str(status[0].get("agent")) if status else agent_from_filename(path)
        if agent in agents:
            notes.append(f"{path.name}: a second recording of {agent}; skipped")
            continue
        agents[agent] = _describe(agent, messages, path.name, meta)
    if not agents:
        raise ConfigError(f"{directory}: no readable MCAP recording ({len(files)} files tried)")
    run = Run(agents, meta, notes, str(directory))
    for agent in (meta or {}).get("agents") or {}:
        if agent not in agents:
            notes.append(f"{agent} is in run.json but has no recording")
    return run


def _describe(
    agent: str, messages: dict[str, list[dict[str, Any]]], file: str, meta: dict[str, Any] | None
) -> AgentRecording:
    """Role and followed agent from run.json, else from the recorded status."""
    rec = AgentRecording(agent, messages, file)
    status = messages.get("/status") or []
    last = status[-1] if status else {}
    info = ((meta or {}).get("agents") or {}).get(agent) or {}
    rec.role = info.get("role") or last.get("role")
    rec.follow = info.get("follow") or last.get("follow")
    rec.platform = info.get("platform") or last.get("platform")
    comp = info.get("latency_compensation")
    rec.latency_compensation = None if comp is None else bool(comp)
    received = [str(m.get("agent")) for m in messages.get("/pose/received") or []]
    if received and rec.role in (None, "follower") and rec.follow is None:
        # Whose poses it received most: the agent it followed.
        rec.role, rec.follow = "follower", max(set(received), key=received.count)
    return rec


# -- clocks --------------------------------------------------------------------------------
def fit_clock(messages: dict[str, list[dict[str, Any]]]) -> Clock | None:
    """An agent's clock line from its recorded /status (else any channel stamped with both
    ``t_exec`` and ``host_monotonic``); None if nothing fits."""
    for topic in ("/status", "/pose/sent", "/reference", "/truth"):
        lines = [
            m
            for m in messages.get(topic) or []
            if m.get("t_exec") is not None and m.get("host_monotonic") is not None
        ]
        if len(lines) >= 2 and lines[0]["host_monotonic"] != lines[-1]["host_monotonic"]:
            return clock_line(lines)
    return None


def clock_map(source: Clock, target: Clock) -> Callable[[Array], Array]:
    """Source clock time -> target clock time at the same host instant."""
    a_s, b_s = source
    a_t, b_t = target
    return lambda t: a_t + b_t * (np.asarray(t, dtype=float) - a_s) / b_s


def _estimated_map(reference: list[dict[str, Any]]) -> Callable[[Array], Array] | None:
    """Own clock -> reference clock as the agent itself estimated it (``/reference`` t_sim)."""
    pairs = [(m["t_exec"], m["t_sim"]) for m in reference if m.get("t_sim") is not None]
    if not pairs:
        return None
    te, ts = np.array(pairs, dtype=float).T
    order = np.argsort(te)
    te, offset = te[order], (ts - te)[order]
    return lambda t: np.asarray(t, dtype=float) + np.interp(t, te, offset)


# -- numerical pieces ----------------------------------------------------------------------
def _series(t: Any, x: Any) -> tuple[Array, Array]:
    """Finite samples, sorted by time."""
    t_a, x_a = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    keep = np.isfinite(t_a) & np.isfinite(x_a)
    t_a, x_a = t_a[keep], x_a[keep]
    order = np.argsort(t_a, kind="stable")
    return t_a[order], x_a[order]


def _refine(values: Array, k: int, step: float, maximum: bool) -> float:
    """Sub-step position of an extremum from the parabola through it and its neighbours."""
    if 0 < k < len(values) - 1:
        lo, mid, hi = values[k - 1], values[k], values[k + 1]
        curvature = lo - 2.0 * mid + hi
        if (curvature < 0) if maximum else (curvature > 0):
            return float(k + 0.5 * (lo - hi) / curvature) * step
    return float(k) * step


def best_shift(
    t: Any,
    x: Any,
    t_ref: Any,
    x_ref: Any,
    window: tuple[float, float] | None = None,
    max_shift: float = SHIFT_MAX_S,
    step: float = SHIFT_STEP_S,
) -> float | None:
    """How far ``x(t)`` trails ``x_ref(t_ref)`` (s, positive: later), by least squares.

    Tests shifts ``d`` from ``-max_shift`` to ``max_shift`` and keeps the one that
    minimises the mean of :math:`(x_i - x_{ref}(t_i - d))^2` over the samples with
    ``t_i`` in ``window``; the reference is linearly interpolated. None when fewer
    than three samples fall in the window or the best shift is at the edge of the
    range (the true one may lie beyond it).
    """
    t_a, x_a = _series(t, x)
    tr, xr = _series(t_ref, x_ref)
    if len(tr) < 2:
        return None
    keep = (t_a >= tr[0]) & (t_a <= tr[-1])
    if window is not None:
        keep &= (t_a >= window[0]) & (t_a <= window[1])
    t_a, x_a = t_a[keep], x_a[keep]
    if len(t_a) < 3:
        return None
    n = round(max_shift / step)
    shifts = np.arange(-n, n + 1) * step
    cost = np.array([np.mean((x_a - np.interp(t_a - d, tr, xr)) ** 2) for d in shifts])
    k = int(np.argmin(cost))
    if k in (0, len(shifts) - 1):
        return None
    return float(shifts[0] + _refine(cost, k, step, maximum=False))


def xcorr_lag(
    t: Any,
    x: Any,
    t_ref: Any,
    x_ref: Any,
    max_lag: float = LAG_MAX_S,
    step: float = LAG_STEP_S,
) -> float | None:
    """The shift ``d`` (s) maximising the Pearson correlation of ``x(t_i)`` with
    ``x_ref(t_i - d)``: how far ``x`` lags ``x_ref``.

    The search range is capped at half the span both series cover. None when a
    series does not move, or the peak is at the edge of the range.
    """
    t_a, x_a = _series(t, x)
    tr, xr = _series(t_ref, x_ref)
    if len(tr) < 2 or len(t_a) < 3:
        return None
    keep = (t_a >= tr[0]) & (t_a <= tr[-1])
    t_a, x_a = t_a[keep], x_a[keep]
    if len(t_a) < 3 or np.std(x_a) == 0:
        return None
    max_lag = min(max_lag, 0.5 * (t_a[-1] - t_a[0]))
    n = int(max_lag / step)
    if n < 2:
        return None
    shifts = np.arange(-n, n + 1) * step
    xc = x_a - x_a.mean()
    norm_x = math.sqrt(float(np.sum(xc**2)))
    corr = np.full(len(shifts), np.nan)
    for i, d in enumerate(shifts):
        y = np.interp(t_a - d, tr, xr)
        yc = y - y.mean()
        norm_y = math.sqrt(float(np.sum(yc**2)))
        if norm_y > 0:
            corr[i] = float(np.sum(xc * yc)) / (norm_x * norm_y)
    if np.all(np.isnan(corr)):
        return None
    k = int(np.nanargmax(corr))
    if k in (0, len(shifts) - 1) or np.isnan(corr[k - 1]) or np.isnan(corr[k + 1]):
        return None
    return float(shifts[0] + _refine(corr, k, step, maximum=True))


def _wrap(angle: Array) -> Array:
    return np.asarray((angle + np.pi) % (2.0 * np.pi) - np.pi, dtype=float)


def heading_rms_deg(
    heading: Sequence[dict[str, Any]], reference: Sequence[dict[str, Any]]
) -> float | None:
    """RMS of heading minus guidance reference (deg), at the reference's stamps while running.

    ``heading``: messages with ``t_exec`` and ``heading`` (``/truth`` or ``/pose/sent``);
    ``reference``: ``/reference`` messages (``t_exec``, ``heading_ref``, ``mode``).
    """
    t_h, h = _series([m["t_exec"] for m in heading], [m["heading"] for m in heading])
    running = [m for m in reference if m.get("mode") in (None, "running")]
    t_r, r = _series([m["t_exec"] for m in running], [m["heading_ref"] for m in running])
    if len(t_h) < 2 or not len(t_r):
        return None
    inside = (t_r >= t_h[0]) & (t_r <= t_h[-1])
    if not inside.any():
        return None
    error = _wrap(np.interp(t_r[inside], t_h, np.unwrap(h)) - r[inside])
    return math.degrees(math.sqrt(float(np.mean(error**2))))


# -- analysis ------------------------------------------------------------------------------
@dataclass
class SyncPair:
    """One client's exchanges with one peer; times on the client's clock."""

    client: str
    peer: str
    t3: Array
    offset: Array
    delay: Array
    estimate: Array  # NaN where the client had no estimate yet
    truth: Array | None  # true offset at each t3, if both clocks are known
    rejected: int | None


@dataclass
class Follow:
    """A follower and the agent it follows; every time on the followed agent's clock."""

    follower: str
    leader: str
    compensation: bool | None
    sent: tuple[Array, Array]  # leader's published heading (rad)
    leader_heading: tuple[Array, Array]  # leader's true heading (else published)
    leader_reference: tuple[Array, Array] | None  # leader's guidance reference
    received: tuple[Array, Array] | None  # heading as received, at reception
    received_time: str  # how reception times were mapped: "truth" or "estimate"
    reference: tuple[Array, Array] | None  # follower's guidance reference on its t_sim
    heading: tuple[Array, Array] | None  # follower's true heading (else published)
    window: tuple[float, float] | None  # the maneuver (leader's reference rate non-zero)
    start: float  # reference time the run started (for plots)
    pose_received: int
    pose_age: Array  # reception (true reference time) minus send time, s


def _col(messages: Sequence[dict[str, Any]], key: str) -> Array:
    return np.array([np.nan if m.get(key) is None else m[key] for m in messages], dtype=float)


def _heading_source(rec: AgentRecording) -> tuple[list[dict[str, Any]], str]:
    truth = rec.channel("/truth")
    return (truth, "truth") if truth else (rec.channel("/pose/sent"), "estimate")


def sync_pairs(run: Run) -> list[SyncPair]:
    clocks = {a: fit_clock(r.messages) for a, r in run.agents.items()}
    pairs = []
    for client, rec in run.agents.items():
        by_peer: dict[str, list[dict[str, Any]]] = {}
        for m in rec.channel("/sync/exchange"):
            by_peer.setdefault(str(m.get("peer")), []).append(m)
        status = rec.channel("/status")
        peers_status = (status[-1].get("peers") or {}) if status else {}
        for peer, exchanges in sorted(by_peer.items()):
            exchanges = sorted(exchanges, key=lambda m: float(m["t3"]))
            t3 = _col(exchanges, "t3")
            truth = None
            c_clock, s_clock = clocks.get(client), clocks.get(peer)
            if c_clock is not None and s_clock is not None:
                truth = clock_map(c_clock, s_clock)(t3) - t3
            rejected = (peers_status.get(peer) or {}).get("rejected")
            pairs.append(
                SyncPair(
                    client,
                    peer,
                    t3,
                    _col(exchanges, "offset"),
                    _col(exchanges, "delay"),
                    _col(exchanges, "estimate"),
                    truth,
                    None if rejected is None else int(rejected),
                )
            )
    return pairs


def sync_summary(
    pair: SyncPair, emulated_delay_s: float | None = None, sync_phase: float = SYNC_PHASE_S
) -> dict[str, Any]:
    """Offset, delay and estimate-error statistics of one client/peer pair (s)."""
    out: dict[str, Any] = {
        "client": pair.client,
        "peer": pair.peer,
        "exchanges_count": len(pair.t3),
        "rejected_count": pair.rejected,
    }
    if not len(pair.t3):
        return out
    delay_median = float(np.nanmedian(pair.delay))
    out |= {
        "offset_median_s": float(np.nanmedian(pair.offset)),
        "offset_std_s": float(np.nanstd(pair.offset)),
        "delay_median_s": delay_median,
        "delay_std_s": float(np.nanstd(pair.delay)),
        "delay_max_deviation_s": float(np.nanmax(np.abs(pair.delay - delay_median))),
        "emulated_delay_s": emulated_delay_s,
        "delay_median_minus_emulated_s": (
            None if emulated_delay_s is None else delay_median - emulated_delay_s
        ),
    }
    if pair.truth is not None:
        out["true_offset_median_s"] = float(np.median(pair.truth))
        late = (pair.t3 - pair.t3[0] >= sync_phase) & np.isfinite(pair.estimate)
        error = np.abs(pair.estimate[late] - pair.truth[late])
        out["estimate_error_samples_count"] = int(error.size)
        if error.size:
            out |= {
                "estimate_error_median_abs_s": float(np.median(error)),
                "estimate_error_p95_abs_s": float(np.percentile(error, 95)),
                "estimate_error_max_abs_s": float(error.max()),
                "offset_median_error_s": out["offset_median_s"] - out["true_offset_median_s"],
            }
    return out


def _maneuver(reference: list[dict[str, Any]]) -> tuple[float, float] | None:
    """Reference-time span where the leader's reference rate is non-zero."""
    moving = [
        m["t_sim"] if m.get("t_sim") is not None else m["t_exec"]
        for m in reference
        if m.get("rate_ref") and abs(float(m["rate_ref"])) > 1e-12
    ]
    return (float(min(moving)), float(max(moving))) if moving else None


def _run_start(reference: list[dict[str, Any]], control: list[dict[str, Any]]) -> float | None:
    """Reference time at which run time is zero: from /reference (t_sim - run_time), else
    the start instant of the control events."""
    origins = [
        float(m["t_sim"]) - float(m["run_time"])
        for m in reference
        if m.get("t_sim") is not None and m.get("run_time") is not None
    ]
    if origins:
        return float(np.median(origins))
    for m in control:
        if m.get("event") == "started":
            at = m.get("at") if m.get("at") is not None else m.get("t_sim")
            if at is not None:
                return float(at)
    return None


def follows(run: Run) -> list[Follow]:
    """Every follower whose followed agent was recorded too (others get a note)."""
    clocks = {a: fit_clock(r.messages) for a, r in run.agents.items()}
    out = []
    for name, rec in run.agents.items():
        if rec.role != "follower":
            continue
        leader_name = rec.follow or run.leader
        if leader_name is None or leader_name not in run.agents:
            run.notes.append(
                f"{name} follows {leader_name or 'an unknown agent'}, which has no recording: "
                "no separation or lag for it"
            )
            continue
        lead = run.agents[leader_name]
        sent = lead.channel("/pose/sent")
        if len(sent) < 2:
            run.notes.append(f"{leader_name} recorded no /pose/sent: nothing to compare {name} to")
            continue
        # Follower clock -> leader (reference) clock: the truth if both clocks are known.
        f_clock, l_clock = clocks.get(name), clocks.get(leader_name)
        to_ref = clock_map(f_clock, l_clock) if f_clock and l_clock else None
        source = "truth"
        if to_ref is None:
            to_ref = _estimated_map(rec.channel("/reference"))
            source = "estimate"
            run.notes.append(
                f"{name}: no clock truth (needs both agents' recordings); reception mapped to "
                "reference time with the follower's own offset estimate"
            )
        received_msgs = [m for m in rec.channel("/pose/received") if m.get("agent") == leader_name]
        received = None
        age = np.array([])
        if received_msgs and to_ref is not None:
            t_recv = to_ref(_col(received_msgs, "t_recv"))
            received = _series(t_recv, _col(received_msgs, "heading"))
            age = t_recv - _col(received_msgs, "t")
        ref_msgs = [m for m in rec.channel("/reference") if m.get("t_sim") is not None]
        reference = (
            _series(_col(ref_msgs, "t_sim"), _col(ref_msgs, "heading_ref")) if ref_msgs else None
        )
        own, _ = _heading_source(rec)
        heading = None
        if own and to_ref is not None:
            heading = _series(to_ref(_col(own, "t_exec")), _col(own, "heading"))
        lead_own, _ = _heading_source(lead)
        lead_ref = lead.channel("/reference")
        leader_reference = (
            _series(
                [m["t_sim"] if m.get("t_sim") is not None else m["t_exec"] for m in lead_ref],
                _col(lead_ref, "heading_ref"),
            )
            if lead_ref
            else None
        )
        window = _maneuver(lead_ref)
        if window is None:
            run.notes.append(
                f"{leader_name}: no maneuver in its /reference (rate never non-zero); "
                "separations over the whole run"
            )
        sent_series = _series(_col(sent, "t_exec"), _col(sent, "heading"))
        start = _run_start(lead_ref, lead.channel("/control"))
        out.append(
            Follow(
                follower=name,
                leader=leader_name,
                compensation=rec.latency_compensation,
                sent=sent_series,
                leader_heading=_series(_col(lead_own, "t_exec"), _col(lead_own, "heading")),
                leader_reference=leader_reference,
                received=received,
                received_time=source,
                reference=reference,
                heading=heading,
                window=window,
                start=float(sent_series[0][0]) if start is None else start,
                pose_received=len(received_msgs),
                pose_age=age,
            )
        )
    return out


def follow_summary(f: Follow) -> dict[str, Any]:
    """Separations (s) and lag (s) of one follower."""
    sent_t, sent_h = f.sent[0], np.unwrap(f.sent[1])

    def shift(series: tuple[Array, Array] | None) -> float | None:
        if series is None:
            return None
        return best_shift(series[0], np.unwrap(series[1]), sent_t, sent_h, f.window)

    lag = None
    if f.heading is not None:  # while running: before the start, headings are not commanded
        (t, h), (t_l, h_l) = f.heading, f.leader_heading
        mine, theirs = t >= f.start, t_l >= f.start
        lag = xcorr_lag(t[mine], np.unwrap(h[mine]), t_l[theirs], np.unwrap(h_l[theirs]))
    return {
        "follower": f.follower,
        "leader": f.leader,
        "latency_compensation": f.compensation,
        "reference_separation_s": shift(f.reference),
        "received_separation_s": shift(f.received),
        "received_time_source": f.received_time,
        "pose_age_median_s": float(np.median(f.pose_age)) if f.pose_age.size else None,
        "lag_s": lag,
        "maneuver_s": None if f.window is None else [f.window[0] - f.start, f.window[1] - f.start],
        "pose_received_count": f.pose_received,
    }


def summarize(run: Run, sync_phase: float = SYNC_PHASE_S) -> dict[str, Any]:
    """Everything ``summary.json`` holds; seconds, degrees and counts named in the keys."""
    run = Run(run.agents, run.meta, list(run.notes), run.directory)  # notes: the caller's stay
    pairs = sync_pairs(run)
    follow_list = follows(run)
    followers = [follow_summary(f) for f in follow_list]
    for f in followers:
        for key, what in (
            ("reference_separation_s", f"separation within ±{SHIFT_MAX_S} s"),
            ("received_separation_s", f"received heading's separation within ±{SHIFT_MAX_S} s"),
            ("lag_s", "lag (no motion, or beyond the search range)"),
        ):
            if f[key] is None:
                run.notes.append(f"{f['follower']}: no {what}")
    agents: dict[str, Any] = {}
    for name, rec in run.agents.items():
        heading, source = _heading_source(rec)
        rms = heading_rms_deg(heading, rec.channel("/reference"))
        if rms is None:
            run.notes.append(f"{name}: no heading and running reference to compare")
        agents[name] = {
            "recording": rec.file,
            "role": rec.role,
            "platform": rec.platform,
            "follow": rec.follow,
            "latency_compensation": rec.latency_compensation,
            "heading_rms_error_deg": rms,
            "heading_source": source,
            "pose_received_count": len(rec.channel("/pose/received")),
            "messages_count": {k: len(v) for k, v in rec.messages.items() if v},
        }
    for pair in pairs:
        if pair.truth is None:
            run.notes.append(
                f"{pair.client} -> {pair.peer}: no clock truth (needs both agents' recordings)"
            )
    if not pairs:
        run.notes.append("no /sync/exchange recorded by any agent")
    meta = run.meta or {}
    return {
        "run_dir": run.directory,
        "leader": run.leader,
        "duration_s": meta.get("duration_s"),
        "command": meta.get("command"),
        "link": {
            "emulated_delay_s": run.emulated_delay_s,
            "emulated_jitter_s": run.emulated_jitter_s,
        },
        "sync_phase_s": sync_phase,
        "agents": agents,
        "sync": [sync_summary(p, run.emulated_delay_s, sync_phase) for p in pairs],
        "followers": followers,
        "paper": {f"{k}_range": list(v) for k, v in PAPER.items()},
        "notes": list(dict.fromkeys(run.notes)),
    }


# -- the table beside the paper ------------------------------------------------------------
def _fmt(value: float | None, scale: float = 1.0, digits: int = 1) -> str:
    return "n/a" if value is None else f"{value * scale:.{digits}f}"


def _paper(key: str) -> str:
    lo, hi = PAPER[key]
    return f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}"


def _compensation(value: bool | None) -> str:
    return {True: "compensated", False: "raw", None: "compensation unknown"}[value]


def comparison_rows(summary: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """(figure, pair or agent, this run, the paper) for the report and the terminal."""
    sync = [(f"{s['client']} → {s['peer']}", s) for s in summary["sync"]]
    followers = [
        (f"{f['follower']} ({_compensation(f['latency_compensation'])})", f)
        for f in summary["followers"]
    ]
    agents = list(summary["agents"].items())
    emulated = [(w, s) for w, s in sync if s.get("emulated_delay_s") is not None]
    rows: list[tuple[str, str, str, str]] = []

    def add(
        label: str,
        entries: list[tuple[str, dict[str, Any]]],
        key: str,
        scale: float,
        digits: int,
        paper: str,
    ) -> None:
        rows.extend((label, who, _fmt(e.get(key), scale, digits), paper) for who, e in entries)

    add("offset median (s)", sync, "offset_median_s", 1, 4, "±26.420")
    add("offset std (ms)", sync, "offset_std_s", 1e3, 2, _paper("offset_std_ms"))
    errors = ("estimate_error_median_abs_s", "estimate_error_p95_abs_s", "estimate_error_max_abs_s")
    rows.extend(
        (
            "estimate |error| vs truth, p50/p95/max (ms)",
            who,
            "/".join(_fmt(s.get(k), 1e3, 3) for k in errors),
            "no truth",
        )
        for who, s in sync
    )
    add("delay median (ms)", sync, "delay_median_s", 1e3, 2, _paper("delay_median_ms"))
    add("delay median − emulated (ms)", emulated, "delay_median_minus_emulated_s", 1e3, 2, "n/a")
    add("delay std (ms)", sync, "delay_std_s", 1e3, 2, _paper("delay_std_ms"))
    separation = _paper("separation_ms")
    label = "received-vs-sent separation, {} (ms)"
    add(label.format("received heading"), followers, "received_separation_s", 1e3, 1, separation)
    add(
        label.format("follower's reference"),
        followers,
        "reference_separation_s",
        1e3,
        1,
        separation,
    )
    add("follower lag (s)", followers, "lag_s", 1, 2, _paper("lag_s"))
    add("heading RMS error (deg)", agents, "heading_rms_error_deg", 1, 3, "n/a")
    return rows


# -- figures ---------------------------------------------------------------------------------
def _figure(rows: int = 1, height: float = 5.0) -> tuple[Figure, list[Axes]]:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, height), dpi=DPI, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    for ax in axes:
        ax.grid(True, alpha=0.35)
    return fig, list(axes)


def _slug(agent: str) -> str:
    return agent.replace("/", "-")


def plot_sync(
    pair: SyncPair, path: Path, emulated_delay_s: float | None, sync_phase: float
) -> None:
    """Offset and delay of every exchange (the paper's figures 8, 9 and 11)."""
    fig, (ax_o, ax_d) = _figure(2, 7.0)
    t = pair.t3 - pair.t3[0]
    base = round(float(np.nanmedian(pair.offset if pair.truth is None else pair.truth)), 3)
    ax_o.axvspan(0, min(sync_phase, float(t[-1])), color="0.92", label=f"first {sync_phase:g} s")
    ax_o.plot(
        t,
        (pair.offset - base) * 1e3,
        ".",
        ms=3,
        alpha=0.55,
        color="tab:blue",
        label=f"per exchange, Eq. 4 (std {np.nanstd(pair.offset) * 1e3:.2f} ms)",
    )
    ax_o.plot(
        t, (pair.estimate - base) * 1e3, "-", lw=1.8, color="tab:orange", label="filtered estimate"
    )
    if pair.truth is not None:
        ax_o.plot(
            t,
            (pair.truth - base) * 1e3,
            "--",
            lw=1.4,
            color="black",
            label="truth (shared host clock)",
        )
    _robust_ylim(ax_o, (pair.offset - base) * 1e3, "exchanges")
    ax_o.set_ylabel(f"offset {'−' if base >= 0 else '+'} {abs(base):.3f} s (ms)")
    ax_o.set_title(
        f"Clock offset ({pair.peer} minus {pair.client}) and one-way delay, {len(t)} exchanges",
        fontsize=11,
    )
    ax_o.legend(loc="upper right", fontsize=8, framealpha=0.9)
    median = float(np.nanmedian(pair.delay))
    ax_d.plot(
        t,
        pair.delay * 1e3,
        ".",
        ms=3,
        alpha=0.55,
        color="tab:green",
        label=f"per exchange, Eq. 3 (std {np.nanstd(pair.delay) * 1e3:.2f} ms)",
    )
    ax_d.axhline(median * 1e3, color="tab:green", lw=1.5, label=f"median {median * 1e3:.2f} ms")
    if emulated_delay_s is not None:
        ax_d.axhline(
            emulated_delay_s * 1e3,
            color="black",
            ls="--",
            lw=1.2,
            label=f"emulated {emulated_delay_s * 1e3:.1f} ms",
        )
    _robust_ylim(ax_d, pair.delay * 1e3, "exchanges")
    ax_d.set_ylabel("one-way delay (ms)")
    ax_d.set_xlabel(f"time since the first exchange, {pair.client}'s clock (s)")
    ax_d.legend(loc="upper right", fontsize=8, framealpha=0.9)
    fig.savefig(path, dpi=DPI)


def _robust_ylim(ax: Any, values: Array, what: str) -> None:
    """Scale to the bulk (0.5th to 99.5th percentile) so one outlier does not flatten the
    plot; say how many points fall outside."""
    finite = values[np.isfinite(values)]
    if finite.size < 20:
        return
    lo, hi = np.percentile(finite, [0.5, 99.5])
    pad = max(0.25 * float(hi - lo), 0.5)
    lo, hi = float(lo) - pad, float(hi) + pad
    outside = int(np.sum((finite < lo) | (finite > hi)))
    ax.set_ylim(lo, hi)
    if outside:
        ax.text(
            0.01, 0.02, f"{outside} {what} outside the axis", transform=ax.transAxes, fontsize=8,
            color="0.4",
        )  # fmt: skip


_COLORS = ["tab:blue", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:olive"]


def plot_heading(follow_list: list[Follow], summaries: list[dict[str, Any]], path: Path) -> None:
    """Leader reference and heading with each follower's heading (the paper's figure 10)."""
    fig, (ax,) = _figure(1, 5.5)
    first = follow_list[0]
    t0 = first.start
    if first.leader_reference is not None:
        t, h = first.leader_reference
        ax.plot(
            t - t0,
            np.degrees(np.unwrap(h)),
            "--",
            color="0.45",
            lw=1.5,
            label=f"{first.leader} reference",
        )
    t, h = first.leader_heading
    ax.plot(
        t - t0, np.degrees(np.unwrap(h)), color="black", lw=1.6, label=f"{first.leader} heading"
    )
    for i, (f, s) in enumerate(zip(follow_list, summaries, strict=True)):
        if f.heading is None:
            continue
        ax.plot(
            f.heading[0] - t0,
            np.degrees(np.unwrap(f.heading[1])),
            color=_COLORS[i % 6],
            lw=1.4,
            label=f"{f.follower} heading, {_compensation(f.compensation)} "
            f"(lag {_fmt(s['lag_s'], 1, 2)} s)",
        )
    ax.set_xlabel(f"reference time since the run started, {first.leader}'s clock (s)")
    ax.set_ylabel("heading (deg)")
    ax.set_title("Leader and follower heading on corrected (reference) time", fontsize=11)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    fig.savefig(path, dpi=DPI)


def _steepest(f: Follow) -> float:
    """Reference time of the leader's fastest turn (its reference, else its sent heading)."""
    t, h = f.leader_reference if f.leader_reference is not None else f.sent
    if f.window is not None:
        keep = (t >= f.window[0]) & (t <= f.window[1])
        t, h = t[keep], h[keep]
    if len(t) < 3:
        return float(f.sent[0][len(f.sent[0]) // 2])
    rate = np.gradient(np.unwrap(h), t)
    return float(t[int(np.nanargmax(np.abs(rate)))])


def plot_sent_received(
    follow_list: list[Follow], summaries: list[dict[str, Any]], path: Path
) -> None:
    """Sent heading, heading as received, and each follower's guidance reference, zoomed on
    the leader's fastest turn, all on reference time.

    Samples joined by straight lines: the separation is measured with linear
    interpolation, so a series that trails by ``d`` is the sent line moved right by ``d``.
    """
    fig, (ax,) = _figure(1, 6.0)
    first = follow_list[0]
    centre = _steepest(first)
    lo, hi = centre - ZOOM_HALF_WIDTH_S, centre + ZOOM_HALF_WIDTH_S
    t0 = first.start
    shown: list[Array] = []

    def zoom(series: tuple[Array, Array]) -> tuple[Array, Array]:
        t, h = series
        keep = (t >= lo - 0.1) & (t <= hi + 0.1)  # one sample past each edge
        degrees = np.degrees(np.unwrap(h))
        shown.append(degrees[(t >= lo) & (t <= hi)])
        return t[keep] - t0, degrees[keep]

    t, h = zoom(first.sent)
    ax.plot(t, h, color="black", lw=3.0, marker="o", ms=5, label=f"sent by {first.leader}")
    for i, (f, s) in enumerate(zip(follow_list, summaries, strict=True)):
        color = _COLORS[i % 6]
        if f.received is not None:
            t, h = zoom(f.received)
            after = _fmt(s["received_separation_s"], 1e3, 1)
            ax.plot(
                t,
                h,
                color=color,
                lw=1.0,
                ls=":",
                marker="x",
                ms=6,
                label=f"received at {f.follower} ({after} ms after sent)",
            )
        if f.reference is not None:
            t, h = zoom(f.reference)
            after = _fmt(s["reference_separation_s"], 1e3, 1)
            ax.plot(
                t,
                h,
                color=color,
                lw=1.6,
                marker="s",
                ms=3.5,
                label=f"{f.follower} reference, {_compensation(f.compensation)} "
                f"({after} ms after sent)",
            )
    ax.set_xlim(lo - t0, hi - t0)
    visible = np.concatenate(shown) if shown else np.array([])
    if visible.size:
        pad = 0.05 * max(float(np.ptp(visible)), 1e-3)
        ax.set_ylim(float(visible.min()) - pad, float(visible.max()) + pad)
    ax.set_xlabel(f"reference time since the run started, {first.leader}'s clock (s)")
    ax.set_ylabel("heading (deg)")
    ax.set_title(
        "Sent vs received heading at the leader's fastest turn\n"
        "(in brackets: least-squares time shift from the sent heading over the whole maneuver)",
        fontsize=10,
    )
    # Below the axes: the curves cross the zoom diagonally, any corner may hold data.
    fig.legend(loc="outside lower center", ncols=2, fontsize=8)
    fig.savefig(path, dpi=DPI)


# -- report ----------------------------------------------------------------------------------
def write_report(
    run: Run | str | Path, out: str | Path | None = None, sync_phase: float = SYNC_PHASE_S
) -> dict[str, Any]:
    """Write summary.json, the figures and report.md into ``out`` (default: the run
    directory); return the summary, whose ``files`` name what was written (in ``out``)."""
    if not isinstance(run, Run):
        run = load_run(run)
    out = Path(out if out is not None else run.directory)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(run, sync_phase)
    figures: dict[str, Path] = {}
    for pair, s in zip(sync_pairs(run), summary["sync"], strict=True):
        if len(pair.t3):
            path = out / f"sync_{_slug(pair.client)}_{_slug(pair.peer)}.png"
            plot_sync(pair, path, s.get("emulated_delay_s"), sync_phase)
            figures[f"sync {pair.client} {pair.peer}"] = path
    follow_list = follows(Run(run.agents, run.meta, [], run.directory))
    if follow_list:
        leader = follow_list[0].leader
        pairs = zip(follow_list, summary["followers"], strict=True)
        chosen = [(f, s) for f, s in pairs if f.leader == leader]
        fs, ss = [f for f, _ in chosen], [s for _, s in chosen]
        figures["heading"] = out / "heading.png"
        plot_heading(fs, ss, figures["heading"])
        figures["sent_vs_received"] = out / "sent_vs_received.png"
        plot_sent_received(fs, ss, figures["sent_vs_received"])
        if len(chosen) < len(follow_list):
            summary["notes"].append(f"heading figures show only the followers of {leader}")
    else:
        summary["notes"].append("no follower with a recorded leader: no heading figures")
    summary["figures"] = {k: p.name for k, p in figures.items()}
    summary["files"] = ["summary.json", "report.md", *(p.name for p in figures.values())]
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    (out / "report.md").write_text(markdown(summary, run.meta), encoding="utf-8")
    return summary


def _emulated(summary: dict[str, Any], meta: dict[str, Any] | None) -> str:
    if meta is None:
        return "Unknown: the run directory has no run.json."
    link = meta.get("link")
    if not link:
        return "No network emulation: the agents talked over loopback."
    delay, jitter = link.get("delay_ms"), link.get("jitter_ms")
    extra = {k: v for k, v in link.items() if k not in ("delay_ms", "jitter_ms")}
    text = f"A link with {delay} ms one-way delay"
    text += f" and {jitter} ms jitter" if jitter is not None else ""
    if extra:
        text += " (" + ", ".join(f"{k} {v}" for k, v in extra.items()) + ")"
    return text + " between the labs' routers."


def markdown(summary: dict[str, Any], meta: dict[str, Any] | None) -> str:
    """report.md: the run, the table beside the paper, the figures and the notes."""
    run_name = Path(summary["run_dir"]).name or summary["run_dir"]
    lines = [f"# fedlab run report: {run_name}", ""]
    if summary.get("command"):
        lines += [f"Command: `{summary['command']}`", ""]
    if summary.get("duration_s") is not None:
        lines += [f"Duration: {summary['duration_s']} s.", ""]
    lines += ["## What was emulated", "", _emulated(summary, meta), ""]
    info = (meta or {}).get("agents") or {}
    lines += [
        "| agent | role | platform | follows | latency compensation | clock offset (s) "
        "| clock drift (ppm) | recording |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, a in summary["agents"].items():
        i = info.get(name) or {}
        comp = a["latency_compensation"]
        lines.append(
            f"| {name} | {a['role'] or '?'} | {a['platform'] or '?'} | {a['follow'] or '-'} "
            f"| {'-' if comp is None else ('on' if comp else 'off')} "
            f"| {i.get('clock_offset', '?')} | {i.get('clock_drift_ppm', '?')} | {a['recording']} |"
        )
    lines += [
        "",
        "## This run beside the paper",
        "",
        "The paper's figures: NOTES.md (600 s over the internet; hardware run, figs 8-11).",
        "",
        "| figure | pair or agent | this run | paper |",
        "|---|---|---:|---:|",
    ]
    for row in comparison_rows(summary):
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |")
    figures = summary.get("figures", {})
    lines += ["", "## Clock synchronization (figures 8, 9 and 11)", ""]
    lines += [
        "Each exchange gives an offset (Eq. 4) and a delay (Eq. 3); the line is the client's "
        "filtered estimate, the dashed line the truth from the shared host clock. Truth here "
        "cannot show path asymmetry: over a real path the estimate is also off by half of it.",
        "",
    ]
    for s in summary["sync"]:
        key = f"sync {s['client']} {s['peer']}"
        if key in figures:
            lines += [f"![sync of {s['client']} with {s['peer']}]({figures[key]})", ""]
    lines += ["## Heading (figure 10)", ""]
    if "heading" in figures:
        lines += [
            "Every heading on reference time (the leader's clock). Lag: the shift of the peak "
            "Pearson correlation between the follower's and the leader's heading.",
            "",
            f"![heading]({figures['heading']})",
            "",
            "## Sent vs received heading",
            "",
            "Separation: the time shift that best aligns a series with the sent heading "
            "(least squares over the maneuver). The received heading trails by the one-way "
            "delay; a latency-compensated follower's guidance reference should not trail at all.",
            "",
            f"![sent vs received heading]({figures['sent_vs_received']})",
            "",
        ]
    else:
        lines += ["No follower with a recorded leader: no heading figures.", ""]
    if summary["notes"]:
        lines += ["## Notes", ""] + [f"- {n}" for n in summary["notes"]] + [""]
    return "\n".join(lines)


# -- command line ----------------------------------------------------------------------------
def register(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser],
    formatter_class: type[argparse.HelpFormatter],
    add_zenoh_flags: Callable[[argparse.ArgumentParser], None],
) -> None:
    """Add the ``report`` command. It opens no Zenoh session, so ``add_zenoh_flags`` is unused."""
    del add_zenoh_flags
    p = subparsers.add_parser(
        "report",
        help="write report.md, summary.json and figures for a recorded run",
        formatter_class=formatter_class,
        description=(
            "Read every agent's MCAP recording in RUN_DIR (and run.json, if there) and write\n"
            "summary.json, PNG figures like the paper's and report.md setting the run beside\n"
            "the paper's numbers."
        ),
        epilog="Example:\n  fedlab report runs/demo\n  fedlab report runs/demo --out /tmp/report",
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="folder of *.mcap recordings")
    p.add_argument(
        "--out", type=Path, default=None, metavar="DIR", help="output folder (default: RUN_DIR)"
    )
    p.set_defaults(func=cmd_report)


def summary_table(summary: dict[str, Any], title: str = "this run beside the paper") -> Any:
    """The comparison rows as a rich table."""
    from rich.table import Table

    table = Table(title=title)
    table.add_column("figure")
    table.add_column("pair or agent")
    table.add_column("this run", justify="right")
    table.add_column("paper", justify="right")
    for row in comparison_rows(summary):
        table.add_row(*row)
    return table


def cmd_report(args: argparse.Namespace) -> int:
    from rich.console import Console

    out = args.out or args.run_dir
    summary = write_report(args.run_dir, out)
    console = Console()
    console.print(
        summary_table(summary, f"fedlab report {args.run_dir}: this run beside the paper")
    )
    for note in summary["notes"]:
        console.print(f"[yellow]note:[/] {note}", highlight=False)
    console.print(f"wrote to {out}: {', '.join(summary['files'])}", highlight=False)
    return 0
