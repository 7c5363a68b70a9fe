"""Security of a lab pair: the shipped TLS configs (deploy/routers/tls/) with real routers.

Certificates are made by federation.deploy.certs into a temporary folder; the routers run
as ``python -m federation router -c deploy/routers/tls/<lab>.json5`` with the
certificate paths and loopback ports overridden by flags, nothing else changed.
Kiruna's agents authenticate with client certificates, Rome's with user/password.

Every wait is bounded; every process is stopped by pid (the ``labs`` fixture);
every Zenoh session opened here is closed. Measured facts are printed (``-s``).
The certificates themselves are tested in tests/unit/deploy/test_certs.py.
"""

from __future__ import annotations

import json
import socket
import ssl
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh
from loopback import FOLLOWER, LEADER, Labs, offset_error

from federation.deploy import certs
from federation.fleet.launch import free_port, wait_for
from federation.report.status import true_offset

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "deploy" / "routers" / "tls"
OPEN_TIMEOUT_MS = 1500  # how long a test client tries to reach its router
PASSWORDS = {"rome/pinocchio": "pinocchio-secret", "rome/ctl": "ctl-secret"}


# -- a lab pair with the shipped configs --------------------------------------------
@dataclass
class Pki:
    """The federation's certificates, and a stranger's (another CA) for the refusals."""

    dir: Path
    other: Path
    users: Path


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    base = tmp_path_factory.mktemp("pki")
    d, other = base / "certs", base / "other"
    certs.init_ca(d)
    for lab in ("kiruna", "rome"):
        certs.issue_lab(d, lab)
    for agent in ("kiruna/knatte", "kiruna/ctl", "kiruna/ghost"):
        certs.issue_agent(d, *agent.split("/"))
    certs.init_ca(other, "default")  # same names, another CA
    certs.issue_lab(other, "rome")
    certs.issue_agent(other, "kiruna", "knatte")
    users = base / "rome.users"
    users.write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    users.chmod(0o600)
    return Pki(d, other, users)


@dataclass
class TlsPair:
    kiruna_port: int
    rome_port: int

    @property
    def kiruna(self) -> str:  # dialled by name: the lab certificate's SAN is checked
        return f"tls/localhost:{self.kiruna_port}"

    @property
    def rome(self) -> str:
        return f"tls/localhost:{self.rome_port}"


def _shipped_endpoint(lab: str, key: str, port: int) -> str:
    """The shipped config's first endpoint under ``key``, moved to loopback ``port``
    (keeping its ``#...`` link options, e.g. Rome's ``enable_mtls=false``)."""
    endpoints = json.loads(zenoh.Config.from_file(str(CONFIGS / f"{lab}.json5")).get_json(key))
    proto, _, rest = endpoints[0].partition("/")
    options = rest.partition("#")[2]
    return f"{proto}/127.0.0.1:{port}" + (f"#{options}" if options else "")


def _start_router(labs: Labs, pki: Pki, lab: str, port: int, *extra: str) -> None:
    args = certs.cfg_flags(certs.tls_settings(pki.dir, lab, listen=True))
    if lab == "rome":
        args += ["--cfg", f"transport/auth/usrpwd/dictionary_file:{json.dumps(str(pki.users))}"]
    listen = _shipped_endpoint(lab, "listen/endpoints", port)
    labs.router(lab, *args, *extra, listen=listen, config=CONFIGS / f"{lab}.json5")


def _wait_listening(port: int, timeout: float = 10.0) -> None:
    def up() -> bool:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return True
        except OSError:
            return False

    assert wait_for(up, timeout=timeout, interval=0.05), f"nothing listens on {port}"


def start_lab_pair(labs: Labs, pki: Pki, *kiruna_extra: str) -> TlsPair:
    pair = TlsPair(free_port(), free_port())
    _start_router(labs, pki, "kiruna", pair.kiruna_port, *kiruna_extra)
    _wait_listening(pair.kiruna_port)
    _start_router(labs, pki, "rome", pair.rome_port, "-e", pair.kiruna)
    _wait_listening(pair.rome_port)
    return pair


