"""Three-timestamp synchronization (federation/core/sync.py): both halves.

SyncClient is driven through a tiny in-memory network: a server whose clock is the
client's clock plus a known offset answers each request at once, and datagrams travel
with chosen outbound and return delays. Every loop is bounded.
"""

from __future__ import annotations

import heapq
import math
import random
import statistics
from dataclasses import dataclass, field

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.core import wire
from federation.core.clockfilter import ClockFilter
from federation.core.estimators import make_estimator
from federation.core.sync import (
    DEFAULT_WINDOW,
    Exchange,
    PaperEstimator,
    SyncClient,
    read_send_time,
    serve,
)
from federation.core.wire import Pose, encode_reply

PAPER_OFFSET = 26.420  # s, validation run (figures 8 and 9)
PAPER_DELAY = 0.0395  # s, one way, median on KNATTE
HARDWARE_OFFSET = 30.880  # s, hardware run (figures 10 and 11)


# ------------------------------------------------------------------ helpers


def exchange_for(t1: float, offset: float, out: float, back: float | None = None) -> Exchange:
    """The exchange a client at ``t1`` would record with a server ``offset`` ahead."""
    back = out if back is None else back
    return Exchange(t1=t1, t2=t1 + out + offset, t3=t1 + out + back)


class MemoryServer:
    """Answers a request at once; its clock reads the client's clock plus ``offset``."""

    def __init__(self, offset: float, pose: Pose | None = None):
        self.offset = offset
        self.pose = pose or Pose(x=1.0, y=2.0, heading=0.5, vx=0.0, vy=0.0, omega=0.01)
        self.requests = 0

    def handle(self, request: bytes, client_now: float) -> bytes:
        self.requests += 1
        t2 = client_now + self.offset
        return serve(request, t2, self.pose, t2).payload


@dataclass
class MemoryLink:
    """Client and server joined by a network with given delays.

    Requests are sent every ``period`` seconds of client time; each datagram is
    delivered after its delay. ``drop_reply`` and ``duplicate_reply`` pick requests
    (by sequence number) whose reply is lost or delivered twice.
    """

    client: SyncClient
    server: MemoryServer
    out: float = PAPER_DELAY
    back: float = PAPER_DELAY
    period: float = 0.1
    drop_reply: set[int] = field(default_factory=set)
    duplicate_reply: set[int] = field(default_factory=set)
    accepted_replies: list[wire.SyncReply] = field(default_factory=list)

    def run(self, duration: float, start: float = 0.0, max_events: int = 100_000) -> None:
        # (time, order, kind, payload, sequence): heap of events in client time.
        events: list[tuple[float, int, str, bytes, int]] = []
        order = 0
        n_requests = round(duration / self.period)
        for seq in range(n_requests):
            heapq.heappush(events, (start + seq * self.period, order, "send", b"", seq))
            order += 1
        handled = 0
        while events:
            handled += 1
            assert handled <= max_events, "network simulation did not settle"
            now, _, kind, payload, seq = heapq.heappop(events)
            if kind == "send":
                request = self.client.request(now)
                heapq.heappush(events, (now + self.out, order, "server", request, seq))
            elif kind == "server":
                reply = self.server.handle(payload, now)
                copies = 0 if seq in self.drop_reply else 2 if seq in self.duplicate_reply else 1
                for _ in range(copies):
                    heapq.heappush(events, (now + self.back, order, "client", reply, seq))
                    order += 1
            else:
                got = self.client.receive(payload, now)
                if got is not None:
                    self.accepted_replies.append(got)
            order += 1


# ----------------------------------------------------------------- Exchange


def test_exchange_hand_computed() -> None:
    ex = Exchange(t1=10.0, t2=36.5, t3=10.08)
    assert ex.delay == pytest.approx(0.04, abs=1e-12)  # (10.08 - 10) / 2
    assert ex.offset == pytest.approx(26.46, abs=1e-12)  # 36.5 - (10 + 10.08) / 2
    assert ex.error_bound == pytest.approx(0.04, abs=1e-12)


def test_exchange_exact_dyadic() -> None:
    ex = Exchange(t1=1.0, t2=101.5, t3=2.0)
    assert ex.delay == 0.5
    assert ex.offset == 100.0
    ex = Exchange(t1=4.0, t2=0.25, t3=4.5)
    assert ex.delay == 0.25
    assert ex.offset == -4.0  # 0.25 - 4.25: the server is behind


def test_exchange_offset_sign_is_server_minus_client() -> None:
    # Server clock ahead of the client's: positive offset.
    assert Exchange(0.0, 30.0, 0.0).offset == 30.0
    assert Exchange(30.0, 0.0, 30.0).offset == -30.0


def test_exchange_is_frozen() -> None:
    ex = Exchange(0.0, 1.0, 2.0)
    with pytest.raises(AttributeError):
        ex.t1 = 5.0  # type: ignore[misc]


