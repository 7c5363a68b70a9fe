"""A live terminal view of every agent in a federation (``fedlab monitor``).

Three layers, so the part that decides what is shown is tested without Zenoh:

- :class:`MonitorModel` (no I/O, no clock): status payloads and liveliness changes
  go in with the time they arrived (``now``, any monotonic seconds), :class:`Row`
  objects come out of :meth:`MonitorModel.rows`. Nothing it receives can make it
  raise: a status that is not JSON, does not validate as
  :class:`schemas.messages.Status`, or names another agent than its key says is
  counted as malformed and shown in the footer.
- :func:`render`: rows to a ``rich.table.Table``.
- The Zenoh layer (:func:`subscribe`, :class:`Watch`, :func:`live`): subscribers on
  ``fedlab/<federation>/*/*/status`` and on liveliness ``fedlab/<federation>/*/*``
  (with history, so agents already present show up at once) hand each sample to
  the model under a lock; the display refreshes once a second.

What a row shows
----------------
An agent's *sync peers* are its reference (``status.reference``) or, for the
reference itself, every peer it syncs with.

==============  ==================================================================
offset          ``peers[reference].offset`` (s); ``ref`` on the reference itself
delay           ``peers[reference].delay``; on the reference, the largest delay to
                any alive peer (its farthest agent)
pose age        ``status.pose_age`` (followers; how old the followed pose is)
samples         accepted sync exchanges with the sync peers
rejected        rejected sync replies (all peers) + every counter ending ``_malformed``
late p99        control loop lateness, 99th percentile (``status.loop.late_p99_ms``)
run             ``status.run_id``: the run started last
run time        ``status.run_time`` / ``status.duration`` (progress, %)
hold            ``status.hold``: why every valve is closed (docs/holds.md); in red
                one that stops a start, in yellow the run's own (waiting, done, reset)
silent          an alarm, in red: the peers it reports alive but silent (answering
                no sync request for 2 s, ``peers.<agent>.silent``) and for how long;
                never left out on a narrow terminal
bound           error bound of its estimate of the reference clock (``peers[reference]
                .bound``, else the last exchange's ``error_bound``); 0 on the reference
last status     seconds since its last valid status, marked ``stale`` after
                ``stale_after``; ``left`` once its liveliness token is gone (dimmed);
                a row silent (or gone) for ``drop_after`` s is dropped
==============  ==================================================================
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

from pydantic import ValidationError
from rich import box
from rich.console import Console
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

from federation.core import keys
from federation.core.holds import BY_HOLD, Hold
from federation.core.keys import AgentId
from federation.core.preflight import named_silent
from federation.runtime.session import undeclare_all
from schemas.messages import Status

__all__ = [
    "COLUMNS",
    "DEFAULT_DROP_AFTER",
    "DEFAULT_STALE_AFTER",
    "MAX_STATUS_BYTES",
    "OPTIONAL_COLUMNS",
    "MonitorModel",
    "Row",
    "Snapshot",
    "Watch",
    "fit",
    "live",
    "render",
    "row_json",
    "subscribe",
]

log = logging.getLogger("fedlab.monitor")

DEFAULT_STALE_AFTER = 3.0
"""Seconds without a status after which a row is stale (agents publish once a second)."""
DEFAULT_DROP_AFTER = 30.0
"""Seconds without a status (or since its token went) after which a row is dropped."""
MAX_STATUS_BYTES = 1 << 20
"""A status larger than this is malformed without being parsed."""

State = Literal["ok", "stale", "left", "waiting"]


@dataclass(frozen=True)
class Row:
    """One agent as the monitor shows it; ``None`` where nothing is known yet."""

    agent: str  # LAB/NAME
    lab: str
    name: str
    state: State  # waiting: no valid status yet; stale: none for stale_after s; left: token gone
    alive: bool  # liveliness token present (or not yet seen either way)
    role: str | None = None
    mode: str | None = None
    platform: str | None = None
    reference: str | None = None
    is_reference: bool = False
    offset_s: float | None = None  # peers[reference].offset; None on the reference itself
    delay_s: float | None = None
    pose_age_s: float | None = None
    samples: int | None = None
    rejected: int | None = None
    late_p99_ms: float | None = None
    since_status_s: float | None = None
    contested: dict[str, str] | None = None  # peer -> why two sources speak for it
    run_id: str | None = None
    run_time_s: float | None = None
    duration_s: float | None = None  # the run's; run_time / duration is its progress
    hold: str | None = None  # why every valve is held closed (stale, aborted, done, reset)
    bound_s: float | None = None  # error bound of its estimate of the reference clock
    silent: dict[str, float] | None = None  # peer -> s it has been alive but silent


@dataclass
class _Agent:
    id: AgentId
    alive: bool = True
    status: Status | None = None
    status_at: float | None = None
    changed_at: float | None = None  # last liveliness change


class MonitorModel:
    """What the monitor knows: the last valid status and the liveliness of every agent.

    Not thread-safe: the Zenoh layer calls it under one lock.
    """

    def __init__(
        self,
        federation: str = keys.DEFAULT_FEDERATION,
        stale_after: float = DEFAULT_STALE_AFTER,
        drop_after: float = DEFAULT_DROP_AFTER,
    ) -> None:
        self.federation = keys.validate_name(federation, "federation name")
        self.stale_after = stale_after
        self.drop_after = drop_after
        self.malformed = 0
        self.last_error: str | None = None
        self._agents: dict[AgentId, _Agent] = {}

    def _agent(self, agent: AgentId) -> _Agent:
        entry = self._agents.get(agent)
        if entry is None:
            entry = self._agents[agent] = _Agent(agent)
        return entry

    def _reject(self, key: str, reason: str) -> None:
        self.malformed += 1
        self.last_error = f"{key}: {reason}"
        if self.malformed <= 5 or self.malformed % 100 == 0:
            log.warning("malformed status #%d on %s: %s", self.malformed, key, reason)

    def on_status(self, key: str, payload: bytes, now: float) -> None:
        """A status sample published on ``key``; a malformed one is counted, never raised."""
        key = str(key)
        parsed = keys.parse_agent_key(self.federation, key)
        if parsed is None or parsed[1] != "status":
            self._reject(key, "not a status key of this federation")
            return
        agent = parsed[0]
        if len(payload) > MAX_STATUS_BYTES:
            self._reject(key, f"{len(payload)} bytes, more than {MAX_STATUS_BYTES}")
            return
        try:
            status = Status.model_validate_json(payload)
        except ValidationError as error:
            self._reject(key, _first_error(error))
            return
        except Exception as error:  # anything else a broken payload may raise
            self._reject(key, f"{type(error).__name__}: {error}")
            return
        if status.agent != str(agent):
            self._reject(key, f"agent {status.agent!r} does not match the key")
            return
        if status.federation != self.federation:
            self._reject(key, f"federation {status.federation!r} does not match the key")
            return
        entry = self._agent(agent)
        entry.status = status
        entry.status_at = now

    def on_liveliness(self, key: str, alive: bool, now: float) -> None:
        """A liveliness token appeared (``alive``) or went away; other keys are ignored."""
        parsed = keys.parse_agent_key(self.federation, str(key))
        if parsed is None or parsed[1] is not None:
            return
        entry = self._agent(parsed[0])
        entry.alive = alive
        entry.changed_at = now

    def rows(self, now: float) -> list[Row]:
        """Every agent seen, sorted by lab and name; an agent silent (or gone) for
        ``drop_after`` s is forgotten."""
        for agent in [a for a, e in self._agents.items() if self._dropped(e, now)]:
            del self._agents[agent]
        return [self._row(self._agents[a], now) for a in sorted(self._agents)]

    def _dropped(self, entry: _Agent, now: float) -> bool:
        last = max((t for t in (entry.status_at, entry.changed_at) if t is not None), default=None)
        return last is not None and now - last > self.drop_after

    def _row(self, entry: _Agent, now: float) -> Row:
        since = None if entry.status_at is None else max(0.0, now - entry.status_at)
        state: State
        if not entry.alive:
            state = "left"
        elif since is None:
            state = "waiting"
        elif since > self.stale_after:
            state = "stale"
        else:
            state = "ok"
        base = Row(
            agent=str(entry.id),
            lab=entry.id.lab,
            name=entry.id.name,
            state=state,
            alive=entry.alive,
            since_status_s=since,
        )
        status = entry.status
        if status is None:
            return base
        is_reference = status.reference == status.agent
        if is_reference:
            sync_peers = list(status.peers.values())
            delays = [_finite(p.delay) for p in sync_peers if p.alive]
            known = [d for d in delays if d is not None]
            offset = None
            delay = max(known) if known else None
        else:
            ref = status.peers.get(status.reference)
            sync_peers = [] if ref is None else [ref]
            offset = None if ref is None else _finite(ref.offset)
            delay = None if ref is None else _finite(ref.delay)
        rejected = sum(p.rejected for p in status.peers.values()) + sum(
            v for k, v in status.counters.items() if k.endswith("_malformed")
        )
        return replace(
            base,
            role=status.role,
            mode=status.mode,
            platform=status.platform,
            reference=status.reference,
            is_reference=is_reference,
            offset_s=offset,
            delay_s=delay,
            pose_age_s=_finite(status.pose_age),
            samples=sum(p.samples for p in sync_peers) if sync_peers else None,
            rejected=rejected,
            late_p99_ms=_finite(status.loop.get("late_p99_ms")),
            contested=dict(status.contested) or None,
            run_id=status.run_id,
            run_time_s=_finite(status.run_time),
            duration_s=_finite(status.duration),
            hold=status.hold,
            bound_s=0.0 if is_reference else None if ref is None else _bound(ref),
            silent=_silent(status) or None,
        )


def _first_error(error: ValidationError) -> str:
    """The first problem pydantic found, as ``field.path: message``."""
    details = error.errors()
    if not details:
        return str(error)
    where = ".".join(str(part) for part in details[0]["loc"]) or "payload"
    return f"{where}: {details[0]['msg']}"


def _silent(status: Status) -> dict[str, float]:
    """Peers ``status`` reports alive but silent (s silent), as preflight reads them."""
    return {
        name: float(p.silent)
        for name, p in status.peers.items()
        if p.silent is not None and math.isfinite(p.silent)
    }


def _bound(peer: Any) -> float | None:
    """The error bound status reports of a peer's clock (the estimate's, else the last
    exchange's)."""
    bound = _finite(peer.bound)
    return bound if bound is not None else _finite(peer.error_bound)


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def row_json(row: Row) -> dict[str, Any]:
    """A row as JSON-ready values; the reference's ``offset_s`` is ``"ref"``."""
    data = asdict(row)
    if row.is_reference:
        data["offset_s"] = "ref"
    return data