def client_config(
    pki: Pki,
    endpoint: str,
    *,
    cert: str | None = None,
    user: str | None = None,
    password: str | None = None,
    ca_dir: Path | None = None,
    cert_dir: Path | None = None,
) -> dict[str, Any]:
    """A client's Zenoh settings: ``cert`` an agent ``lab/name`` (shows its certificate),
    ``user`` a user name (with ``password``, by default its own); ``ca_dir`` and
    ``cert_dir`` to take the trusted CA or the certificate from another folder."""
    settings: dict[str, Any] = {
        "mode": "client",
        "connect/endpoints": [endpoint],
        "connect/timeout_ms": OPEN_TIMEOUT_MS,
        "connect/exit_on_failure": True,
        "scouting/multicast/enabled": False,
    }
    settings |= certs.tls_settings(ca_dir or pki.dir)
    if cert is not None:
        tls = certs.tls_settings(cert_dir or pki.dir, certs.agent_stem(*cert.split("/")))
        settings |= {k: v for k, v in tls.items() if not k.endswith("root_ca_certificate")}
    if user is not None:
        settings["transport/auth/usrpwd/user"] = user
        settings["transport/auth/usrpwd/password"] = password or PASSWORDS.get(user, "")
    return settings


def _zconf(settings: dict[str, Any]) -> zenoh.Config:
    conf = zenoh.Config()
    for key, value in settings.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def try_open(settings: dict[str, Any]) -> tuple[zenoh.Session | None, float]:
    """A session (or None if refused) and the seconds zenoh.open took."""
    start = time.monotonic()
    try:
        session = zenoh.open(_zconf(settings))
    except zenoh.ZError:
        return None, time.monotonic() - start
    return session, time.monotonic() - start


def open_session(settings: dict[str, Any]) -> zenoh.Session:
    session, took = try_open(settings)
    assert session is not None, f"refused after {took:.2f} s: {settings}"
    return session


def tls_handshake_verdict(port: int, pki: Pki, cert: Path | None) -> tuple[str, float]:
    """Open a raw TLS connection to a router (optionally with a client certificate) and
    report whether the router accepted it: 'accepted' if it waits for Zenoh's first
    message, else why it hung up, and the seconds until then."""
    ctx = ssl.create_default_context(cafile=str(pki.dir / "ca.pem"))
    if cert is not None:
        ctx.load_cert_chain(str(cert), str(cert.with_suffix(".key")))
    start = time.monotonic()
    with (
        socket.create_connection(("127.0.0.1", port), timeout=2.0) as raw,
        ctx.wrap_socket(raw, server_hostname="localhost") as tls,
    ):
        tls.settimeout(0.5)
        try:
            data = tls.recv(1)  # TLS 1.3: the server judges the client's certificate now
        except TimeoutError:
            return "accepted", time.monotonic() - start
        except ssl.SSLError as error:
            return f"refused ({error.reason})", time.monotonic() - start
        except ConnectionResetError:
            return "refused (reset)", time.monotonic() - start
        return ("refused (closed)" if data == b"" else "accepted"), time.monotonic() - start


class Inbox:
    """Samples received on a key expression, with their arrival times."""

    def __init__(self, session: zenoh.Session, key_expr: str):
        self.samples: list[tuple[str, bytes, float]] = []
        self._lock = threading.Lock()
        self.sub = session.declare_subscriber(key_expr, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_bytes(), time.monotonic()))

    def __contains__(self, key: str) -> bool:
        with self._lock:
            return any(k == key for k, _, _ in self.samples)

    def arrival(self, key: str, payload: bytes) -> float | None:
        with self._lock:
            return next((t for k, p, t in self.samples if (k, p) == (key, payload)), None)

    def close(self) -> None:
        self.sub.undeclare()