@pytest.mark.parametrize("offset", [PAPER_OFFSET, -PAPER_OFFSET, HARDWARE_OFFSET, 0.0])
def test_exchange_recovers_known_offset_and_delay(offset: float) -> None:
    ex = exchange_for(t1=123.4, offset=offset, out=PAPER_DELAY)
    assert ex.offset == pytest.approx(offset, abs=1e-9)
    assert ex.delay == pytest.approx(PAPER_DELAY, abs=1e-9)


def test_asymmetric_path_errs_by_half_the_difference() -> None:
    ex = exchange_for(t1=0.0, offset=PAPER_OFFSET, out=0.030, back=0.050)
    assert ex.offset - PAPER_OFFSET == pytest.approx((0.030 - 0.050) / 2, abs=1e-9)
    assert ex.delay == pytest.approx(0.040, abs=1e-9)


@given(
    t1=st.floats(0.0, 1e4),
    offset=st.floats(-1e5, 1e5),
    delay=st.floats(0.0, 1.0),
)
def test_symmetric_exchange_recovers_offset(t1: float, offset: float, delay: float) -> None:
    ex = exchange_for(t1, offset, delay)
    assert ex.offset == pytest.approx(offset, abs=1e-9)
    assert ex.delay == pytest.approx(delay, abs=1e-9)


@given(
    offset=st.floats(-1e3, 1e3),
    out=st.floats(0.0, 1.0),
    back=st.floats(0.0, 1.0),
)
def test_error_bound_covers_any_asymmetry(offset: float, out: float, back: float) -> None:
    ex = exchange_for(100.0, offset, out, back)
    assert abs(ex.offset - offset) <= ex.error_bound + 1e-9


# ------------------------------------------------------------ PaperEstimator


def test_estimator_empty() -> None:
    est = PaperEstimator()
    assert est.offset is None
    assert est.locked is False
    assert est.window == DEFAULT_WINDOW == 10.0
    assert est.statistic == "mean"


@pytest.mark.parametrize("statistic", ["max", "Mean", "", "avg"])
def test_estimator_rejects_unknown_statistic(statistic: str) -> None:
    with pytest.raises(ValueError, match="statistic"):
        PaperEstimator(statistic)  # type: ignore[arg-type]


@pytest.mark.parametrize("window", [0.0, -1.0, math.nan, -math.inf])
def test_estimator_rejects_bad_window(window: float) -> None:
    with pytest.raises(ValueError, match="window"):
        PaperEstimator(window=window)


@pytest.mark.parametrize("statistic", ["mean", "median"])
@pytest.mark.parametrize("offset", [PAPER_OFFSET, -PAPER_OFFSET, HARDWARE_OFFSET, -HARDWARE_OFFSET])
def test_estimator_recovers_offset_from_replayed_exchanges(statistic: str, offset: float) -> None:
    est = PaperEstimator(statistic)  # type: ignore[arg-type]
    for k in range(200):  # 20 s of requests every 100 ms: the window closes half way
        est.add(exchange_for(5.0 + 0.1 * k, offset, PAPER_DELAY))
    assert est.locked
    assert est.offset == pytest.approx(offset, abs=1e-9)


def test_estimator_mean_hand_computed() -> None:
    est = PaperEstimator("mean")
    for t2, off in [(0.0, 1.0), (1.0, 2.0), (2.0, 6.0)]:
        est.add(Exchange(t1=t2 - off, t2=t2, t3=t2 - off))  # offset == off exactly
    assert est.offset == 3.0


def test_estimator_median_hand_computed() -> None:
    est = PaperEstimator("median")
    for t2, off in [(0.0, 1.0), (1.0, 2.0), (2.0, 6.0), (3.0, 10.0)]:
        est.add(Exchange(t1=t2 - off, t2=t2, t3=t2 - off))
    assert est.offset == 4.0  # (2 + 6) / 2


def test_median_is_robust_to_one_outlier_and_mean_is_not() -> None:
    mean, median = PaperEstimator("mean"), PaperEstimator("median")
    exchanges = [exchange_for(0.1 * k, PAPER_OFFSET, PAPER_DELAY) for k in range(9)]
    # One burst (paper: every ~3 min): the reply is held up 2 s on the way back.
    exchanges.append(exchange_for(0.9, PAPER_OFFSET, PAPER_DELAY, back=PAPER_DELAY + 2.0))
    for ex in exchanges:
        mean.add(ex)
        median.add(ex)
    assert median.offset == pytest.approx(PAPER_OFFSET, abs=1e-9)
    assert mean.offset == pytest.approx(PAPER_OFFSET - 0.1, abs=1e-9)  # -(2 / 2) / 10
    assert mean.offset != pytest.approx(PAPER_OFFSET, abs=1e-3)


def test_estimate_is_usable_before_the_window_closes() -> None:
    est = PaperEstimator()
    est.add(exchange_for(0.0, PAPER_OFFSET, PAPER_DELAY))
    assert est.locked is False
    assert est.offset == pytest.approx(PAPER_OFFSET, abs=1e-9)