# -- rendering ---------------------------------------------------------------------
_DASH = "-"


def _num(value: float | None, scale: float = 1.0, fmt: str = ".2f") -> str:
    return _DASH if value is None else format(value * scale, fmt)


def _int(value: int | None) -> str:
    return _DASH if value is None else str(value)


def _offset(row: Row) -> Text:
    if row.is_reference:
        return Text("ref", style="cyan")
    return Text(_num(row.offset_s, fmt="+.6f"))


def _mode(row: Row) -> str | Text:
    """The run mode; and, in red, the peers this agent finds contested."""
    if not row.contested:
        return row.mode or _DASH
    peers = ", ".join(f"{peer} ({why})" for peer, why in row.contested.items())
    return Text(f"{row.mode or _DASH}, contested: {peers}", style="red")


def _run_time(row: Row) -> str:
    """``12.3 s / 20 (62 %)``: run time and progress through the run's duration."""
    if row.run_time_s is None:
        return _DASH
    if not row.duration_s:
        return f"{row.run_time_s:.1f}"
    return f"{row.run_time_s:.1f}/{row.duration_s:g} ({100 * row.run_time_s / row.duration_s:.0f}%)"


_HOLDS = frozenset(hold.value for hold in Hold)


def _hold(row: Row) -> Text:
    if row.hold is None:
        return Text(_DASH)
    rule = BY_HOLD.get(Hold(row.hold)) if row.hold in _HOLDS else None
    fault = rule is None or rule.preflight  # the run's own holds are no fault
    return Text(row.hold, style="red" if fault else "yellow")


