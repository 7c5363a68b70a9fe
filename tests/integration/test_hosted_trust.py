"""A hosted process in a generated federation: one identity speaks for the agents it
runs, and for no other (``labs.<lab>.hosted``, ``fedlab host``).

The federation is generated from one file (``fedlab deploy generate --local``) and run
on loopback over TLS with real certificates and per-agent access control: Kiruna's
leader and its hosted process ``kiruna/hosts/sim`` (running ``f1`` and ``f2``) show
certificates; Rome's follower logs in with a password. Every wait is bounded; every
process is stopped by pid (the ``labs`` fixture); every Zenoh session opened here is
closed.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import zenoh
from loopback import FOLLOWER, LEADER, Agent, Labs

from federation import cli
from federation.deploy.generate import generate
from federation.fleet.launch import free_port, wait_for
from schemas.federation import load_federation

pytestmark = pytest.mark.integration

# Held for no fault: deployed agents wait for ctl start with every valve closed.
NO_FAULT = (None, "waiting")

HOSTED = ("kiruna/f1", "kiruna/f2")


def federation_toml(kiruna: int, rome: int) -> str:
    return f"""
federation = "default"

[labs.kiruna]
auth = "certificate"
listen = ["tls/127.0.0.1:{kiruna}"]
endpoint = "tls/localhost:{kiruna}"
agents.knatte = {{ role = "leader" }}
agents.f1 = {{ role = "follower", follow = "kiruna/knatte" }}
agents.f2 = {{ role = "follower", follow = "kiruna/knatte" }}
agents.f3 = {{ role = "follower", follow = "kiruna/knatte" }}
hosted.sim = ["f1", "f2"]