def test_estimate_held_after_window_closes() -> None:
    est = PaperEstimator("mean", window=10.0)
    for k in range(101):  # t2 from 0 to 10 s: all within the window
        est.add(Exchange(t1=0.1 * k, t2=0.1 * k + 5.0, t3=0.1 * k))
    assert est.locked is False
    assert est.offset == pytest.approx(5.0, abs=1e-9)
    # The first exchange past the window closes it; its own sample is not used.
    est.add(Exchange(t1=10.5, t2=10.5 + 99.0, t3=10.5))
    assert est.locked is True
    assert est.offset == pytest.approx(5.0, abs=1e-9)
    # Later samples, however different, change nothing.
    for k in range(50):
        est.add(Exchange(t1=20.0 + k, t2=1000.0 + k, t3=20.0 + k))
    assert est.locked is True
    assert est.offset == pytest.approx(5.0, abs=1e-9)


def test_window_counts_from_first_exchange_not_from_zero() -> None:
    est = PaperEstimator(window=10.0)
    est.add(Exchange(t1=0.0, t2=500.0, t3=0.0))  # window runs 500 .. 510 on the server
    est.add(Exchange(t1=9.0, t2=509.0, t3=9.0))
    assert est.locked is False
    est.add(Exchange(t1=11.0, t2=511.0, t3=11.0))
    assert est.locked is True
    assert est.offset == 500.0


def test_window_is_measured_on_t2_not_client_time() -> None:
    est = PaperEstimator(window=10.0)
    est.add(Exchange(t1=0.0, t2=100.0, t3=0.0))
    # Client time far past the window, server time inside it: still collecting.
    est.add(Exchange(t1=1000.0, t2=105.0, t3=1000.0))
    assert est.locked is False
    assert est.offset == pytest.approx((100.0 + (105.0 - 1000.0)) / 2)
    # Client time inside the window, server time past it: closes.
    est2 = PaperEstimator(window=10.0)
    est2.add(Exchange(t1=0.0, t2=100.0, t3=0.0))
    est2.add(Exchange(t1=1.0, t2=111.0, t3=1.0))
    assert est2.locked is True
    assert est2.offset == 100.0


def test_window_length_is_honoured() -> None:
    est = PaperEstimator(window=2.0)
    est.add(Exchange(0.0, 0.0, 0.0))
    est.add(Exchange(0.0, 1.5, 0.0))
    assert not est.locked
    est.add(Exchange(0.0, 2.5, 0.0))
    assert est.locked
    assert est.offset == 0.75


def test_estimator_reset() -> None:
    est = PaperEstimator("median", window=1.0)
    est.add(Exchange(0.0, 10.0, 0.0))
    est.add(Exchange(0.0, 12.0, 0.0))
    assert est.locked
    est.reset()
    assert est.offset is None
    assert est.locked is False
    # A new window starts at the next exchange.
    est.add(Exchange(0.0, -50.0, 0.0))
    est.add(Exchange(0.0, -49.5, 0.0))
    assert not est.locked
    assert est.offset == -49.75
    assert est.statistic == "median"
    assert est.window == 1.0


# --------------------------------------------------------------- SyncClient


def make_client(timeout: float = 0.5, **kwargs: int) -> SyncClient:
    return SyncClient(PaperEstimator("median"), timeout=timeout, **kwargs)


def reply_to(request: bytes, t2: float, pose: Pose | None = None) -> bytes:
    return wire.encode_reply(wire.decode_request(request), t2, pose or Pose())


@pytest.mark.parametrize("timeout", [0.0, -0.5, math.nan])
def test_client_rejects_bad_timeout(timeout: float) -> None:
    with pytest.raises(ValueError, match="timeout"):
        SyncClient(PaperEstimator(), timeout=timeout)


def test_fresh_client() -> None:
    client = make_client()
    assert client.sent == client.accepted == client.timeouts == client.pending == 0
    assert not client.rejected
    assert client.offset is None
    assert client.delay is None
    assert client.last is None
    assert client.last_rejection is None


def test_request_payload_is_t1_now() -> None:
    client = make_client()
    payload = client.request(12.25)
    assert payload == bytes.fromhex("0000000000802840")  # 12.25 as <d
    assert len(payload) == wire.REQUEST_SIZE
    assert client.sent == 1
    assert client.pending == 1


def test_accepted_reply_builds_exchange_and_feeds_estimator() -> None:
    client = make_client()
    request = client.request(1.0)
    pose = Pose(x=3.0, heading=0.25)
    got = client.receive(reply_to(request, 27.5, pose), now=1.5)
    assert got == wire.SyncReply(1.0, 27.5, pose)
    assert client.last == Exchange(1.0, 27.5, 1.5)
    assert client.accepted == 1
    assert client.pending == 0
    assert client.delay == 0.25
    # Held back until three exchanges agree (a wild first one must not be the estimate).
    assert client.offset is None
    for t in (2.0, 3.0):
        client.receive(reply_to(client.request(t), t + 26.5), now=t + 0.5)
    assert client.accepted == 3
    assert client.offset == 26.25
    assert client.estimator.offset == 26.25
    assert client.last_rejection is None