@pytest.fixture
def sessions() -> Iterator[list[Any]]:
    """Zenoh sessions and declarations to close/undeclare at teardown (last first)."""
    items: list[Any] = []
    try:
        yield items
    finally:
        for item in reversed(items):
            if isinstance(item, (zenoh.Session, Inbox)):
                item.close()
            else:
                item.undeclare()


def _probe_until_linked(sender: zenoh.Session, inbox: Inbox, key: str, timeout: float) -> float:
    """Put on ``key`` every 50 ms until ``inbox`` sees it; the seconds it took."""
    start = time.monotonic()
    n = 0
    while time.monotonic() - start < timeout:
        sender.put(key, f"probe {n}".encode())
        n += 1
        if wait_for(lambda: key in inbox, timeout=0.05, interval=0.01):
            return time.monotonic() - start
    raise AssertionError(f"nothing crossed the lab link on {key} within {timeout} s")


def _forbidden_then_allowed(
    sender: zenoh.Session, inbox: Inbox, forbidden: str, allowed: str, tag: bytes
) -> float:
    """Put on ``forbidden`` then on ``allowed`` (same session, link and priority, so in
    order); wait for the allowed one, then 0.5 s more. Returns the allowed sample's latency;
    the caller checks the forbidden one never arrived."""
    sent = time.monotonic()
    sender.put(forbidden, tag)
    sender.put(allowed, tag)
    assert wait_for(lambda: inbox.arrival(allowed, tag) is not None, timeout=5), allowed
    arrived = inbox.arrival(allowed, tag)
    assert arrived is not None
    time.sleep(0.5)  # 0.5 s more in which the forbidden one does not arrive either
    return arrived - sent


def test_tls_lab_pair_refuses_strangers(labs: Labs, pki: Pki, sessions: list[Any]) -> None:
    pair = start_lab_pair(labs, pki)
    facts = []

    # Raw TLS: Kiruna's router hangs up on a client without a certificate, or with one
    # from another CA, right after the handshake; with a federation certificate it waits.
    verdict, took = tls_handshake_verdict(pair.kiruna_port, pki, None)
    assert verdict.startswith("refused"), verdict
    facts.append(f"raw TLS without certificate: {verdict} after {took * 1e3:.1f} ms")
    verdict, took = tls_handshake_verdict(pair.kiruna_port, pki, pki.other / "kiruna.knatte.pem")
    assert verdict.startswith("refused"), verdict
    facts.append(f"raw TLS with another CA's certificate: {verdict} after {took * 1e3:.1f} ms")
    verdict, _ = tls_handshake_verdict(pair.kiruna_port, pki, pki.dir / "kiruna.knatte.pem")
    assert verdict == "accepted", verdict

    # Zenoh clients: each refused one fails to open a session at all.
    refused = {
        "no certificate": client_config(pki, pair.kiruna),
        "another CA's certificate": client_config(
            pki, pair.kiruna, cert="kiruna/knatte", cert_dir=pki.other
        ),
        "trusting another CA": client_config(
            pki, pair.kiruna, cert="kiruna/knatte", ca_dir=pki.other
        ),
        "rome: no password": client_config(pki, pair.rome),
        "rome: wrong password": client_config(pki, pair.rome, user="rome/pinocchio", password="x"),
        "rome: unknown user": client_config(pki, pair.rome, user="rome/ada", password="x"),
    }
    for what, settings in refused.items():
        session, took = try_open(settings)
        if session is not None:
            sessions.append(session)
        assert session is None, f"{what}: a session was opened"
        facts.append(f"zenoh client, {what}: refused after {took:.2f} s (open timeout)")
    # An impostor router (Rome's name, another CA) cannot join the federation either.
    verdict, took = tls_handshake_verdict(pair.kiruna_port, pki, pki.other / "rome.pem")
    assert verdict.startswith("refused"), verdict

    # The federation's own clients get in at once.
    for what, settings in {
        "kiruna/knatte (certificate)": client_config(pki, pair.kiruna, cert="kiruna/knatte"),
        "rome/pinocchio (password)": client_config(pki, pair.rome, user="rome/pinocchio"),
    }.items():
        session, took = try_open(settings)
        assert session is not None, what
        sessions.append(session)
        facts.append(f"zenoh client {what}: session opened in {took * 1e3:.1f} ms")
    print("\n" + "\n".join(facts))


