"""What a run's recordings measure: clock sync against the truth, separations, lag, RMS.

Every function here takes decoded messages (:mod:`federation.report.load`), not
files. The paper's own figures, printed beside these, are in
:mod:`federation.core.paper` (described in ``docs/paper.md``).

- **Clock sync**, per client and peer: median and standard deviation of the
  per-exchange offsets (Eq. 4) and delays (Eq. 3). Agents on one host share its
  monotonic clock, and every execution clock is an exact linear function of it
  (:func:`federation.report.status.clock_line`), so the true offset at client time
  :math:`t` is

  .. math::

      \\theta(t) = c_s\\big(h_c^{-1}(t)\\big) - t

  with :math:`h_c^{-1}` the client's clock line inverted (client time to host
  time) and :math:`c_s` the server's. The filtered estimate is scored against it
  after the paper's sync phase (:data:`federation.core.paper.SYNC_PHASE`) of
  exchanges (median, p95 and max of the absolute error). Over a real path the
  estimate also carries half the path asymmetry, which no recording can reveal;
  the host truth cannot show it either.
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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from federation.core.angles import wrap_angles
from federation.core.channels import Channel
from federation.report.load import AgentRecording, Messages, Run
from federation.report.status import clock_line

__all__ = [
    "LAG_MAX_S",
    "LAG_STEP_S",
    "SHIFT_MAX_S",
    "SHIFT_STEP_S",
    "Array",
    "Clock",
    "Follow",
    "SyncPair",
    "best_shift",
    "clock_map",
    "fit_clock",
    "follows",
    "heading_error",
    "heading_rms_deg",
    "heading_source",
    "sync_pairs",
    "xcorr_lag",
]

Array = npt.NDArray[np.float64]
Clock = tuple[float, float]  # (a, b): t_exec = a + b * host_monotonic

# Defaults, in one place.
SHIFT_MAX_S = 0.5  # s, separation search range (both ways)
SHIFT_STEP_S = 0.0005  # s, separation search step
LAG_MAX_S = 10.0  # s, follower lag search range (both ways)
LAG_STEP_S = 0.005  # s, follower lag search step


# -- clocks --------------------------------------------------------------------------------
def fit_clock(messages: Messages) -> Clock | None:
    """An agent's clock line from its recorded /status (else any channel stamped with both
    ``t_exec`` and ``host_monotonic``); None if nothing fits."""
    for topic in (Channel.STATUS, Channel.POSE_SENT, Channel.REFERENCE, Channel.TRUTH):
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
    error = wrap_angles(np.interp(t_r[inside], t_h, np.unwrap(h)) - r[inside])
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
    end: float | None = None  # reference time the leader's run stopped running


def heading_error(f: Follow) -> tuple[Array, Array] | None:
    """The follower's heading minus the leader's actual heading at the same reference time
    (rad, wrapped to [-pi, pi)), while the run ran: from its start to its end (or the
    leader's last sample). None without both headings."""
    if f.heading is None:
        return None
    (t, h), (t_l, h_l) = f.heading, f.leader_heading
    if t_l.size < 2:
        return None
    end = f.end if f.end is not None else float(t_l[-1])
    keep = (t >= max(f.start, float(t_l[0]))) & (t <= min(end, float(t_l[-1])))
    if not keep.any():
        return None
    leader = np.interp(t[keep], t_l, np.unwrap(h_l))
    error = (h[keep] - leader + np.pi) % (2 * np.pi) - np.pi
    return t[keep], error


def _col(messages: Sequence[dict[str, Any]], key: str) -> Array:
    return np.array([np.nan if m.get(key) is None else m[key] for m in messages], dtype=float)


def heading_source(rec: AgentRecording) -> tuple[list[dict[str, Any]], str]:
    truth = rec.channel(Channel.TRUTH)
    return (truth, "truth") if truth else (rec.channel(Channel.POSE_SENT), "estimate")


def sync_pairs(run: Run) -> list[SyncPair]:
    clocks = {a: fit_clock(r.messages) for a, r in run.agents.items()}
    pairs = []
    for client, rec in run.agents.items():
        by_peer: dict[str, list[dict[str, Any]]] = {}
        for m in rec.channel(Channel.SYNC_EXCHANGE):
            by_peer.setdefault(str(m.get("peer")), []).append(m)
        status = rec.channel(Channel.STATUS)
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
        sent = lead.channel(Channel.POSE_SENT)
        if len(sent) < 2:
            run.notes.append(
                f"{leader_name} recorded no {Channel.POSE_SENT}: nothing to compare {name} to"
            )
            continue
        # Follower clock -> leader (reference) clock: the truth if both clocks are known.
        f_clock, l_clock = clocks.get(name), clocks.get(leader_name)
        to_ref = clock_map(f_clock, l_clock) if f_clock and l_clock else None
        source = "truth"
        if to_ref is None:
            to_ref = _estimated_map(rec.channel(Channel.REFERENCE))
            source = "estimate"
            run.notes.append(
                f"{name}: no clock truth (needs both agents' recordings); reception mapped to "
                "reference time with the follower's own offset estimate"
            )
        received_msgs = [
            m for m in rec.channel(Channel.POSE_RECEIVED) if m.get("agent") == leader_name
        ]
        received = None
        age = np.array([])
        if received_msgs and to_ref is not None:
            t_recv = to_ref(_col(received_msgs, "t_recv"))
            received = _series(t_recv, _col(received_msgs, "heading"))
            age = t_recv - _col(received_msgs, "t")
        ref_msgs = [m for m in rec.channel(Channel.REFERENCE) if m.get("t_sim") is not None]
        reference = (
            _series(_col(ref_msgs, "t_sim"), _col(ref_msgs, "heading_ref")) if ref_msgs else None
        )
        own, _ = heading_source(rec)
        heading = None
        if own and to_ref is not None:
            heading = _series(to_ref(_col(own, "t_exec")), _col(own, "heading"))
        lead_own, _ = heading_source(lead)
        lead_ref = lead.channel(Channel.REFERENCE)
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
        start = _run_start(lead_ref, lead.channel(Channel.CONTROL))
        ran = [m["t_sim"] for m in lead_ref if m.get("mode") == "running" and m.get("t_sim")]
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
                end=max(ran) if ran else None,
            )
        )
    return out
