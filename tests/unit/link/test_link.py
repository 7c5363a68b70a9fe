"""The link emulator without processes: the pure model's statistics and delivery
times, the settings (schemas.link) and the ``fedlab link`` flags.

The relay itself, live on loopback, is in tests/integration/test_link_processes.py.
"""

from __future__ import annotations

import argparse
import ast
import itertools
import math
import random
import socket
import statistics
from pathlib import Path
from typing import Any

import pytest

import federation.link.model
import federation.link.stats
import schemas.link
from federation import cli
from federation.cli import link as link_cli
from federation.cli.link import options_from_args
from federation.link import (
    PARETO_SHAPE,
    DatagramScheduler,
    DirectionConfig,
    DirectionModel,
    LinkEndpoint,
    LinkModel,
    LinkOptions,
    StreamScheduler,
    datagram_deliver_at,
    parse_endpoint,
    stream_deliver_at,
)
from schemas.config import ConfigError, validate

N = 20_000


def main(args: list[str]) -> int:
    """``fedlab link ARGS`` in this process."""
    return cli.main(["link", *args])


def direction(**kw: Any) -> DirectionModel:
    return DirectionModel(DirectionConfig(**kw), random.Random(1234))


def binomial_ok(k: int, n: int, p: float, sigmas: float = 5.0) -> bool:
    return abs(k - n * p) <= sigmas * math.sqrt(n * p * (1 - p)) + 1


# -- pure model -----------------------------------------------------------------
@pytest.mark.parametrize(
    ("dist", "mean_factor", "std_factor"),
    [("normal", math.sqrt(2 / math.pi), math.sqrt(1 - 2 / math.pi)), ("exp", 1.0, 1.0)],
)
def test_jitter_mean_std_min(dist: str, mean_factor: float, std_factor: float) -> None:
    base, jitter = 0.040, 0.005
    model = direction(delay=base, jitter=jitter, jitter_dist=dist)
    delays = [model.delay(i * 1e-3) for i in range(N)]
    extra = [d - base for d in delays]
    assert min(delays) >= base
    assert min(extra) < 0.01 * jitter  # the floor is the base delay itself
    assert statistics.fmean(extra) == pytest.approx(mean_factor * jitter, rel=0.03)
    assert statistics.stdev(extra) == pytest.approx(std_factor * jitter, rel=0.03)
    assert model.mean_delay == pytest.approx(base + mean_factor * jitter)


def test_pareto_jitter_is_heavy_tailed_with_mean_j() -> None:
    base, jitter = 0.040, 0.005
    model = direction(delay=base, jitter=jitter, jitter_dist="pareto")
    extra = sorted(model.delay(0.0) - base for _ in range(N))
    assert extra[0] >= 0
    # Lomax, shape a, scale s = J (a - 1): quantile q is s ((1 - q)^(-1/a) - 1).
    scale = jitter * (PARETO_SHAPE - 1)
    for q in (0.5, 0.9, 0.99):
        expected = scale * ((1 - q) ** (-1 / PARETO_SHAPE) - 1)
        assert extra[int(q * N)] == pytest.approx(expected, rel=0.08), q
    # Infinite variance: the sample mean converges slowly, so a loose check.
    assert statistics.fmean(extra) == pytest.approx(jitter, rel=0.25)
    assert extra[-1] > 20 * jitter  # the tail a normal jitter never has


def test_loss_rate_within_binomial_tolerance() -> None:
    model = direction(delay=0.01, loss=0.1)
    results = [model.sample(i * 1e-3) for i in range(N)]
    lost = sum(r is None for r in results)
    assert lost == model.lost and model.sent == N
    assert binomial_ok(lost, N, 0.1)
    assert all(r == pytest.approx(0.01) for r in results if r is not None)


def test_reordered_datagrams_are_overtaken() -> None:
    model = direction(delay=0.005, reorder=0.05, reorder_extra=0.010)
    sent = [i * 1e-3 for i in range(N)]
    arrivals = []
    for t in sent:
        d = model.sample(t)
        assert d is not None
        arrivals.append(t + d)
    assert binomial_ok(model.reordered, N, 0.05)
    # A datagram is out of order if one sent after it arrives first.
    overtaken, later_min = 0, math.inf
    for a in reversed(arrivals):
        overtaken += a > later_min
        later_min = min(later_min, a)
    assert overtaken == model.reordered