def test_agents_write_only_under_their_own_lab(labs: Labs, pki: Pki, sessions: list[Any]) -> None:
    pair = start_lab_pair(labs, pki)
    knatte = open_session(client_config(pki, pair.kiruna, cert="kiruna/knatte"))
    sessions.append(knatte)
    pinocchio = open_session(client_config(pki, pair.rome, user="rome/pinocchio"))
    sessions.append(pinocchio)
    in_rome = Inbox(pinocchio, "fedlab/default/**")
    in_kiruna = Inbox(knatte, "fedlab/default/**")
    sessions += [in_rome, in_kiruna]
    linked = _probe_until_linked(knatte, in_rome, "fedlab/default/kiruna/knatte/status", 10)
    facts = [f"lab link carried a kiruna sample {linked:.2f} s after the routers listened"]
    # ... nor under its own name outside the protocol's keys (its token, pose, sync,
    # status, recordings), where anything it liked would cross the lab link.
    _forbidden_then_allowed(
        knatte, in_rome, forbidden="fedlab/default/kiruna/knatte/other",
        allowed="fedlab/default/kiruna/knatte/pose", tag=b"own-other",
    )  # fmt: skip
    assert "fedlab/default/kiruna/knatte/other" not in in_rome

    # A kiruna agent cannot publish under rome (or outside the federation's keys)...
    latency = _forbidden_then_allowed(
        knatte,
        in_rome,
        forbidden="fedlab/default/rome/pinocchio/pose",
        allowed="fedlab/default/kiruna/knatte/pose",
        tag=b"k1",
    )
    knatte.put("fedlab/default/control", b"k1")  # only operators may command
    knatte.put("fedlab/default/kiruna/knatte/pose", b"k2")
    assert wait_for(lambda: in_rome.arrival("fedlab/default/kiruna/knatte/pose", b"k2"), 5)
    time.sleep(0.3)  # 0.3 s more in which the forbidden ones do not arrive either
    assert "fedlab/default/rome/pinocchio/pose" not in in_rome
    assert "fedlab/default/control" not in in_rome
    facts.append(
        f"kiruna/knatte on its own key: arrived in rome after {latency * 1e3:.1f} ms; "
        "under fedlab/default/rome/** and on the control key: never arrived"
    )
    # ... and a rome agent cannot publish under kiruna.
    _forbidden_then_allowed(
        pinocchio,
        in_kiruna,
        forbidden="fedlab/default/kiruna/knatte/pose",
        allowed="fedlab/default/rome/pinocchio/pose",
        tag=b"r1",
    )
    assert in_kiruna.arrival("fedlab/default/kiruna/knatte/pose", b"r1") is None
    facts.append("rome/pinocchio (password) under fedlab/default/kiruna/**: never arrived")

    # Queryables and liveliness tokens: only under the agent's own lab.
    def answer(query: zenoh.Query) -> None:
        with query:
            query.reply(query.key_expr, b"ok")

    sessions.append(knatte.declare_queryable("fedlab/default/kiruna/knatte/sync", answer))
    sessions.append(knatte.declare_queryable("fedlab/default/rome/fake/sync", answer))
    sessions.append(knatte.liveliness().declare_token("fedlab/default/kiruna/knatte"))
    sessions.append(knatte.liveliness().declare_token("fedlab/default/rome/fake"))

    def replies(key: str) -> list[bytes]:
        return [r.ok.payload.to_bytes() for r in pinocchio.get(key, timeout=1.0) if r.ok]

    assert wait_for(lambda: replies("fedlab/default/kiruna/knatte/sync") == [b"ok"], 5)
    assert replies("fedlab/default/rome/fake/sync") == []

    def tokens() -> set[str]:
        got = pinocchio.liveliness().get("fedlab/default/*/*", timeout=1.0)
        return {str(r.ok.key_expr) for r in got if r.ok}

    assert wait_for(lambda: "fedlab/default/kiruna/knatte" in tokens(), 5)
    assert tokens() == {"fedlab/default/kiruna/knatte"}
    facts.append("queryable and liveliness token under rome/** by a kiruna agent: unseen")

    # A valid certificate whose CN no ACL subject lists gets a session but can do nothing.
    ghost = open_session(client_config(pki, pair.kiruna, cert="kiruna/ghost"))
    sessions.append(ghost)
    in_ghost = Inbox(ghost, "fedlab/default/**")
    sessions.append(in_ghost)
    ghost.put("fedlab/default/kiruna/ghost/pose", b"g1")
    knatte.put("fedlab/default/kiruna/knatte/pose", b"g1")
    pinocchio.put("fedlab/default/rome/pinocchio/pose", b"g1")
    assert wait_for(lambda: in_rome.arrival("fedlab/default/kiruna/knatte/pose", b"g1"), 5)
    assert wait_for(lambda: in_kiruna.arrival("fedlab/default/rome/pinocchio/pose", b"g1"), 5)
    time.sleep(0.3)  # 0.3 s more in which the ghost's put does not arrive either
    assert "fedlab/default/kiruna/ghost/pose" not in in_rome
    # (a session delivers its own puts to its own subscribers, without the router)
    assert [k for k, _, _ in in_ghost.samples if "/ghost/" not in k] == []
    facts.append(
        "kiruna/ghost (valid certificate, CN in no ACL subject): nothing it put arrived, "
        "nothing reached it"
    )

    # Operators command the federation; from either lab.
    ctl = open_session(client_config(pki, pair.kiruna, cert="kiruna/ctl"))
    rome_ctl = open_session(client_config(pki, pair.rome, user="rome/ctl"))
    sessions += [ctl, rome_ctl]
    ctl.put("fedlab/default/control", b"from kiruna")
    rome_ctl.put("fedlab/default/control", b"from rome")
    assert wait_for(lambda: in_rome.arrival("fedlab/default/control", b"from kiruna"), 5)
    assert wait_for(lambda: in_kiruna.arrival("fedlab/default/control", b"from rome"), 5)
    facts.append("operators kiruna/ctl and rome/ctl: control commands crossed both ways")
    print("\n" + "\n".join(facts))


