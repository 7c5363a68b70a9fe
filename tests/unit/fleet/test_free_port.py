"""``free_port``: a port nothing binds, below the ephemeral range, never handed out
twice on this host within its reservation, even to processes asking at once;
``free_ports``: a run of consecutive ones, each reserved."""

from __future__ import annotations

import multiprocessing
import os
import random
import socket
import tempfile
import time
from pathlib import Path

import pytest

from federation.fleet import launch
from federation.fleet.launch import PORTS, free_port, free_ports


@pytest.fixture
def reservations(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A reservation directory of this test's own (the host's is shared by every test)."""
    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    return tmp_path / f"fedlab-ports-{os.getuid()}"


def _ports(count: int) -> list[int]:
    return [free_port() for _ in range(count)]


def test_ports_are_bindable_and_outside_the_ephemeral_range(reservations: Path) -> None:
    for host in ("127.0.0.1", "::1"):
        port = free_port(host)
        assert port in PORTS
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
            with socket.socket(family, kind) as s:
                s.bind((host, port))
        assert (reservations / str(port)).exists()


def test_processes_asking_at_once_get_distinct_ports(reservations: Path) -> None:
    with multiprocessing.get_context("fork").Pool(4) as pool:
        handed = [p for batch in pool.map(_ports, [200] * 4) for p in batch]
    assert len(handed) == len(set(handed)) == 800


def test_a_bound_port_is_skipped(reservations: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:  # UDP only: a QUIC router
        busy.bind(("127.0.0.1", PORTS.start))
        monkeypatch.setattr(random, "randrange", lambda n: 0)
        assert free_port() == PORTS.start + 1


def test_a_reservation_is_taken_again_once_it_has_expired(
    reservations: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(random, "randrange", lambda n: 0)
    first = free_port()
    assert free_port() == first + 1  # reserved: the next one
    old = time.time() - launch.RESERVED_FOR - 1
    os.utime(reservations / str(first), (old, old))
    assert free_port() == first + 2  # the expired reservation is removed on the way
    assert free_port() == first  # and the port handed out again


def _runs(count: int) -> list[int]:
    return [p for _ in range(count) for p in free_ports(3)]


def test_a_run_of_ports_is_reserved_whole(reservations: Path) -> None:
    ports = free_ports(3)
    assert len(ports) == 3 and ports.step == 1 and set(ports) <= set(PORTS)
    assert all((reservations / str(p)).exists() for p in ports)
    # A single port is never handed out inside a reserved run (here, the second port of
    # a two-lab deployment, which the command numbers itself).
    for _ in range(50):
        assert free_port() not in ports


def test_processes_asking_at_once_get_disjoint_runs(reservations: Path) -> None:
    with multiprocessing.get_context("fork").Pool(4) as pool:
        handed = [p for batch in pool.map(_runs, [50] * 4) for p in batch]
    assert len(handed) == len(set(handed)) == 600


def test_a_run_with_a_bound_port_is_skipped_and_its_reservations_given_back(
    reservations: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:  # a TCP listener only
        busy.bind(("127.0.0.1", PORTS.start + 1))
        monkeypatch.setattr(random, "randrange", lambda n: 0)
        assert free_ports(2) == range(PORTS.start + 2, PORTS.start + 4)
    # PORTS.start was reserved for the first try, then given back when PORTS.start + 1
    # was found bound: the next single port is it again.
    assert not (reservations / str(PORTS.start)).exists()
    assert free_port() == PORTS.start


def test_no_run_long_enough_is_an_error_naming_the_range(
    reservations: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(launch, "PORTS", range(PORTS.start, PORTS.start + 2))
    with pytest.raises(
        OSError, match=f"no 3 free consecutive port.s. on 127.0.0.1 in {PORTS.start}"
    ):
        free_ports(3)