def _silent_cell(row: Row) -> Text:
    """``kiruna/knatte 2.3 s`` in red for each peer alive but silent; ``-`` when none."""
    if not row.silent:
        return Text(_DASH)
    return Text(named_silent(row.silent), style="bold red")


def _rejected(row: Row) -> Text:
    return Text(_int(row.rejected), style="red" if row.rejected else "")


# (header, right-aligned, cell); in display order.
_COLUMNS: dict[str, tuple[str, bool, Callable[[Row], str | Text]]] = {
    "lab": ("lab", False, lambda r: r.lab),
    "name": ("name", False, lambda r: r.name),
    "role": ("role", False, lambda r: r.role or _DASH),
    "mode": ("mode", False, lambda r: _mode(r)),
    "run": ("run", False, lambda r: r.run_id or _DASH),
    "run_time": ("run time\ns", True, _run_time),
    "hold": ("hold", False, _hold),
    "silent": ("silent\npeers", False, _silent_cell),
    "platform": ("platform", False, lambda r: r.platform or _DASH),
    "offset": ("offset\ns", True, _offset),
    "delay": ("delay\nms", True, lambda r: _num(r.delay_s, 1e3)),
    "bound": ("bound\nms", True, lambda r: _num(r.bound_s, 1e3, ".3f")),
    "pose_age": ("pose age\nms", True, lambda r: _num(r.pose_age_s, 1e3, ".1f")),
    "samples": ("samples", True, lambda r: _int(r.samples)),
    "rejected": ("rejected", True, _rejected),
    "late_p99": ("late p99\nms", True, lambda r: _num(r.late_p99_ms)),
    "since": ("last\nstatus", True, lambda r: _since(r)),
}
COLUMNS = tuple(_COLUMNS)
"""Column ids, in display order."""
OPTIONAL_COLUMNS = (
    "platform",
    "late_p99",
    "samples",
    "pose_age",
    "run",
    "bound",
    "run_time",
    "hold",
    "mode",
)
"""Columns :func:`fit` leaves out, first to last, when a terminal is too narrow."""


