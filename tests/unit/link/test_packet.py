"""The packet stage (federation/link/packet.py): IPv4 parsing, ICMP errors, loss
runs, MTU, rate, cuts and delivery order, on injected times."""

from __future__ import annotations

import random
import struct

import pytest

from federation.link.packet import (
    PacketOptions,
    PacketPath,
    PacketStage,
    checksum,
    frag_needed,
    gilbert,
    parse_ipv4,
)

KIRUNA_NET = "203.0.113.0/24"


def ipv4(src: str, dst: str, size: int = 60, df: bool = True, proto: int = 6) -> bytes:
    """A minimal IPv4 packet of ``size`` bytes with a valid header checksum."""
    import ipaddress

    head = struct.pack(
        "!BBHHHBBH4s4s", 0x45, 0, size, 1, 0x4000 if df else 0, 64, proto, 0,
        ipaddress.IPv4Address(src).packed, ipaddress.IPv4Address(dst).packed,
    )  # fmt: skip
    head = head[:10] + struct.pack("!H", checksum(head)) + head[12:]
    return head + bytes(size - 20)


def test_parse_ipv4_reads_the_fields() -> None:
    head = parse_ipv4(ipv4("198.51.100.2", "203.0.113.10", 100))
    assert (head.src, head.dst, head.protocol, head.length) == (
        "198.51.100.2", "203.0.113.10", 6, 100,
    )  # fmt: skip
    assert head.dont_fragment and head.header_length == 20