def test_lab_link_confines_a_misconfigured_peer(labs: Labs, pki: Pki, sessions: list[Any]) -> None:
    """Rome's router checks what comes over the lab link too: with Kiruna's access control
    switched off (a misconfigured or compromised lab), a kiruna client still cannot write
    under fedlab/default/rome/** as far as Rome's agents can see."""
    pair = start_lab_pair(labs, pki, "--cfg", "access_control/enabled:false")
    ghost = open_session(client_config(pki, pair.kiruna, cert="kiruna/ghost"))
    sessions.append(ghost)
    pinocchio = open_session(client_config(pki, pair.rome, user="rome/pinocchio"))
    sessions.append(pinocchio)
    in_rome = Inbox(pinocchio, "fedlab/default/**")
    sessions.append(in_rome)
    _probe_until_linked(ghost, in_rome, "fedlab/default/kiruna/ghost/probe", 10)
    _forbidden_then_allowed(
        ghost,
        in_rome,
        forbidden="fedlab/default/rome/pinocchio/pose",
        allowed="fedlab/default/kiruna/ghost/pose",
        tag=b"x",
    )
    assert "fedlab/default/rome/pinocchio/pose" not in in_rome
    print("\nkiruna ACL off: rome's lab-link rule still dropped a put under fedlab/default/rome")