[labs.rome]
auth = "password"
listen = ["tls/127.0.0.1:{rome}"]
agent_endpoint = "tls/localhost:{rome}"
dial = ["kiruna"]
agents.pinocchio = {{ role = "follower", follow = "kiruna/knatte" }}
"""


def setup(labs: Labs, tmp: Path) -> Path:
    """Generate the federation and start both routers; the generated folder."""
    ports = {"kiruna": free_port(), "rome": free_port()}
    source = tmp / "federation.toml"
    source.write_text(federation_toml(ports["kiruna"], ports["rome"]))
    out = tmp / "fed"
    generate(load_federation(source), out, local=True)
    for lab in ("kiruna", "rome"):
        config = out / lab / "routers" / f"{lab}.json5"
        doc = zenoh.Config.from_file(str(config))
        listen, *more = json.loads(doc.get_json("listen/endpoints"))  # TLS, then QUIC
        labs.router(lab, *(a for e in more for a in ("-l", e)), listen=listen, config=config)
    return out


def start_agent(labs: Labs, fed: Path, who: str) -> Agent:
    lab, name = who.split("/")
    folder = fed / lab / "agents"
    args = ["--agent-config", str(folder / f"{name}.toml"), "-c", str(folder / f"{name}.json5")]
    return labs.agent(who, None, *args, status_period=0.25)


def open_as(config: Path) -> zenoh.Session:
    conf = zenoh.Config.from_file(str(config))
    conf.insert_json5("connect/timeout_ms", "5000")
    conf.insert_json5("connect/exit_on_failure", "true")
    return zenoh.open(conf)


def test_a_hosted_process_flies_its_agents_and_speaks_for_no_other(
    labs: Labs, tmp_path: Path
) -> None:
    fed = setup(labs, tmp_path)
    leader = start_agent(labs, fed, LEADER)
    follower = start_agent(labs, fed, FOLLOWER)  # Rome, own identity, as before
    sim = fed / "kiruna" / "hosts"
    status = tmp_path / "status"
    args = ["host", str(sim / "sim"), "-c", str(sim / "sim.json5"), "--status-dir", str(status)]
    labs.fleet.start("sim", args)  # the generated files, nothing else
    hosted = {
        who: Agent(labs.fleet, "sim", [], who=who, status=status / f"kiruna-{who[7:]}.jsonl")
        for who in HOSTED
    }
    for agent in hosted.values():
        line = agent.until(
            lambda line: (
                line["peers"].get(LEADER, {}).get("samples", 0) >= 5
                and line["counters"].get("pose_received", 0) >= 20
                and line["hold"] in NO_FAULT
            ),
            timeout=30,
            what="synced with the leader and following it",
        )
        assert line["peers"][LEADER]["sharing"] == 2, line["peers"]
    follower.wait_samples(LEADER, 5, timeout=20)
    # The leader queries f1 and f2 (once a second): their replies pass Kiruna's router
    # under the host's identity.
    assert wait_for(
        lambda: all(
            ((leader.last() or {}).get("peers", {}).get(who) or {}).get("samples", 0) >= 2
            for who in HOSTED
        ),
        timeout=20,
    ), leader.last()

    # Under the host's identity a put on its agents' keys arrives; on another's, never.
    got: list[tuple[str, bytes]] = []
    heard = threading.Condition()

    def on_sample(sample: zenoh.Sample) -> None:
        with heard:
            got.append((str(sample.key_expr), sample.payload.to_bytes()))
            heard.notify_all()

    def wait_for_payload(payload: bytes, key: str) -> bool:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # bounded: 10 s, a put every 0.1 s
            speaker.put(key, payload)
            with heard:
                if heard.wait_for(lambda: (key, payload) in got, timeout=0.1):
                    return True
        return False

    allowed = "fedlab/default/kiruna/f1/recordings"
    listener = open_as(fed / "rome" / "agents" / "pinocchio.json5")
    speaker = open_as(sim / "sim.json5")
    try:
        sub = listener.declare_subscriber("fedlab/default/kiruna/*/recordings", on_sample)
        try:
            # The route is up end to end before anything forbidden is sent...
            assert wait_for_payload(b"first", allowed), "the host's own agent's key never arrived"
            forged = (
                "fedlab/default/kiruna/knatte/recordings",
                "fedlab/default/kiruna/f3/recordings",
            )
            for key in forged:
                for _ in range(20):  # bounded: 20 puts each
                    speaker.put(key, b"forged")
            # ...and a later put on an allowed key arrives after them, had they passed.
            assert wait_for_payload(b"last", allowed)
            with heard:
                assert {key for key, _ in got} == {allowed}, got
        finally:
            sub.undeclare()
        # Nor can it hold another agent's liveliness token or answer its queries (f3, not
        # running: anything seen under its name would be the host's); its own agent's work.
        f3, f1 = "fedlab/default/kiruna/f3", "fedlab/default/kiruna/f1"
        declared = [
            speaker.liveliness().declare_token(f3),
            speaker.declare_queryable(f"{f3}/sync", lambda q: q.reply(q.key_expr, b"forged")),
            speaker.declare_queryable(f"{f1}/recordings", lambda q: q.reply(q.key_expr, b"own")),
        ]
        try:
            assert wait_for(
                lambda: any(
                    r.ok is not None for r in listener.get(f"{f1}/recordings", timeout=0.5)
                ),
                timeout=10,
            ), "the host's own agent's queryable never answered"
            # f1's token (held by the host, which runs it) is seen where f3's is not.
            assert [r.ok for r in listener.liveliness().get(f1, timeout=2.0) if r.ok], "no f1"
            for _ in range(3):  # bounded: three queries and liveliness queries of f3
                assert [r.ok for r in listener.get(f"{f3}/sync", timeout=0.5) if r.ok] == []
                assert [r.ok for r in listener.liveliness().get(f3, timeout=0.5) if r.ok] == []
        finally:
            for item in reversed(declared):
                item.undeclare()
    finally:
        speaker.close()
        listener.close()
    assert labs.fleet.stop("sim") == 0


def test_a_host_refuses_an_agent_its_identity_may_not_speak_for(
    labs: Labs, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ports = {"kiruna": free_port(), "rome": free_port()}
    source = tmp_path / "federation.toml"
    source.write_text(federation_toml(ports["kiruna"], ports["rome"]))
    fed = tmp_path / "fed"
    generate(load_federation(source), fed, local=True)
    sim = fed / "kiruna" / "hosts"
    f3 = fed / "kiruna" / "agents" / "f3.toml"
    started = time.monotonic()
    code = cli.main(["host", str(sim / "sim" / "f1.toml"), str(f3), "-c", str(sim / "sim.json5")])
    assert code == 2
    assert time.monotonic() - started < 5  # at load: no router is dialled
    err = capsys.readouterr().err
    assert "kiruna/f3 not among the agents the certificate CN 'kiruna/hosts/sim'" in err
