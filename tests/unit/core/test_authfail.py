"""What a TLS probe saw, told as the failure it is (federation/core/authfail.py)."""

from __future__ import annotations

import pytest

from federation.core.authfail import ClientTls, TlsOutcome, explain, refused_commands

EP = "tls/localhost:7447"
CLIENT = ClientTls(
    ca="/etc/fedlab/certs/ca.pem",
    cert="/etc/fedlab/certs/kiruna.knatte.pem",
    key="/etc/fedlab/certs/kiruna.knatte.key",
    mtls=True,
    source="/etc/fedlab/agents/knatte.json5",
    cert_not_after="2026-11-27T09:00:00+00:00",
)


@pytest.mark.parametrize(
    ("outcome", "kind", "words"),
    [
        (TlsOutcome("verify", "CERTIFICATE_VERIFY_FAILED", "unable to get local issuer "
                    "certificate", router_issuer="lund federation CA"), "router-ca",
         ["not signed by the CA this client trusts, /etc/fedlab/certs/ca.pem",
          "issued by 'lund federation CA'", "root_ca_certificate in /etc/fedlab/agents/"]),
        (TlsOutcome("verify", "CERTIFICATE_VERIFY_FAILED", "certificate has expired"),
         "router-expired", ["the router's certificate has expired"]),
        (TlsOutcome("verify", "CERTIFICATE_VERIFY_FAILED", "Hostname mismatch, certificate "
                    "is not valid for 'localhost'", router_names=("kiruna.example.org",)),
         "name", ["does not name localhost", "it names kiruna.example.org", "--host localhost"]),
        (TlsOutcome("alert", "TLSV1_ALERT_UNKNOWN_CA", "alert 'unknown ca'"), "client-ca",
         ["does not trust this client's certificate /etc/fedlab/certs/kiruna.knatte.pem",
          "connect_certificate in /etc/fedlab/agents/knatte.json5"]),
        (TlsOutcome("alert", "TLSV1_ALERT_DECRYPT_ERROR", "alert 'decrypt error'"), "client-ca",
         ["signed by another CA"]),
        (TlsOutcome("alert", "SSLV3_ALERT_CERTIFICATE_EXPIRED", "alert 'certificate expired'"),
         "client-expired", ["kiruna.knatte.pem: it has expired",
                            "valid until 2026-11-27T09:00:00+00:00", "issue-agent --force"]),
        (TlsOutcome("alert", "TLSV13_ALERT_CERTIFICATE_REQUIRED", "alert 'certificate "
                    "required'"), "client-missing", ["wants a client certificate"]),
        (TlsOutcome("alert", "SSLV3_ALERT_BAD_CERTIFICATE", "alert 'bad certificate'"),
         "client-refused", ["refused this client's certificate", "bad certificate"]),
        (TlsOutcome("accepted"), "session", ["opens no Zenoh session"]),
    ],
)  # fmt: skip
def test_each_outcome_says_what_failed_and_where(
    outcome: TlsOutcome, kind: str, words: list[str]
) -> None:
    failure = explain(EP, "localhost", outcome, CLIENT)
    assert failure is not None and failure.kind == kind
    assert failure.message.startswith(f"TLS to {EP} ")
    for word in words:
        assert word in failure.message, failure.message


def test_a_login_refused_after_tls_names_the_user_and_the_file() -> None:
    client = ClientTls(ca="ca.pem", user="rome/pinocchio", source="rome/agents/pinocchio.json5")
    failure = explain("tls/localhost:7448", "localhost", TlsOutcome("accepted"), client)
    assert failure is not None and failure.kind == "password"
    assert "refuses user 'rome/pinocchio'" in failure.message
    assert "rome/agents/pinocchio.json5" in failure.message


def test_a_missing_certificate_says_mtls_is_off() -> None:
    client = ClientTls(ca="ca.pem", cert="k.pem", key="k.key", mtls=False, source="k.json5")
    outcome = TlsOutcome("alert", "TLSV13_ALERT_CERTIFICATE_REQUIRED", "alert")
    failure = explain(EP, "localhost", outcome, client)
    assert failure is not None and "(enable_mtls is off)" in failure.message


def test_a_handshake_broken_off_otherwise_is_no_authentication_failure() -> None:
    assert explain(EP, "localhost", TlsOutcome("error", detail="reset"), CLIENT) is None


KEY = "fedlab/default/control"
UNSEEN = {"kiruna/knatte": "command not seen (mode waiting)", "rome/pinocchio": "command not "
          "seen (mode waiting); the run was aborted before its start"}  # fmt: skip


def test_commands_no_agent_saw_from_an_agents_identity_name_it() -> None:
    hint = refused_commands(
        KEY, {"certificate CN": "kiruna/knatte"}, "knatte.json5", UNSEEN, set(UNSEEN)
    )
    assert hint is not None
    assert "certificate CN 'kiruna/knatte' (from knatte.json5), an agent's" in hint
    assert KEY in hint and "operators/<name>.json5" in hint


def test_commands_no_agent_saw_from_another_identity_say_it_may_not_command() -> None:
    hint = refused_commands(KEY, {"user name": "rome/guest"}, "g.json5", UNSEEN, set(UNSEEN))
    assert hint is not None and "may not let this ctl's identity, the user name" in hint
    hint = refused_commands(KEY, {}, "Zenoh flags", UNSEEN, set(UNSEEN))
    assert hint is not None and "proves no identity" in hint


def test_a_command_some_agent_saw_is_not_blamed_on_access_control() -> None:
    reasons = dict(UNSEEN, **{"rome/pinocchio": "refused: not synchronized"})
    assert refused_commands(KEY, {"user name": "x"}, "f", reasons, set(reasons)) is None
    assert refused_commands(KEY, {"user name": "x"}, "f", {}, set()) is None