def test_replies_matched_by_t1_out_of_order() -> None:
    client = make_client(timeout=1.0)
    first = client.request(0.0)
    second = client.request(0.125)
    third = client.request(0.25)
    # Replies come back in reverse order; each is matched to its own request.
    assert client.receive(reply_to(third, 10.375), now=0.5) is not None
    assert client.last == Exchange(0.25, 10.375, 0.5)
    assert client.receive(reply_to(first, 10.0), now=0.5) is not None
    assert client.last == Exchange(0.0, 10.0, 0.5)
    assert client.receive(reply_to(second, 10.25), now=0.5) is not None
    assert client.last == Exchange(0.125, 10.25, 0.5)
    assert client.accepted == 3
    assert client.pending == 0
    assert not client.rejected


def test_t1_unique_when_clock_repeats() -> None:
    client = make_client()
    a = wire.decode_request(client.request(5.0))
    b = wire.decode_request(client.request(5.0))
    c = wire.decode_request(client.request(5.0))
    assert a == 5.0
    assert a < b < c
    assert b == math.nextafter(5.0, math.inf)
    assert client.pending == 3
    # Each reply finds its own request.
    for t1 in (c, a, b):
        assert client.receive(wire.encode_reply(t1, 6.0, Pose()), now=5.25) is not None
    assert client.accepted == 3
    assert not client.rejected


def test_t1_unique_when_clock_steps_back() -> None:
    client = make_client()
    a = wire.decode_request(client.request(5.0))
    b = wire.decode_request(client.request(4.0))
    assert b > a
    c = wire.decode_request(client.request(6.0))
    assert c == 6.0  # a clock ahead again is used as is


def test_duplicate_reply_rejected() -> None:
    client = make_client()
    request = client.request(1.0)
    reply = reply_to(request, 2.0)
    assert client.receive(reply, now=1.25) is not None
    assert client.receive(reply, now=1.25) is None
    assert client.rejected["duplicate"] == 1
    assert client.last_rejection == "duplicate"
    assert client.accepted == 1
    assert client.last == Exchange(1.0, 2.0, 1.25)


def test_duplicate_does_not_feed_estimator_twice() -> None:
    client = SyncClient(PaperEstimator("mean"), timeout=1.0)
    r1 = client.request(0.0)
    r2 = client.request(0.25)
    r3 = client.request(0.375)
    client.receive(reply_to(r1, 10.0), now=0.5)  # offset 9.75
    client.receive(reply_to(r2, 10.0), now=0.5)  # offset 9.625
    client.receive(reply_to(r3, 10.0), now=0.5)  # offset 9.5625
    for _ in range(5):
        client.receive(reply_to(r1, 10.0), now=0.5)
    assert client.rejected["duplicate"] == 5
    assert client.offset == pytest.approx((9.75 + 9.625 + 9.5625) / 3)


def test_unmatched_reply_rejected() -> None:
    client = make_client()
    client.request(1.0)
    assert client.receive(wire.encode_reply(0.75, 2.0, Pose()), now=1.25) is None
    assert client.rejected["unmatched"] == 1
    assert client.last_rejection == "unmatched"
    assert client.pending == 1  # the real request is still waiting
    assert client.accepted == 0
    assert client.offset is None


def test_reply_without_any_request_is_unmatched() -> None:
    client = make_client()
    assert client.receive(wire.encode_reply(1.0, 2.0, Pose()), now=1.0) is None
    assert client.rejected == {"unmatched": 1}


def test_late_reply_after_expire() -> None:
    client = make_client(timeout=0.5)
    request = client.request(0.0)
    client.expire(0.75)
    assert client.timeouts == 1
    assert client.pending == 0
    assert client.receive(reply_to(request, 1.0), now=0.75) is None
    assert client.rejected["late"] == 1
    assert client.last_rejection == "late"
    assert client.accepted == 0
    assert client.offset is None
    assert client.delay is None


def test_late_reply_without_expire() -> None:
    client = make_client(timeout=0.5)
    request = client.request(0.0)
    reply = reply_to(request, 1.0)
    assert client.receive(reply, now=0.75) is None
    assert client.rejected["late"] == 1
    assert client.pending == 0
    assert client.accepted == 0
    assert client.offset is None
    # The same reply again is still late, not unmatched.
    assert client.receive(reply, now=0.875) is None
    assert client.rejected["late"] == 2
    assert client.rejected["unmatched"] == 0


def test_reply_exactly_at_timeout_accepted() -> None:
    client = make_client(timeout=0.5)
    request = client.request(1.0)
    client.expire(1.5)
    assert client.timeouts == 0
    assert client.receive(reply_to(request, 3.0), now=1.5) is not None
    assert client.accepted == 1


def test_expire_keeps_fresh_requests() -> None:
    client = make_client(timeout=0.5)
    old = client.request(0.0)
    fresh = client.request(0.5)
    client.expire(0.75)
    assert client.timeouts == 1
    assert client.pending == 1
    assert client.receive(reply_to(old, 1.0), now=0.75) is None
    assert client.receive(reply_to(fresh, 1.0), now=0.75) is not None
    assert client.rejected == {"late": 1}