def test_jitter_alone_never_swaps_datagrams() -> None:
    """In order unless held back: jitter larger than the gaps stretches them only."""
    model = direction(delay=0.020, jitter=0.002, reorder=0.02, reorder_extra=0.010)
    last, arrivals, held = -math.inf, [], []
    for k in range(N):
        t = k * 1e-4  # 0.1 ms apart: 2 ms of jitter would swap most of them
        d = model.sample(t)
        assert d is not None
        at = datagram_deliver_at(t, d, model.held, last)
        if not model.held:
            last = at
        arrivals.append(at)
        held.append(model.held)
    assert sum(held) == model.reordered and binomial_ok(model.reordered, N, 0.02)
    in_order = [a for a, h in zip(arrivals, held, strict=True) if not h]
    assert all(b >= a for a, b in itertools.pairwise(in_order))
    assert statistics.median(b - a for a, b in itertools.pairwise(in_order)) < 2e-3


def test_the_datagram_scheduler_keeps_order_but_for_the_held_and_drops_the_lost() -> None:
    config = DirectionConfig(delay=0.020, jitter=0.002, loss=0.1, reorder=0.02)
    scheduler = DatagramScheduler(DirectionModel(config, random.Random(5)))
    twin = DirectionModel(config, random.Random(5))  # the same draws, scheduled by hand
    last = -math.inf
    for k in range(N):
        t = k * 1e-4
        at = scheduler.deliver_at(t)
        d = twin.sample(t)
        if d is None:
            assert at is None
            continue
        expected = datagram_deliver_at(t, d, twin.held, last)
        if not twin.held:
            last = expected
        assert at == expected
    assert scheduler.model.lost == twin.lost and binomial_ok(twin.lost, N, 0.1)


def test_asymmetry_is_added_to_backward_only() -> None:
    config = DirectionConfig(delay=0.020, jitter=0.002)
    link = LinkModel(config, asymmetry=0.008, seed=5)
    fwd = [link.forward.delay(0.0) for _ in range(N)]
    bwd = [link.backward.delay(0.0) for _ in range(N)]
    assert min(fwd) >= 0.020 and min(fwd) < 0.0201
    assert min(bwd) >= 0.028 and min(bwd) < 0.0281
    assert statistics.fmean(bwd) - statistics.fmean(fwd) == pytest.approx(0.008, abs=1e-4)
    assert link.backward.mean_delay - link.forward.mean_delay == pytest.approx(0.008)


def test_bursts_only_inside_their_windows() -> None:
    start = 100.0
    model = DirectionModel(
        DirectionConfig(
            delay=0.010,
            jitter=0.001,
            burst_every=10.0,
            burst_duration=2.0,
            burst_extra=0.020,
            burst_jitter_factor=3.0,
        ),
        random.Random(7),
        start=start,
    )
    rng = random.Random(8)
    inside: list[float] = []
    outside: list[float] = []
    for _ in range(N):
        t = rng.uniform(0.0, 60.0)
        d = model.delay(start + t)
        window = t >= 10.0 and t % 10.0 < 2.0  # [10, 12), [20, 22), ...: the start is quiet
        assert model.in_burst(start + t) == window
        (inside if window else outside).append(d)
    assert len(inside) > 0.15 * N
    assert min(inside) >= 0.030 and max(outside) < 0.030
    spread_in = statistics.stdev(inside)
    spread_out = statistics.stdev(outside)
    assert spread_in / spread_out == pytest.approx(3.0, rel=0.1)


def test_stream_delivery_never_goes_back() -> None:
    model = direction(delay=0.010, jitter=0.005, jitter_dist="pareto")
    stream = StreamScheduler(model)
    last = -math.inf
    for i in range(N):
        now = i * 1e-4
        at = stream.deliver_at(now)
        assert at >= last and at >= now + 0.010
        last = at
    assert stream_deliver_at(1.0, 0.01, 2.0) == 2.0
    assert stream_deliver_at(1.0, 0.01, 0.5) == pytest.approx(1.01)