def render(
    rows: Sequence[Row],
    *,
    federation: str = keys.DEFAULT_FEDERATION,
    malformed: int = 0,
    last_error: str | None = None,
    columns: Sequence[str] = COLUMNS,
) -> Table:
    """The monitor's table: one line per agent, malformed statuses in the caption.

    Stale rows and rows of agents that left are dimmed.
    """
    table = Table(
        title=f"fedlab monitor · federation {federation}",
        caption=_footer(rows, malformed, last_error),
        caption_justify="left",
        header_style="bold",
        box=box.SIMPLE_HEAD,
        pad_edge=False,
        collapse_padding=True,
        expand=False,
    )
    shown = [c for c in COLUMNS if c in columns]
    for column in shown:
        header, right, _ = _COLUMNS[column]
        # Who a row is about stays readable on a narrow terminal: the numbers shrink first.
        width = None
        if column in ("lab", "name"):
            width = max((len(getattr(r, column)) for r in rows), default=0) or None
        table.add_column(header, justify="right" if right else "left", min_width=width)
    for row in rows:
        table.add_row(
            *(_safe(_COLUMNS[c][2](row)) for c in shown),
            style="dim" if row.state in ("stale", "left") else None,
        )
    return table


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """``text`` without control characters: what any agent's status says is shown, never
    run by the terminal (an escape sequence would repaint other agents' rows)."""
    return _CONTROL.sub("\N{REPLACEMENT CHARACTER}", text)


def _safe(cell: str | Text) -> Text:
    """A cell as plain text: a string is never read as rich markup (a status whose mode
    is ``[/]`` would stop the monitor), and neither carries control characters."""
    if isinstance(cell, Text):
        return Text(printable(cell.plain), style=cell.style)
    return Text(printable(cell))


def fit(console: Console, rows: Sequence[Row], **kwargs: Any) -> Table:
    """:func:`render` with the optional columns left out, in order, until it fits ``console``."""
    columns = list(COLUMNS)
    table = render(rows, columns=columns, **kwargs)
    unbounded = console.options.update_width(1 << 16)  # a measurement is clamped to its width
    for column in OPTIONAL_COLUMNS:
        if Measurement.get(console, unbounded, table).maximum <= console.width:
            break
        columns.remove(column)
        table = render(rows, columns=columns, **kwargs)
    return table


def _since(row: Row) -> Text:
    if row.state == "left":
        return Text("left", style="red")
    if row.since_status_s is None:
        return Text("waiting", style="yellow")
    text = f"{row.since_status_s:.1f} s"
    if row.state == "stale":
        return Text(f"{text} stale", style="yellow")
    return Text(text)