def test_request_expires_old_ones() -> None:
    client = make_client(timeout=0.5)
    client.request(0.0)
    client.request(0.25)
    client.request(0.5)
    assert client.timeouts == 0
    client.request(1.0)  # 0.0 and 0.25 are older than 0.5 s
    assert client.timeouts == 2
    assert client.pending == 2
    client.request(10.0)
    assert client.timeouts == 4
    assert client.pending == 1
    assert client.sent == 5


def test_expire_is_idempotent() -> None:
    client = make_client(timeout=0.5)
    client.request(0.0)
    client.expire(2.0)
    client.expire(2.0)
    client.expire(3.0)
    assert client.timeouts == 1


def test_timeouts_count_same_whether_or_not_expire_ran() -> None:
    """A reply after the timeout is late, and its request a timeout, in either call order."""
    expired_first = make_client(timeout=0.5)
    request = expired_first.request(0.0)
    expired_first.expire(1.0)
    expired_first.receive(reply_to(request, 5.0), now=1.0)

    not_expired = make_client(timeout=0.5)
    request = not_expired.request(0.0)
    not_expired.receive(reply_to(request, 5.0), now=1.0)
    not_expired.expire(1.0)

    assert expired_first.rejected == not_expired.rejected == {"late": 1}
    assert not_expired.sent == not_expired.accepted + not_expired.timeouts + not_expired.pending
    assert expired_first.timeouts == not_expired.timeouts


@pytest.mark.parametrize(
    "payload",
    [
        pytest.param(bytes(63), id="63 bytes"),
        pytest.param(bytes(65), id="65 bytes"),
        pytest.param(b"", id="empty"),
        pytest.param(wire.encode_request(1.0), id="a request"),
        pytest.param(
            wire.encode_reply(1.0, 2.0, Pose())[:8] + bytes.fromhex("000000000000f87f") + bytes(48),
            id="NaN t2",
        ),
        pytest.param(
            wire.encode_reply(1.0, 2.0, Pose())[:56] + bytes.fromhex("000000000000f07f"),
            id="inf omega",
        ),
    ],
)
def test_malformed_reply_rejected(payload: bytes) -> None:
    client = make_client()
    client.request(1.0)
    assert client.receive(payload, now=1.25) is None
    assert client.rejected == {"malformed": 1}
    assert client.last_rejection == "malformed"
    assert client.pending == 1
    assert client.accepted == 0


def test_malformed_does_not_spoil_the_real_reply() -> None:
    client = make_client()
    request = client.request(1.0)
    good = reply_to(request, 2.0)
    client.receive(good[:63], now=1.125)
    assert client.receive(good, now=1.25) is not None
    assert client.accepted == 1
    assert client.rejected == {"malformed": 1}


def test_last_rejection_tracks_the_latest() -> None:
    client = make_client()
    request = client.request(1.0)
    reply = reply_to(request, 2.0)
    client.receive(bytes(3), now=1.0)
    assert client.last_rejection == "malformed"
    client.receive(wire.encode_reply(99.0, 2.0, Pose()), now=1.0)
    assert client.last_rejection == "unmatched"
    client.receive(reply, now=1.25)
    client.receive(reply, now=1.25)
    assert client.last_rejection == "duplicate"
    assert client.rejected == {"malformed": 1, "unmatched": 1, "duplicate": 1}


def test_delay_is_median_of_recent_delays() -> None:
    client = make_client(timeout=10.0)
    for k, round_trip in enumerate([0.08, 0.1, 4.0, 0.06, 0.09]):
        t1 = float(10 * k)
        request = client.request(t1)
        client.receive(reply_to(request, t1), now=t1 + round_trip)
    # One-way delays 0.04 0.05 2.0 0.03 0.045: median 0.045, the outlier ignored.
    assert client.delay == pytest.approx(0.045, abs=1e-12)
    assert client.delay == pytest.approx(statistics.median([0.04, 0.05, 2.0, 0.03, 0.045]))


def test_delay_window_keeps_only_recent() -> None:
    client = SyncClient(PaperEstimator(), timeout=100.0, delay_window=3)
    for k, round_trip in enumerate([10.0, 10.0, 10.0, 0.2, 0.4, 0.6]):
        t1 = float(100 * k)
        request = client.request(t1)
        client.receive(reply_to(request, t1), now=t1 + round_trip)
    assert client.delay == pytest.approx(0.2, abs=1e-9)  # median of 0.1, 0.2, 0.3


def test_client_reset() -> None:
    client = make_client(timeout=1.0)
    for t in (0.0, 0.05, 0.1):
        client.receive(reply_to(client.request(t), t + 30.0), now=t + 0.25)
    client.receive(bytes(1), now=0.25)
    r2 = client.request(0.5)
    assert client.offset is not None
    assert client.delay is not None
    client.reset()
    assert client.offset is None
    assert client.delay is None
    assert client.last is None
    assert client.pending == 0
    assert client.estimator.offset is None
    # Counters are kept.
    assert client.sent == 4
    assert client.accepted == 3
    assert client.rejected == {"malformed": 1}
    # A reply to a request sent before the reset is no longer matched.
    assert client.receive(reply_to(r2, 30.5), now=0.75) is None
    assert client.rejected["unmatched"] == 1
    # New exchanges work and give a fresh estimate.
    r3 = client.request(1.0)
    assert wire.decode_request(r3) == 1.0
    assert client.receive(reply_to(r3, -5.0), now=1.5) is not None
    for t in (2.0, 3.0):  # three that agree: the estimate
        client.receive(reply_to(client.request(t), t - 6.0), now=t + 0.5)
    assert client.offset == -6.25