def test_stream_loss_is_a_retransmission_delay_in_order() -> None:
    """On TCP a lost segment comes one RTO late and holds up those behind it."""
    model = DirectionModel(DirectionConfig(delay=0.01, loss=0.2, rto=0.2), random.Random(9))
    stream = StreamScheduler(model)
    times = [stream.deliver_at(0.001 * k) for k in range(N)]
    assert all(b >= a for a, b in itertools.pairwise(times))
    assert binomial_ok(model.lost, N, 0.2)
    late = sum(1 for k, t in enumerate(times) if t - 0.001 * k > 0.15)
    assert late >= model.lost  # each loss delays itself, and often those behind it


def test_a_seed_reproduces_both_directions() -> None:
    config = DirectionConfig(delay=0.01, jitter=0.003, loss=0.2, reorder=0.1)

    def draws(seed: int) -> list[float | None]:
        link = LinkModel(config, seed=seed)
        return [m.sample(i * 0.01) for i in range(200) for m in (link.forward, link.backward)]

    assert draws(3) == draws(3)
    assert draws(3) != draws(4)


def test_zero_settings_pass_straight_through() -> None:
    model = direction()
    assert all(model.sample(i) == 0.0 for i in range(100))


def test_burst_longer_than_its_period_is_refused() -> None:
    with pytest.raises(ValueError, match="burst_duration"):
        DirectionConfig(burst_every=2.0, burst_duration=2.0)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("tcp/127.0.0.1:7447", LinkEndpoint("tcp", "127.0.0.1", 7447)),
        ("udp/[::1]:9000", LinkEndpoint("udp", "::1", 9000)),
        ("[::1]:0", LinkEndpoint(None, "::1", 0)),
        ("tcp/localhost:80", LinkEndpoint("tcp", "localhost", 80)),
    ],
)
def test_endpoints(text: str, expected: LinkEndpoint) -> None:
    assert parse_endpoint(text) == expected
    if expected.protocol:
        assert str(parse_endpoint(text)) == text


@pytest.mark.parametrize(
    "text", ["tcp/127.0.0.1", "quic/127.0.0.1:7447", "tcp/::1:80", "tcp/[::1]:70000", "tcp/:1"]
)
def test_bad_endpoints(text: str) -> None:
    with pytest.raises(ValueError):
        parse_endpoint(text)


# -- settings (schemas.link) -------------------------------------------------------
def test_a_bad_setting_names_the_field() -> None:
    data = {"listen": "tcp/127.0.0.1:7450", "to": "tcp/127.0.0.1:7447"}
    with pytest.raises(ConfigError, match=r"link.toml: field 'delay_ms': .*greater than"):
        validate(LinkOptions, data | {"delay_ms": -1}, "link.toml")
    with pytest.raises(ConfigError, match=r"field 'burst_duration': .*'burst_every' 2.0 s"):
        validate(LinkOptions, data | {"burst_every": 2}, "link.toml")
    with pytest.raises(ConfigError, match=r"field 'to': .*port 0 cannot be dialled"):
        validate(LinkOptions, data | {"to": "tcp/127.0.0.1:0"}, "link.toml")
    with pytest.raises(ConfigError, match=r"field 'reorder': .*never reorders"):
        validate(LinkOptions, data | {"reorder": 0.1}, "link.toml")
    udp = validate(LinkOptions, {"listen": "[::1]:0", "to": "udp/[::1]:9", "reorder": 0.1}, "x")
    assert udp.proto == "udp"


def test_the_link_model_of_options_is_in_seconds_with_backward_asymmetry() -> None:
    options = LinkOptions(
        listen="tcp/127.0.0.1:0", to="tcp/127.0.0.1:9", delay_ms=40, asymmetry_ms=6
    )
    link = LinkModel.from_options(options, seed=1, start=0.0)
    assert link.forward.base == pytest.approx(0.040)
    assert link.backward.base == pytest.approx(0.046)


