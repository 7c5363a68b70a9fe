"""The report's PNG figures, like the source paper's (figures 8 to 11, ``docs/paper.md``).

- :func:`plot_sync`: offset and delay of every exchange of one client and peer,
  with the filtered estimate and the truth (figures 8, 9 and 11);
- :func:`plot_heading`: the leader's reference and heading with each follower's
  heading on reference time (figure 10);
- :func:`plot_sent_received`: sent heading, heading as received and each
  follower's guidance reference, zoomed on the leader's fastest turn.

matplotlib is imported when a figure is drawn (Agg backend, no display needed).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from federation.core import paper
from federation.core.channels import recording_stem
from federation.report.analysis import Array, Follow, SyncPair, follows, heading_error, sync_pairs
from federation.report.load import Run
from federation.report.summary import compensation_label, fmt

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "DPI",
    "ZOOM_HALF_WIDTH_S",
    "plot_heading",
    "plot_sent_received",
    "plot_sync",
    "write_figures",
]

DPI = 150  # 10 in wide: 1500 pixels
ZOOM_HALF_WIDTH_S = 0.3  # s either side of the steepest point in the sent-vs-received figure


def write_figures(
    run: Run, summary: dict[str, Any], out: Path, sync_phase: float = paper.SYNC_PHASE
) -> dict[str, Path]:
    """Draw every figure of ``run`` into ``out``; return them by name.

    ``summary`` is :func:`federation.report.summary.summarize` of the same run (the
    legends quote its figures); notes on what could not be drawn are added to its
    ``notes``. The heading figures show the followers of one leader: the first
    follower's.
    """
    figures: dict[str, Path] = {}
    for pair, s in zip(sync_pairs(run), summary["sync"], strict=True):
        if len(pair.t3):
            path = out / f"sync_{recording_stem(pair.client)}_{recording_stem(pair.peer)}.png"
            plot_sync(pair, path, s.get("emulated_delay_s"), sync_phase)
            figures[f"sync {pair.client} {pair.peer}"] = path
    follow_list = follows(dataclasses.replace(run, notes=[]))  # notes: summary's
    if not follow_list:
        summary["notes"].append("no follower with a recorded leader: no heading figures")
        return figures
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
    return figures


def _figure(rows: int = 1, height: float = 5.0) -> tuple[Figure, list[Axes]]:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, height), dpi=DPI, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    for ax in axes:
        ax.grid(True, alpha=0.35)
    return fig, list(axes)


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
# Heading as received: dotted with crosses; a follower's guidance reference: solid with squares.
_RECEIVED: dict[str, Any] = {"lw": 1.0, "ls": ":", "marker": "x", "ms": 6}
_REFERENCE: dict[str, Any] = {"lw": 1.6, "marker": "s", "ms": 3.5}


def plot_heading(follow_list: list[Follow], summaries: list[dict[str, Any]], path: Path) -> None:
    """Leader reference and heading with each follower's heading (the paper's figure 10);
    below, each follower's heading error against the leader's actual heading."""
    fig, (ax, err_ax) = _figure(2, 8.0)
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
            label=f"{f.follower} heading, {compensation_label(f.compensation)} "
            f"(lag {fmt(s['lag_s'], 1, 2)} s)",
        )
    ax.set_ylabel("heading (deg)")
    ax.set_title("Leader and follower heading on corrected (reference) time", fontsize=11)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    for i, (f, s) in enumerate(zip(follow_list, summaries, strict=True)):
        error = heading_error(f)
        if error is None:
            continue
        rms, peak = (
            s.get("heading_error_vs_leader_rms_deg"),
            s.get("heading_error_vs_leader_max_deg"),
        )
        err_ax.plot(
            error[0] - t0,
            np.degrees(error[1]),
            color=_COLORS[i % 6],
            lw=1.2,
            label=f"{f.follower}, {compensation_label(f.compensation)} "
            f"(RMS {fmt(rms, 1, 2)}, max {fmt(peak, 1, 2)} deg)",
        )
    err_ax.axhline(0.0, color="0.6", lw=0.8)
    err_ax.set_xlabel(f"reference time since the run started, {first.leader}'s clock (s)")
    err_ax.set_ylabel("follower - leader (deg)")
    err_ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    fig.savefig(path, dpi=DPI)


def _steepest(f: Follow) -> float:
    """Reference time of the leader's fastest turn (its reference, else its sent heading)."""
    t, h = f.leader_reference if f.leader_reference is not None else f.sent
    if f.window is not None:
        keep = (t >= f.window[0]) & (t <= f.window[1])
        t, h = t[keep], h[keep]
    # Samples on one instant (a frozen run's, a repeated stamp) would make the gradient
    # infinite there and name them the fastest turn: the first of each instant is kept.
    distinct = np.concatenate(([True], np.diff(t) > 0)) if len(t) else np.array([], bool)
    t, h = t[distinct], h[distinct]
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
        styles = (
            (f.received, "received_separation_s", f"received at {f.follower}", _RECEIVED),
            (
                f.reference,
                "reference_separation_s",
                f"{f.follower} reference, {compensation_label(f.compensation)}",
                _REFERENCE,
            ),
        )
        for series, key, label, style in styles:
            if series is not None:
                t, h = zoom(series)
                after = fmt(s[key], 1e3, 1)
                ax.plot(t, h, color=color, label=f"{label} ({after} ms after sent)", **style)
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