def test_reset_keeps_t1_unique() -> None:
    client = make_client()
    a = wire.decode_request(client.request(5.0))
    client.reset()
    b = wire.decode_request(client.request(5.0))
    assert b > a


# ------------------------------------------------- client with in-memory server


@pytest.mark.parametrize("offset", [PAPER_OFFSET, -PAPER_OFFSET, -HARDWARE_OFFSET])
@pytest.mark.parametrize("statistic", ["mean", "median"])
def test_client_recovers_offset_through_memory_network(offset: float, statistic: str) -> None:
    client = SyncClient(PaperEstimator(statistic), timeout=0.5)  # type: ignore[arg-type]
    server = MemoryServer(offset)
    link = MemoryLink(client, server, out=PAPER_DELAY, back=PAPER_DELAY, period=0.1)
    link.run(duration=15.0, start=3.0)
    assert server.requests == 150
    assert client.sent == 150
    assert client.accepted == 150
    assert client.timeouts == 0
    assert not client.rejected
    assert client.estimator.locked
    assert client.offset == pytest.approx(offset, abs=1e-9)
    assert client.delay == pytest.approx(PAPER_DELAY, abs=1e-9)
    assert link.accepted_replies[0].pose == server.pose


def test_client_in_memory_round_trip_longer_than_period() -> None:
    # Round trip 0.3 s with requests every 0.1 s: three requests always in flight.
    client = make_client(timeout=0.5)
    link = MemoryLink(client, MemoryServer(-PAPER_OFFSET), out=0.15, back=0.15)
    link.run(duration=2.0)
    assert client.accepted == 20
    assert client.offset == pytest.approx(-PAPER_OFFSET, abs=1e-9)
    assert client.delay == pytest.approx(0.15, abs=1e-9)


def test_client_in_memory_with_loss_and_duplicates() -> None:
    client = make_client(timeout=0.5)
    link = MemoryLink(
        client,
        MemoryServer(PAPER_OFFSET),
        drop_reply={3, 7, 8},
        duplicate_reply={1, 5},
    )
    link.run(duration=3.0)
    client.expire(100.0)
    assert client.sent == 30
    assert client.accepted == 27
    assert client.timeouts == 3
    assert client.rejected == {"duplicate": 2}
    assert client.offset == pytest.approx(PAPER_OFFSET, abs=1e-9)


def test_client_in_memory_replies_too_slow_are_late() -> None:
    client = make_client(timeout=0.5)
    link = MemoryLink(client, MemoryServer(PAPER_OFFSET), out=0.3, back=0.3)
    link.run(duration=1.0)
    assert client.accepted == 0
    assert client.rejected["late"] == 10
    assert client.offset is None


def test_client_in_memory_asymmetric_path_within_bound() -> None:
    client = make_client(timeout=0.5)
    link = MemoryLink(client, MemoryServer(PAPER_OFFSET), out=0.030, back=0.050)
    link.run(duration=2.0)
    assert client.last is not None
    error = client.offset - PAPER_OFFSET  # type: ignore[operator]
    assert error == pytest.approx(-0.010, abs=1e-9)
    assert abs(error) <= client.last.error_bound


@given(
    offset=st.floats(-1e4, 1e4),
    delay=st.floats(1e-4, 0.2),
    start=st.floats(0.0, 1e3),
)
def test_client_recovers_any_offset_with_symmetric_delay(
    offset: float, delay: float, start: float
) -> None:
    client = make_client(timeout=0.5)
    MemoryLink(client, MemoryServer(offset), out=delay, back=delay).run(duration=1.0, start=start)
    assert client.accepted == 10
    assert client.offset == pytest.approx(offset, abs=1e-9)
    assert client.delay == pytest.approx(delay, abs=1e-9)


def test_sync_client_needs_a_delay_window() -> None:
    with pytest.raises(ValueError, match="delay_window"):
        SyncClient(PaperEstimator(), delay_window=0)


def _exchanges(offset: float, start: float, n: int, delay: float = 0.02) -> list[Exchange]:
    return [
        Exchange(t, t + delay + offset, t + 2 * delay) for t in (start + 0.1 * k for k in range(n))
    ]


def _feed(client: SyncClient, exchanges: list[Exchange]) -> None:
    for ex in exchanges:
        client.request(ex.t1)
        client.receive(encode_reply(ex.t1, ex.t2, Pose()), ex.t3)


