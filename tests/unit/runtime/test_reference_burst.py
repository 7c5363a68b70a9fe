"""ctl's look at the reference clock (``refclock.reference_sync``): a first exchange, then
the rest of the burst in flight together, over a stand-in path with a delay each way
and a reference whose clock is 100 s ahead; and the faults: a reference that answers
for a while and then nothing, one that answers once, one that answers only with errors,
one that answers from its third query on. A reference that never answers:
``tests/unit/cli/test_cli.py``."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from federation.core import wire
from federation.core.keys import AgentId
from federation.core.sync import serve
from federation.runtime import refclock
from federation.runtime.clock import ExecClock
from federation.runtime.session import ConnectError

AHEAD = 100.0  # s the reference's clock is ahead of ctl's
POSE = wire.Pose()


class _Reply:
    """What ``on_answer`` reads of a reply: whether it is one, its payload, its t3."""

    def __init__(self, payload: bytes | None, t3: float):
        self.ok, self._payload, self.t3 = payload is not None, payload, t3

    def payload(self) -> bytes:
        assert self._payload is not None
        return self._payload


class _Path:
    """A stand-in for ``SyncQuerier``: each request reaches the reference ``delay`` s
    after it is sent and its reply comes back ``delay`` s later, on timer threads as
    Zenoh's would; ``answers(i)`` says what the reference does with the i-th request
    ("reply", "error" or "none")."""

    def __init__(self, delay: float, answers: Callable[[int], str]):
        self.delay, self.answers = delay, answers
        self.sent = 0
        self.in_flight = 0
        self.most_in_flight = 0
        self.lock = threading.Lock()
        self.timers: list[threading.Timer] = []

    def __call__(self, session: Any, key: str, timeout: float, read: Any, on_answer: Any) -> _Path:
        self.read, self.on_answer = read, on_answer
        return self

    def request(self, payload: bytes) -> None:
        with self.lock:
            what = self.answers(self.sent)
            self.sent += 1
            if what == "none":
                return
            self.in_flight += 1
            self.most_in_flight = max(self.most_in_flight, self.in_flight)
        timer = threading.Timer(self.delay, self._at_the_reference, (payload, what))
        self.timers.append(timer)
        timer.start()

    def _at_the_reference(self, payload: bytes, what: str) -> None:
        t2 = self.read()[0] + AHEAD  # ctl's own clock, ahead
        reply = None if what == "error" else serve(payload, t2, POSE, t2).payload
        timer = threading.Timer(self.delay, self._back, (reply,))
        self.timers.append(timer)
        timer.start()

    def _back(self, reply: bytes | None) -> None:
        with self.lock:
            self.in_flight -= 1
        t3, _ = self.read()
        self.on_answer(_Reply(reply, t3))

    def close(self) -> None:
        for timer in list(self.timers):
            timer.cancel()


def look(monkeypatch: pytest.MonkeyPatch, path: _Path) -> tuple[float, float, float]:
    """ctl's look at the reference through ``path``: the reference time it gives, what
    ctl's clock read then plus :data:`AHEAD`, and the seconds it took."""
    monkeypatch.setattr(refclock, "SyncQuerier", path)
    clock = ExecClock()
    t0 = time.monotonic()
    ref_now = refclock.reference_now(object(), "default", AgentId("lab", "ref"), clock)
    return ref_now, clock.now() + AHEAD, time.monotonic() - t0


def test_the_burst_is_in_flight_together_and_gives_the_reference_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    path = _Path(0.04, lambda i: "reply")
    ref_now, truth, _ = look(monkeypatch, path)
    assert path.sent == refclock.REFERENCE_BURST
    # The first alone, then the rest 20 ms apart over an 80 ms round trip: several at once.
    assert path.most_in_flight >= 3
    # A symmetric path: the offset is the clocks' own, but for the timers' lateness.
    assert ref_now == pytest.approx(truth, abs=0.02)


def test_a_reference_that_falls_silent_mid_burst_gives_an_instant_from_what_it_answered(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    path = _Path(0.01, lambda i: "reply" if i < 8 else "none")
    ref_now, truth, took = look(monkeypatch, path)
    assert path.sent == refclock.REFERENCE_BURST
    assert ref_now == pytest.approx(truth, abs=0.02)
    assert took < 5.0  # each unanswered request waits 1 s at most, all at once


def test_a_reference_that_answers_once_then_falls_silent_gives_no_instant(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # One exchange is not an estimate (the filter warms up on a few): ctl says so.
    path = _Path(0.01, lambda i: "reply" if i == 0 else "none")
    with pytest.raises(ConnectError, match="reference agent lab/ref did not answer"):
        look(monkeypatch, path)
    assert path.sent == refclock.REFERENCE_BURST


def test_a_reference_that_answers_only_with_errors_is_given_up_after_a_few(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    path = _Path(0.01, lambda i: "error")
    with pytest.raises(ConnectError, match="reference agent lab/ref did not answer"):
        look(monkeypatch, path)
    assert path.sent == refclock.REFERENCE_UNANSWERED


def test_a_reference_that_answers_the_third_query_gets_the_whole_burst(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The route comes up late: two queries go unanswered, the third is answered.
    path = _Path(0.01, lambda i: "none" if i < 2 else "reply")
    ref_now, truth, _ = look(monkeypatch, path)
    assert path.sent == 2 + refclock.REFERENCE_BURST
    assert ref_now == pytest.approx(truth, abs=0.02)
