"""A lab link on QUIC with mixed reliability keeps what the TLS lab link gives
(docs/deploy.md, "Pose under loss on the secure path").

Two routers in this process, each with its lab certificate from the federation's CA
(federation/deploy/certs.py), link over ``quic/...?mixed_rel=1`` (Zenoh 1.10: reliable
messages on a QUIC stream, best-effort ones as QUIC datagrams). Kiruna's router denies
by default and allows only ``put`` on ``a/ok/**`` from the router whose certificate
says CN ``rome``: best-effort and reliable puts on that key cross, and neither crosses
on another key. A client without a certificate is refused. A few seconds.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import test_trust
import zenoh

from federation.deploy.certs import init_ca, issue_lab, tls_settings
from federation.fleet.launch import free_port, wait_for

pytestmark = pytest.mark.integration


sessions = test_trust.sessions  # the fixture closing every session at teardown


@pytest.fixture
def certs(tmp_path: Path) -> Path:
    init_ca(tmp_path)
    for lab in ("kiruna", "rome"):
        issue_lab(tmp_path, lab, ["localhost", "127.0.0.1"])
    return tmp_path


def _config(mode: str, settings: dict[str, Any], **endpoints: list[str]) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")
    for kind, eps in endpoints.items():
        conf.insert_json5(f"{kind}/endpoints", json.dumps(eps))
    for key, value in settings.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def _acl(cn: str) -> dict[str, Any]:
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {
                "id": "declare",
                "permission": "allow",
                "flows": ["ingress", "egress"],
                "messages": ["declare_subscriber"],
                "key_exprs": ["a/**"],
            },
            {
                "id": "ok",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["put"],
                "key_exprs": ["a/ok/**"],
            },
        ],
        "subjects": [{"id": "peer", "cert_common_names": [cn]}],
        "policies": [{"id": "peer", "rules": ["declare", "ok"], "subjects": ["peer"]}],
    }


@pytest.mark.parametrize("subject", ["rome", "someone-else"])
def test_access_control_by_certificate_applies_to_stream_and_datagrams(
    certs: Path, sessions: list[Any], subject: str
) -> None:
    port = free_port()
    kiruna_conf = _config(
        "router",
        tls_settings(certs, "kiruna", listen=True),
        listen=[f"quic/127.0.0.1:{port}?mixed_rel=1"],
    )
    kiruna_conf.insert_json5("access_control", json.dumps(_acl(subject)))
    kiruna = zenoh.open(kiruna_conf)
    sessions.append(kiruna)
    got: list[str] = []
    sessions.append(kiruna.declare_subscriber("a/**", lambda s: got.append(str(s.key_expr))))
    rome = zenoh.open(
        _config(
            "router",
            tls_settings(certs, "rome", listen=True)
            | {"transport/link/tls/verify_name_on_connect": True},
            connect=[f"quic/localhost:{port}?mixed_rel=1"],
        )
    )
    sessions.append(rome)
    assert wait_for(lambda: list(rome.info.routers_zid()), 10.0, 0.1), "no QUIC lab link"
    reliability = {"be": zenoh.Reliability.BEST_EFFORT, "rel": zenoh.Reliability.RELIABLE}
    pubs = {
        f"a/{where}/{name}": rome.declare_publisher(f"a/{where}/{name}", reliability=rel)
        for where in ("ok", "no")
        for name, rel in reliability.items()
    }
    sessions.extend(pubs.values())
    allowed = {"a/ok/be", "a/ok/rel"} if subject == "rome" else set()
    # Publish on every key at least 20 times, and until each allowed key has arrived (5 s
    # at most): a denied key then had its chances.
    started, sent = time.monotonic(), 0
    while time.monotonic() - started < 5.0:
        for pub in pubs.values():
            pub.put(b"x" * 56)
        sent += 1
        time.sleep(0.05)
        if sent >= 20 and set(got) >= allowed:
            break
    time.sleep(0.5)  # anything denied that was on its way
    assert sent >= 20
    counts = Counter(got)
    assert set(counts) == allowed, counts


def test_a_client_without_a_certificate_is_refused(certs: Path, sessions: list[Any]) -> None:
    port = free_port()
    kiruna = zenoh.open(
        _config(
            "router",
            tls_settings(certs, "kiruna", listen=True),
            listen=[f"quic/127.0.0.1:{port}?mixed_rel=1"],
        )
    )
    sessions.append(kiruna)
    conf = _config("client", tls_settings(certs), connect=[f"quic/localhost:{port}?mixed_rel=1"])
    conf.insert_json5("connect/timeout_ms", "2000")
    with pytest.raises(zenoh.ZError):
        sessions.append(zenoh.open(conf))