CLOCKS_NOTE = (
    "offset: the reference's clock minus this agent's; each agent's clock starts at an "
    "arbitrary origin, so offsets of tens of seconds, even on one host, are expected"
)
"""The monitor's one line on clocks, under its table."""


def _footer(rows: Sequence[Row], malformed: int, last_error: str | None) -> Text:
    present = sum(1 for r in rows if r.state != "left")
    text = Text(f"{len(rows)} agents, {present} present · malformed status: {malformed}")
    if malformed:
        text.stylize("red", text.plain.rindex("malformed"))
        if last_error:
            text.append(f" (last: {printable(last_error[:200])})", style="red")
    text.append(f"\n{CLOCKS_NOTE}", style="dim")
    return text


# -- Zenoh -------------------------------------------------------------------------
def subscribe(
    session: Any, model: MonitorModel, lock: threading.Lock, clock: Callable[[], float]
) -> list[Any]:
    """Declare the status and liveliness subscribers feeding ``model``; undeclare them all
    (in reverse order) before closing ``session``."""
    import zenoh

    def on_status(sample: zenoh.Sample) -> None:
        try:
            payload = sample.payload.to_bytes()
            with lock:
                model.on_status(str(sample.key_expr), payload, clock())
        except Exception:  # a callback on Zenoh's thread must never raise
            log.exception("status sample on %s failed", sample.key_expr)

    def on_liveliness(sample: zenoh.Sample) -> None:
        try:
            alive = sample.kind == zenoh.SampleKind.PUT
            with lock:
                model.on_liveliness(str(sample.key_expr), alive, clock())
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)

    callback = zenoh.handlers.Callback
    declared: list[Any] = []
    fed = model.federation
    try:
        declared.append(
            session.declare_subscriber(
                keys.all_of(fed, "status"), callback(on_status, indirect=False)
            )
        )
        declared.append(
            session.liveliness().declare_subscriber(
                keys.all_agents(fed), callback(on_liveliness, indirect=False), history=True
            )
        )
    except Exception:
        undeclare_all(declared)
        raise
    return declared


@dataclass(frozen=True)
class Snapshot:
    """What the monitor knows at one instant."""

    federation: str
    rows: tuple[Row, ...]
    malformed: int
    last_error: str | None

    def as_json(self) -> dict[str, Any]:
        """JSON-ready: the rows as :func:`row_json` gives them."""
        return {
            "federation": self.federation,
            "rows": [row_json(r) for r in self.rows],
            "malformed": self.malformed,
            "last_error": self.last_error,
        }

    def table(self, console: Console) -> Table:
        """The table :func:`fit` to ``console``."""
        return fit(
            console,
            self.rows,
            federation=self.federation,
            malformed=self.malformed,
            last_error=self.last_error,
        )


class Watch:
    """A :class:`MonitorModel` fed by a session's status and liveliness subscribers.

    Close it (or leave its ``with`` block) before closing the session.
    """

    def __init__(
        self,
        session: Any,
        federation: str = keys.DEFAULT_FEDERATION,
        stale_after: float = DEFAULT_STALE_AFTER,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.model = MonitorModel(federation, stale_after)
        self._clock = clock
        self._lock = threading.Lock()
        self._declared = subscribe(session, self.model, self._lock, clock)

    def snapshot(self) -> Snapshot:
        with self._lock:
            return Snapshot(
                self.model.federation,
                tuple(self.model.rows(self._clock())),
                self.model.malformed,
                self.model.last_error,
            )

    def close(self) -> None:
        undeclare_all(self._declared)

    def __enter__(self) -> Watch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def live(
    watch: Watch, console: Console, stop: threading.Event, duration: float | None = None
) -> None:
    """Show ``watch``'s table on ``console``, refreshed once a second, until ``stop`` or
    ``duration`` seconds."""
    from rich.live import Live

    clock = time.monotonic
    deadline = math.inf if duration is None else clock() + duration
    with Live(watch.snapshot().table(console), console=console, auto_refresh=False) as view:
        while not stop.is_set() and clock() < deadline:
            stop.wait(min(1.0, max(0.0, deadline - clock())))
            view.update(watch.snapshot().table(console), refresh=True)
