"""``ctl start``'s preflight on the participants' latest statuses: a hold of a moment
(a pose late on a loaded link: ``held (stale)`` for 83 ms) refuses nothing once a
status says it is lifted, within the discovery time; a hold that stands is refused
when that time is up, the table saying why. Statuses are fed to ctl's view of the
federation as its subscriber would (no Zenoh)."""

from __future__ import annotations

import json
import threading
import time
from types import SimpleNamespace
from typing import Any

import pytest

from federation.core.keys import AgentId
from federation.runtime import control
from federation.runtime.statuses import Federation

LEADER, FOLLOWER = "kiruna/knatte", "rome/pinocchio"


class _Session:
    def declare_subscriber(self, *args: Any) -> Any:
        return SimpleNamespace(undeclare=lambda: None)


def status(agent: str, held: bool = False) -> dict[str, Any]:
    ready = {
        "platform": not held,
        "platform_detail": "held (stale)" if held else "",
        "recording": True,
        "recording_to": "runs",
        "reference_locked": True,
        "reference_bound": 0.0 if agent == LEADER else 0.0002,
    }
    return {"agent": agent, "reference": LEADER, "mode": "waiting", "t_sim": 12.0, "ready": ready}


def put(fed: Federation, line: dict[str, Any]) -> None:
    key = f"fedlab/default/{line['agent']}/status"
    payload = SimpleNamespace(to_bytes=lambda: json.dumps(line).encode())
    fed._on_status(SimpleNamespace(payload=payload, key_expr=key))


def issuing(discover: float) -> tuple[Any, Federation]:
    fed = Federation(_Session(), "default")
    it = SimpleNamespace(experiment=None, fed=fed, discover=discover, progress=lambda t: None)
    return it, fed


def test_a_hold_lifted_within_the_discovery_time_refuses_nothing() -> None:
    it, fed = issuing(discover=1.5)
    put(fed, status(LEADER))
    put(fed, status(FOLLOWER, held=True))
    seen = fed.snapshot()
    lifted = threading.Timer(0.083, put, (fed, status(FOLLOWER)))
    lifted.start()
    t0 = time.monotonic()
    rows, overridden = control._preflight_start(it, seen, AgentId.parse(LEADER), 0.010, False)
    lifted.join()
    assert time.monotonic() - t0 < 1.0  # the new status, not the end of the wait
    assert all(r.ok for r in rows) and overridden == []


def test_a_hold_that_stands_is_refused_when_the_discovery_time_is_up() -> None:
    it, fed = issuing(discover=0.3)
    put(fed, status(LEADER))
    put(fed, status(FOLLOWER, held=True))
    again = threading.Timer(0.1, put, (fed, status(FOLLOWER, held=True)))  # still held
    again.start()
    t0 = time.monotonic()
    with pytest.raises(control.PreflightFailed) as refused:
        control._preflight_start(it, fed.snapshot(), AgentId.parse(LEADER), 0.010, False)
    again.join()
    assert 0.3 <= time.monotonic() - t0 < 1.0
    (row,) = [r for r in refused.value.rows if not r.ok]
    assert row.agent == FOLLOWER and row.checks["platform"].detail == "held (stale)"


def test_force_starts_at_once_saying_what_it_overrode() -> None:
    it, fed = issuing(discover=5.0)
    put(fed, status(LEADER))
    put(fed, status(FOLLOWER, held=True))
    t0 = time.monotonic()
    _, overridden = control._preflight_start(it, fed.snapshot(), AgentId.parse(LEADER), 0.010, True)
    assert time.monotonic() - t0 < 0.5
    assert overridden == [f"{FOLLOWER}: platform: held (stale)"]


def test_a_status_that_came_after_the_last_look_ends_the_wait_at_once() -> None:
    """One taken between ctl's look at the statuses and its wait (a subscriber's thread
    runs meanwhile) is not missed: the wait returns without waiting for the next."""
    _, fed = issuing(discover=1.5)
    put(fed, status(LEADER))
    looked = fed.count
    put(fed, status(FOLLOWER))  # after the look, before the wait
    t0 = time.monotonic()
    fed.wait_new(looked, 2.0)
    assert time.monotonic() - t0 < 0.5
    t0 = time.monotonic()
    fed.wait_new(fed.count, 0.2)  # nothing new: the whole timeout
    assert time.monotonic() - t0 >= 0.2