def test_clock_step_is_detected_and_the_estimate_restarts() -> None:
    client = SyncClient(ClockFilter(), timeout=1.0)
    _feed(client, _exchanges(26.42, 0.0, 50))
    assert client.offset_at(5.0) == pytest.approx(26.42, abs=1e-9)
    _feed(client, _exchanges(26.92, 5.0, 2))  # the server's clock jumped 0.5 s
    assert client.steps == 0 and client.rejected["inconsistent"] == 2
    _feed(client, _exchanges(26.92, 5.2, 1))  # the third in a row confirms it
    assert client.steps == 1 and client.last_step == pytest.approx(0.5)
    _feed(client, _exchanges(26.92, 5.3, 20))
    assert client.offset_at(7.0) == pytest.approx(26.92, abs=1e-9)


def test_a_single_impossible_exchange_is_rejected_not_a_step() -> None:
    client = SyncClient(ClockFilter(), timeout=1.0)
    _feed(client, _exchanges(1.0, 0.0, 30))
    _feed(client, _exchanges(1.3, 3.0, 1))
    _feed(client, _exchanges(1.0, 3.1, 10))
    assert client.steps == 0 and client.rejected["inconsistent"] == 1
    assert client.offset_at(4.0) == pytest.approx(1.0, abs=1e-9)


def test_jitter_within_the_error_bounds_is_no_step() -> None:
    client = SyncClient(ClockFilter(), timeout=1.0)
    rng = random.Random(3)
    for k in range(300):
        t1 = 0.1 * k
        out, back = 0.04 + rng.expovariate(1 / 0.01), 0.04 + rng.expovariate(1 / 0.01)
        client.request(t1)
        client.receive(encode_reply(t1, t1 + out + 5.0, Pose()), t1 + out + back)
    assert client.steps == 0 and client.rejected["inconsistent"] == 0


def test_own_clock_going_back_rejects_the_reply() -> None:
    client = SyncClient(ClockFilter(), timeout=1.0)
    payload = client.request(10.0)
    assert payload
    assert client.receive(encode_reply(10.0, 12.0, Pose()), 9.0) is None
    assert client.rejected["clock_step"] == 1


# ------------------------------------------------------------------ the server half


def test_serve_echoes_t1_stamps_t2_and_attaches_the_send_time() -> None:
    client = SyncClient(PaperEstimator(), timeout=1.0)
    request = client.request(10.0)
    pose = Pose(1.0, 2.0, 0.5, 0.1, 0.2, 0.01)
    # 40 ms each way, 0.5 ms turnaround, the server 26.42 s ahead (the paper's figures).
    served = serve(request, t2=36.46, pose=pose, now=36.4605)
    assert len(served.payload) == wire.REPLY_SIZE and len(served.attachment) == 8
    assert wire.decode_reply(served.payload) == wire.SyncReply(10.0, 36.46, pose)
    assert read_send_time(served.attachment) == 36.4605
    # The client turns both into a four-timestamp exchange.
    t2s = read_send_time(served.attachment)
    assert client.receive(served.payload, 10.0805, t2s) is not None
    assert client.last == Exchange(10.0, 36.46, 10.0805, 36.4605)
    assert client.last.offset == pytest.approx(26.42, abs=1e-9)
    assert client.last.delay == pytest.approx(0.04, abs=1e-9)


@pytest.mark.parametrize("request_", [b"", bytes(7), bytes(9), bytes.fromhex("000000000000f87f")])
def test_serve_refuses_a_malformed_request(request_: bytes) -> None:
    with pytest.raises(wire.DecodeError):
        serve(request_, 1.0, Pose(), 1.0)


def test_read_send_time_refuses_what_is_not_a_time() -> None:
    with pytest.raises(wire.DecodeError):
        read_send_time(bytes(3))


@given(
    st.lists(
        st.tuples(
            st.floats(0.0, 0.2),  # round trip (s)
            st.sampled_from(["reply", "reset", "step"]),
        ),
        min_size=1,
        max_size=120,
    )
)
def test_delay_is_the_median_of_the_recent_exchanges_after_every_change(
    events: list[tuple[float, str]],
) -> None:
    """The median is kept between reads, not recomputed at each (issue 17): it must
    follow every exchange accepted, a reset and a clock step's restart."""
    client = make_client(timeout=1.0, delay_window=7)
    now, offset = 100.0, 5.0
    for rtt, what in events:
        if what == "reset":
            client.reset()
        elif what == "step":
            offset += 3.0  # the server's clock jumps: a step after STEP_CONFIRM replies
        request = client.request(now)
        client.receive(reply_to(request, now + rtt / 2 + offset), now=now + rtt)
        expected = statistics.median(client._delays._order) if client._delays._order else None
        assert client.delay == expected
        now += 0.5


@given(
    st.lists(st.floats(-1.0, 1.0) | st.sampled_from([0.0, 0.5]), min_size=1, max_size=80),
    st.integers(1, 9),
)
def test_the_running_median_is_the_windows_median_after_every_value(
    values: list[float], window: int
) -> None:
    from collections import deque

    from federation.core.sync import _Median

    median, recent = _Median(window), deque[float](maxlen=window)
    assert median.median is None
    for k, value in enumerate(values):
        median.add(value)
        recent.append(value)
        assert median.median == statistics.median(recent)
        if k == len(values) // 2:
            median.clear()
            recent.clear()
            assert median.median is None