@pytest.mark.parametrize(
    ("packet", "reason"),
    [
        (b"\x45" * 10, "shorter"),
        (b"\x60" + bytes(39), "version 6"),
        (b"\x41" + bytes(19), "length"),
    ],
)
def test_parse_ipv4_refuses_what_is_not_ipv4(packet: bytes, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        parse_ipv4(packet)


def test_checksum_of_a_header_with_its_checksum_is_zero() -> None:
    assert checksum(ipv4("192.0.2.10", "203.0.113.10")[:20]) == 0


def test_frag_needed_is_a_valid_icmp_error_back_to_the_sender() -> None:
    packet = ipv4("198.51.100.2", "203.0.113.10", 1400)
    reply = frag_needed(packet, 576, "198.51.100.1")
    head = parse_ipv4(reply)
    assert (head.src, head.dst, head.protocol) == ("198.51.100.1", "198.51.100.2", 1)
    assert checksum(reply[:20]) == 0 and checksum(reply[20:]) == 0
    icmp_type, code, _, _, mtu = struct.unpack_from("!BBHHH", reply, 20)
    assert (icmp_type, code, mtu) == (3, 4, 576)
    assert reply[28:] == packet[:28]  # the offending header and 8 bytes of its data


@pytest.mark.parametrize(("loss", "burst"), [(0.05, 1.0), (0.05, 4.0), (0.2, 3.0)])
def test_the_gilbert_model_loses_the_asked_fraction_in_runs_of_the_asked_length(
    loss: float, burst: float
) -> None:
    path = PacketPath(PacketOptions(loss=loss, loss_burst=burst), random.Random(7))
    lost = [path._lost() for _ in range(200_000)]
    runs, current = [], 0
    for x in lost:
        if x:
            current += 1
        elif current:
            runs.append(current)
            current = 0
    assert sum(lost) / len(lost) == pytest.approx(loss, rel=0.05)
    # Runs merge when a new one starts right after: slightly longer than asked.
    assert sum(runs) / len(runs) == pytest.approx(burst / (1 - gilbert(loss, burst)[0]), rel=0.05)


def test_gilbert_edges() -> None:
    assert gilbert(0.0, 3.0) == (0.0, 1.0)
    assert gilbert(1.0, 1.0) == (1.0, 0.0)
    assert gilbert(0.1, 1.0) == (pytest.approx(0.1), 1.0)


def test_delivery_is_in_order_after_delay_and_jitter() -> None:
    stage = PacketStage(PacketOptions(delay=0.04, jitter=0.003), forward_net=KIRUNA_NET, seed=3)
    times = []
    for k in range(500):
        verdict = stage.offer(ipv4("198.51.100.2", "203.0.113.10"), k * 0.001)
        assert verdict.at is not None and verdict.at >= k * 0.001 + 0.04
        times.append(verdict.at)
    assert times == sorted(times)
    assert stage.forward.counters.delivered == 500 and stage.backward.counters.offered == 0


def test_due_pops_packets_in_delivery_order_only_when_due() -> None:
    stage = PacketStage(PacketOptions(delay=0.05), forward_net=KIRUNA_NET)
    a, b = ipv4("198.51.100.2", "203.0.113.10", 60), ipv4("203.0.113.10", "198.51.100.2", 70)
    stage.offer(a, 0.0)
    stage.offer(b, 0.01)
    assert stage.next_due() == pytest.approx(0.05)
    assert stage.due(0.049) == []
    assert stage.due(0.05) == [a]
    assert stage.due(1.0) == [b]
    assert len(stage) == 0 and stage.next_due() is None


def test_direction_by_destination() -> None:
    stage = PacketStage(
        PacketOptions(delay=0.01), PacketOptions(delay=0.03), forward_net=KIRUNA_NET
    )
    to_kiruna = stage.offer(ipv4("198.51.100.2", "203.0.113.10"), 0.0)
    to_rome = stage.offer(ipv4("203.0.113.10", "198.51.100.2"), 0.0)
    assert to_kiruna.at == pytest.approx(0.01) and to_rome.at == pytest.approx(0.03)


def test_mtu_with_icmp_answers_and_without_is_a_black_hole() -> None:
    big = ipv4("198.51.100.2", "203.0.113.10", 1500)
    answering = PacketStage(
        PacketOptions(delay=0.04, mtu=576), forward_net=KIRUNA_NET, router="198.51.100.1"
    )
    verdict = answering.offer(big, 0.0)
    assert verdict.drop == "mtu" and verdict.reply is not None
    assert answering.due(1.0) == [verdict.reply]  # sent back after the backward delay
    silent = PacketStage(
        PacketOptions(delay=0.04, mtu=576, icmp=False), forward_net=KIRUNA_NET, router="x"
    )
    verdict = silent.offer(big, 0.0)
    assert verdict.drop == "mtu" and verdict.reply is None and silent.due(1.0) == []
    small = silent.offer(ipv4("198.51.100.2", "203.0.113.10", 576), 0.0)
    assert small.at is not None


def test_mtu_never_answers_an_icmp_packet_nor_one_that_may_be_fragmented() -> None:
    stage = PacketStage(PacketOptions(mtu=576), forward_net=KIRUNA_NET, router="198.51.100.1")
    assert stage.offer(ipv4("198.51.100.2", "203.0.113.10", 1000, proto=1), 0).reply is None
    assert stage.offer(ipv4("198.51.100.2", "203.0.113.10", 1000, df=False), 0).reply is None


def test_a_cut_drops_everything_until_restored_and_on_schedule() -> None:
    stage = PacketStage(PacketOptions(cuts=((1.0, 2.0),)), forward_net=KIRUNA_NET)
    p = ipv4("198.51.100.2", "203.0.113.10")
    assert stage.offer(p, 0.5).at is not None
    assert stage.offer(p, 1.0).drop == "cut"
    assert stage.offer(p, 2.99).drop == "cut"
    assert stage.offer(p, 3.0).at is not None
    stage.set_cut(True)
    assert stage.offer(p, 10.0).drop == "cut"
    stage.set_cut(False)
    assert stage.offer(p, 10.1).at is not None


def test_the_bottleneck_serializes_and_tail_drops() -> None:
    opts = PacketOptions(rate=10_000.0, queue=3000)  # 10 kB/s, 3 kB FIFO
    stage = PacketStage(opts, forward_net=KIRUNA_NET)
    p = ipv4("198.51.100.2", "203.0.113.10", 1000)
    ats = [stage.offer(p, 0.0).at for _ in range(3)]
    assert ats == [pytest.approx(0.1), pytest.approx(0.2), pytest.approx(0.3)]
    assert stage.offer(p, 0.0).drop == "queue"
    assert stage.offer(p, 0.15).at == pytest.approx(0.4)  # room again


def test_reordering_lets_later_packets_overtake() -> None:
    stage = PacketStage(
        PacketOptions(delay=0.01, reorder=0.5, reorder_extra=0.02),
        forward_net=KIRUNA_NET,
        seed=1,
    )
    ats = [stage.offer(ipv4("198.51.100.2", "203.0.113.10"), k * 0.001).at for k in range(200)]
    assert ats != sorted(ats)
    assert stage.forward.counters.reordered > 50


def test_malformed_packets_are_counted_not_raised() -> None:
    stage = PacketStage(PacketOptions(), forward_net=KIRUNA_NET)
    assert stage.offer(b"\x60" + bytes(60), 0.0).drop == "malformed"
    assert stage.snapshot()["malformed"] == 1


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        ("delay", {"delay": -1.0}),
        ("loss", {"loss": 1.5}),
        ("loss_burst", {"loss_burst": 0.5}),
        ("mtu", {"mtu": 40}),
        ("queue", {"queue": -1}),
        ("cuts", {"cuts": ((1.0, 0.0),)}),
        ("rate", {"rate": float("inf")}),
    ],
)
def test_bad_options_name_the_field(field: str, kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError, match=field):
        PacketOptions(**kwargs)  # type: ignore[arg-type]


def test_a_seed_reproduces_the_draws() -> None:
    def run(seed: int) -> list[float | None]:
        stage = PacketStage(
            PacketOptions(delay=0.04, jitter=0.005, loss=0.1), forward_net=KIRUNA_NET, seed=seed
        )
        return [stage.offer(ipv4("198.51.100.2", "203.0.113.10"), k * 0.01).at for k in range(100)]

    assert run(5) == run(5) and run(5) != run(6)