@pytest.mark.parametrize("module", [federation.link.model, federation.link.stats, schemas.link])
def test_the_pure_parts_import_no_io(module: Any) -> None:
    """The model takes ``now``: no sockets, clocks, threads or event loop."""
    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert not imported & {"socket", "time", "threading", "asyncio", "selectors", "argparse"}


# -- command line ----------------------------------------------------------------
def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="fedlab")
    sub = parser.add_subparsers(dest="command", required=True)
    link_cli.add(sub)
    return parser.parse_args(["link", *argv])


ENDS = ("--listen", "tcp/127.0.0.1:7450", "--to", "tcp/127.0.0.1:7447")


def test_flags_become_directions_in_seconds() -> None:
    options = options_from_args(
        parse(*ENDS, "--delay-ms", "40", "--jitter-ms", "5", "--backward-delay-ms", "30")
    )
    assert options.proto == "tcp"
    fwd, bwd = options.direction("forward"), options.direction("backward")
    assert (fwd.delay, fwd.jitter) == pytest.approx((0.040, 0.005))
    assert (bwd.delay, bwd.jitter) == pytest.approx((0.030, 0.005))
    bursts = options_from_args(parse(*ENDS, "--burst-every", "180", "--burst-extra-ms", "20"))
    config = bursts.direction("backward")
    assert (config.burst_every, config.burst_duration, config.burst_extra) == (180, 5.0, 0.02)


def test_link_opens_no_zenoh_session_so_takes_no_zenoh_flags() -> None:
    with pytest.raises(SystemExit):
        parse(*ENDS, "--connect", "tcp/127.0.0.1:1")


@pytest.mark.parametrize(
    ("extra", "flag", "reason"),
    [
        (("--delay-ms", "-5"), "--delay-ms", "greater than or equal to 0"),
        (("--jitter-ms", "nan"), "--jitter-ms", "finite"),
        (("--protocol", "udp", "--loss", "1.5"), "--loss", "less than or equal to 1"),
        (("--burst-extra-ms", "20"), "--burst-extra-ms", "needs --burst-every"),
        (("--burst-every", "2", "--burst-duration", "3"), "--burst-duration", "shorter"),
        (("--protocol", "udp"), "--listen", "different protocols"),
        (("--reorder", "0.1"), "--reorder", "--protocol udp"),
        (("--burst-every", "2"), "--burst-duration", "(the default) must be shorter"),
    ],
)
def test_bad_values_name_the_flag(extra: tuple[str, ...], flag: str, reason: str) -> None:
    with pytest.raises(ConfigError) as info:
        options_from_args(parse(*ENDS, *extra))
    assert flag in str(info.value) and reason in str(info.value)


def test_port_0_is_refused_on_to_only() -> None:
    options = options_from_args(parse("--listen", "tcp/127.0.0.1:0", "--to", "tcp/127.0.0.1:9"))
    assert parse_endpoint(options.listen).port == 0
    with pytest.raises(ConfigError, match=r"--to: port 0 cannot be dialled \(got 'tcp/"):
        options_from_args(parse("--listen", "tcp/127.0.0.1:1", "--to", "tcp/127.0.0.1:0"))


def test_flag_defaults_are_the_settings_defaults() -> None:
    args = parse(*ENDS)
    options = options_from_args(args)
    assert options == LinkOptions(listen=ENDS[1], to=ENDS[3])
    for name, value in vars(args).items():
        if name in LinkOptions.model_fields and name not in ("listen", "to"):
            assert value == LinkOptions.model_fields[name].default, name


def test_main_refuses_bad_values_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--listen", "tcp/127.0.0.1", "--to", "tcp/127.0.0.1:7447"]) == 2
    err = capsys.readouterr().err
    assert "--listen" in err and "tcp/HOST:PORT" in err


def test_a_busy_port_is_a_config_error(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        assert main(["--listen", f"tcp/127.0.0.1:{port}", "--to", "tcp/127.0.0.1:7447"]) == 2
    assert "--listen" in capsys.readouterr().err


def test_help_has_an_example(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "Example" in out and "fedlab link" in out