def test_a_clock_step_starts_the_delay_median_again_from_the_suspect_exchanges() -> None:
    client = SyncClient(ClockFilter(), timeout=1.0, delay_window=50)
    for k in range(20):  # one-way delay 50 ms
        t1 = 0.1 * k
        client.request(t1)
        client.receive(encode_reply(t1, t1 + 0.05 + 3.0, Pose()), t1 + 0.1)
    assert client.delay == pytest.approx(0.05)
    for k in range(SyncClient.STEP_CONFIRM):  # the server's clock jumps 1 s; delay 10 ms
        t1 = 5.0 + 0.1 * k
        client.request(t1)
        client.receive(encode_reply(t1, t1 + 0.01 + 4.0, Pose()), t1 + 0.02)
    assert client.steps == 1
    # Only the exchanges since the step: with the 20 before it the median stays 50 ms.
    assert client.delay == pytest.approx(0.01)


def test_a_reply_whose_offset_overflows_is_rejected_and_changes_nothing() -> None:
    client = make_client(timeout=10.0)
    request = client.request(-1.7e308)
    assert client.receive(reply_to(request, 1.7e308), now=-1.7e308 + 0.1) is None
    assert client.last_rejection == "malformed" and client.accepted == 0
    assert client.delay is None and client.offset is None


def test_a_running_median_of_no_values_is_refused() -> None:
    from federation.core.sync import _Median

    with pytest.raises(ValueError, match="at least 1"):
        _Median(0)


# -- a wild reply among the first ones --------------------------------------------------
def _one_a_tenth(client: SyncClient, offsets: list[float], t: float = 100.0) -> float:
    """One exchange per offset (server clock ``offset`` ahead, 10 ms round trip), 0.1 s
    apart; the client's time after the last."""
    for offset in offsets:
        t1 = wire.decode_request(client.request(t))
        client.receive(encode_reply(t1, t1 + 0.005 + offset, Pose()), t + 0.01)
        t += 0.1
    return t


@pytest.mark.parametrize("estimator", ["mean", "median", "clockfilter"])
@pytest.mark.parametrize("wild_at", [0, 1, 2])
def test_one_wild_reply_among_the_first_never_reaches_the_estimate(
    estimator: str, wild_at: int
) -> None:
    # The paper's window, on the server's clock, once started at a first reply 10 s
    # behind and closed at the next: offset -10 s, locked, bound 0, for good.
    client = SyncClient(make_estimator(estimator, 10.0))
    offsets = [0.0] * 150
    offsets[wild_at] = -10.0
    t = _one_a_tenth(client, offsets)
    offset = client.offset_at(t)
    assert offset is not None and abs(offset) < 0.001, offset
    assert client.rejected["inconsistent"] == 1
    assert client.accepted == 149
    assert client.estimator.locked


def test_a_reply_centuries_off_is_rejected_and_the_estimate_stays_finite() -> None:
    client = SyncClient(make_estimator("clockfilter", 10.0))
    t = _one_a_tenth(client, [0.0] * 5)
    for t2 in (1e300, 1e200, 1e15, -1e11):
        t1 = wire.decode_request(client.request(t))
        assert client.receive(encode_reply(t1, t2, Pose()), t + 0.01) is None
        assert client.last_rejection == "implausible"
        t += 0.1
    offset = client.offset_at(t)
    assert offset is not None and math.isfinite(offset) and abs(offset) < 0.001
    # Clocks on the Unix epoch against one that starts at 0: a real offset.
    far = SyncClient(make_estimator("clockfilter", 10.0))
    t = _one_a_tenth(far, [1.8e9] * 5)
    assert far.offset_at(t) == pytest.approx(1.8e9, abs=1e-3)


@pytest.mark.parametrize("estimator", ["mean", "median", "clockfilter"])
def test_the_wild_first_reply_is_never_the_estimate_even_briefly(estimator: str) -> None:
    client = SyncClient(make_estimator(estimator, 10.0))
    t = 100.0
    seen = []
    for offset in [-10.0, 0.0, 0.0, 0.0]:
        t = _one_a_tenth(client, [offset], t)
        seen.append(client.offset_at(t))
    assert seen[:2] == [None, None]  # held back until three agree
    assert all(abs(o) < 0.001 for o in seen[2:] if o is not None) and seen[3] is not None


@pytest.mark.parametrize("estimator", ["mean", "median", "clockfilter"])
def test_a_clock_step_during_the_warm_up_does_not_jam_the_client(estimator: str) -> None:
    # Two exchanges before a 2 s step outvoted every one after it, for good.
    client = SyncClient(make_estimator(estimator, 10.0))
    t = _one_a_tenth(client, [0.0, 0.0] + [2.0] * 20)
    offset = client.offset_at(t)
    assert offset is not None and abs(offset - 2.0) < 0.001, offset
    assert client.steps == 1 and client.rejected["inconsistent"] == 2