def _agent_config(tmp: Path, name: str, settings: dict[str, Any]) -> Path:
    """An agent's Zenoh config file (json5; plain JSON is valid json5)."""
    doc: dict[str, Any] = {}
    for key, value in settings.items():
        node = doc
        *parents, leaf = key.split("/")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    doc["connect"]["timeout_ms"] = -1  # an agent waits for its router
    doc["connect"]["exit_on_failure"] = False
    path = tmp / f"{name}.json5"
    path.write_text(json.dumps(doc, indent=2))
    path.chmod(0o600)  # it may hold a password
    return path


def test_agents_sync_over_the_tls_lab_link(labs: Labs, pki: Pki, tmp_path: Path) -> None:
    pair = start_lab_pair(labs, pki)
    leader_conf = _agent_config(
        tmp_path, "knatte", client_config(pki, pair.kiruna, cert="kiruna/knatte")
    )
    follower_conf = _agent_config(
        tmp_path, "pinocchio", client_config(pki, pair.rome, user="rome/pinocchio")
    )
    # No -e: each agent dials its router as its config file says.
    leader = labs.leader(None, "-c", str(leader_conf))
    started = time.monotonic()
    follower = labs.follower(None, "--clock-offset", "26.42", "-c", str(follower_conf))

    follower.wait_samples(LEADER, 10, timeout=20)
    took = time.monotonic() - started
    peer = follower.peer(LEADER)
    assert peer is not None
    truth = true_offset(leader.latest(), follower.latest())
    offset_error(peer, truth)
    assert peer["rejected"] == 0
    back = leader.peer(FOLLOWER)
    assert back is not None and back["samples"] > 0  # the leader syncs with rome as well
    line = follower.last()
    assert line is not None and line["counters"]["pose_received"] > 0
    print(
        f"\nagents over TLS (leader by certificate, follower by password): 10 sync samples "
        f"{took:.1f} s after the follower started; offset error "
        f"{abs(peer['offset'] - truth) * 1e6:.0f} us, delay {peer['delay'] * 1e3:.2f} ms"
    )
    assert follower.stop() == 0
    assert leader.stop() == 0


def test_a_run_is_collected_through_routers_that_enforce_access_control(
    labs: Labs, pki: Pki, sessions: list[Any], tmp_path: Path
) -> None:
    """An agent replied to the collector's manifest query on the query's key, a wildcard
    (``fedlab/<fed>/*/*/recordings``), outside its own address: its router dropped the
    reply, and every collect through deployed routers found no agent with the run."""
    from federation.core.keys import AgentId
    from federation.runtime.collect import RecordingServer, collect, finalize, sha256_file

    pair = start_lab_pair(labs, pki)
    knatte = open_session(client_config(pki, pair.kiruna, cert="kiruna/knatte"))
    operator = open_session(client_config(pki, pair.rome, user="rome/ctl"))
    sessions += [knatte, operator]
    runs = tmp_path / "runs"
    folder = runs / "acl-run"
    folder.mkdir(parents=True)
    recording = folder / "kiruna-knatte.mcap"
    recording.write_bytes(bytes(range(256)) * 400)
    finalize(folder, "kiruna/knatte", "acl-run", [recording])
    server = RecordingServer(knatte, "default", AgentId("kiruna", "knatte"), runs)
    try:
        out = tmp_path / "out"

        def collected() -> bool:
            try:
                return collect(operator, "default", "acl-run", out, timeout=1.0).ok
            except Exception:  # ConnectError until the routes are up
                return False

        assert wait_for(collected, timeout=15, interval=0.5)
        assert sha256_file(out / recording.name) == sha256_file(recording)
    finally:
        server.close()
