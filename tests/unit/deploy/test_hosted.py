"""A lab's hosted processes in the federation file (``labs.<lab>.hosted``): one identity
that speaks for exactly the agents it runs (federation/deploy/generate.py,
schemas/federation.py, federation/runtime/identity.py). No processes: the generated
files run with real routers in tests/integration/test_hosted_trust.py."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import pytest
import zenoh

from federation.core.keys import AgentId
from federation.deploy import generate as gen
from federation.runtime.identity import IdentityError, check_hosted_identity
from schemas.base import ConfigError
from schemas.config import AgentConfig
from schemas.federation import load_federation

BASE = """
federation = "default"

[labs.kiruna]
auth = "certificate"
listen = ["tls/127.0.0.1:7447"]
endpoint = "tls/localhost:7447"
agents.knatte = { role = "leader" }
agents.f1 = { role = "follower", follow = "kiruna/knatte" }
agents.f2 = { role = "follower", follow = "kiruna/knatte" }
agents.f3 = { role = "follower", follow = "kiruna/knatte" }

[labs.rome]
auth = "password"
listen = ["tls/127.0.0.1:7448"]
dial = ["kiruna"]
agents.r1 = { role = "follower", follow = "kiruna/knatte" }
agents.r2 = { role = "member" }
"""
HOSTED = BASE + '[labs.kiruna.hosted]\nsim = ["f1", "f2"]\n[labs.rome.hosted]\npad = ["r1", "r2"]\n'


def write(tmp: Path, text: str) -> Path:
    path = tmp / "federation.toml"
    path.write_text(text)
    return path


def acl(doc: dict[str, Any], who: str) -> tuple[set[str], set[str]]:
    """(the keys ``who`` may write, the ids of the subjects listing it)."""
    control = doc["access_control"]
    ids = {
        s["id"]
        for s in control["subjects"]
        if who in s.get("cert_common_names", []) + s.get("usernames", [])
    }
    rules = {r["id"]: r for r in control["rules"]}
    keys = {
        k
        for p in control["policies"]
        if set(p["subjects"]) & ids
        for r in p["rules"]
        if rules[r]["flows"] == ["ingress"] and "put" in rules[r]["messages"]
        for k in rules[r]["key_exprs"]
    }
    return keys, ids


def own(*agents: str) -> set[str]:
    topics = ("pose", "sync", "status", "recordings", "role")
    return {
        k
        for a in agents
        for k in (f"fedlab/default/{a}", *(f"fedlab/default/{a}/{t}" for t in topics))
    }


def test_a_host_writes_for_exactly_its_agents_which_have_no_identity(tmp_path: Path) -> None:
    fed = load_federation(write(tmp_path, HOSTED))
    kiruna = gen.router_config(fed, "kiruna", gen.DEFAULT_ROOT)
    rome = gen.router_config(fed, "rome", gen.DEFAULT_ROOT)
    assert acl(kiruna, "kiruna/hosts/sim")[0] == own("kiruna/f1", "kiruna/f2")
    assert acl(rome, "rome/hosts/pad")[0] == own("rome/r1", "rome/r2")
    for who in ("kiruna/f1", "kiruna/f2"):  # no subject of their own: only the host speaks
        assert acl(kiruna, who) == (set(), set())
    assert acl(kiruna, "kiruna/f3")[0] == own("kiruna/f3")  # not hosted: as before
    assert acl(kiruna, "kiruna/knatte")[0] == own("kiruna/knatte")
    subjects = {s["id"]: s for s in kiruna["access_control"]["subjects"]}
    assert subjects["host-sim"] == {"id": "host-sim", "cert_common_names": ["kiruna/hosts/sim"]}
    subjects = {s["id"]: s for s in rome["access_control"]["subjects"]}
    assert subjects["host-pad"] == {"id": "host-pad", "usernames": ["rome/hosts/pad"]}


def test_generate_writes_each_hosts_config_and_its_agents_settings(tmp_path: Path) -> None:
    out = tmp_path / "fed"
    done = gen.generate(load_federation(write(tmp_path, HOSTED)), out)
    assert "kiruna/hosts/sim" in done.issued and "kiruna/f1" not in done.issued
    certs = {p.name for p in (out / "kiruna" / "certs").iterdir()}
    assert {"kiruna.hosts.sim.pem", "kiruna.hosts.sim.key", "kiruna.f3.pem"} <= certs
    assert not {"kiruna.f1.pem", "kiruna.f2.pem"} & certs
    agents = {p.name for p in (out / "kiruna" / "agents").iterdir()}
    assert agents == {"knatte.toml", "knatte.json5", "f3.toml", "f3.json5"}
    for lab, host, names in (("kiruna", "sim", ["f1", "f2"]), ("rome", "pad", ["r1", "r2"])):
        conf = zenoh.Config.from_file(str(out / lab / "hosts" / f"{host}.json5"))
        metadata = json.loads(conf.get_json("metadata"))
        assert metadata == {"fedlab_hosted": [f"{lab}/{n}" for n in names]}
        settings = sorted((out / lab / "hosts" / host).iterdir())
        assert [p.name for p in settings] == [f"{n}.toml" for n in names]
        for path in settings:
            config = AgentConfig.model_validate(tomllib.loads(path.read_text()))
            assert config.lab == lab
    kiruna = zenoh.Config.from_file(str(out / "kiruna" / "hosts" / "sim.json5"))
    cert = json.loads(kiruna.get_json("transport/link/tls/connect_certificate"))
    assert cert.endswith("kiruna.hosts.sim.pem")
    users = (out / "rome" / "rome.users").read_text()
    assert "rome/hosts/pad:" in users and "rome/r1:" not in users
    rome = zenoh.Config.from_file(str(out / "rome" / "hosts" / "pad.json5"))
    assert json.loads(rome.get_json("transport/auth/usrpwd/user")) == "rome/hosts/pad"
    units = {p.name for p in (out / "kiruna" / "systemd").iterdir()}
    assert "fedlab-host@.service" in units


def test_one_edit_moves_agents_into_and_out_of_a_host(tmp_path: Path) -> None:
    out = tmp_path / "fed"
    source = write(tmp_path, BASE)
    gen.generate(load_federation(source), out)
    assert (out / "kiruna" / "agents" / "f1.json5").exists()
    assert "rome/r1:" in (out / "rome" / "rome.users").read_text()
    source.write_text(HOSTED)
    done = gen.generate(load_federation(source), out)
    # Its identity is gone: no config, no certificate in the lab's folder, no password.
    assert out / "kiruna" / "agents" / "f1.json5" in done.removed
    assert out / "kiruna" / "certs" / "kiruna.f1.pem" in done.removed
    assert "rome/r1:" not in (out / "rome" / "rome.users").read_text()
    assert (out / "kiruna" / "hosts" / "sim" / "f1.toml").exists()
    source.write_text(BASE)  # and back: the host's identity is gone everywhere
    done = gen.generate(load_federation(source), out)
    assert out / "kiruna" / "hosts" / "sim.json5" in done.removed
    assert out / "kiruna" / "certs" / "kiruna.hosts.sim.pem" in done.removed
    assert not (out / "kiruna" / "hosts" / "sim").exists()
    assert (out / "kiruna" / "agents" / "f1.json5").exists()
    router = (out / "kiruna" / "routers" / "kiruna.json5").read_text()
    assert "kiruna/hosts/sim" not in router and "host-sim" not in router
    assert "rome/hosts/pad" not in (out / "rome" / "rome.users").read_text()
    assert "rome/hosts/pad" not in (out / "rome" / "routers" / "rome.json5").read_text()


def test_an_agent_moved_through_a_host_keeps_its_pair_and_its_kind(tmp_path: Path) -> None:
    # Hosted, it is not distrusted: moved out again it flies on its own pair. Moved out
    # as an operator, its agent certificate would gain control: refused.
    from cryptography import x509

    out = tmp_path / "fed"
    pem = out / "ca" / "kiruna.f1.pem"

    def serial() -> int:
        return x509.load_pem_x509_certificate(pem.read_bytes()).serial_number

    source = write(tmp_path, BASE)
    gen.generate(load_federation(source), out)
    first = serial()
    source.write_text(HOSTED)
    gen.generate(load_federation(source), out)
    source.write_text(BASE)
    gen.generate(load_federation(source), out)
    assert serial() == first
    # (A host removed is retired like any identity: hosted again under another name.)
    source.write_text(BASE + '[labs.kiruna.hosted]\nsim2 = ["f1"]\n')
    gen.generate(load_federation(source), out)
    as_operator = BASE.replace(
        'agents.f1 = { role = "follower", follow = "kiruna/knatte" }\n', 'operators = ["f1"]\n'
    )
    source.write_text(as_operator)
    with pytest.raises(ConfigError, match="kiruna/f1 was a agent until now"):
        gen.generate(load_federation(source), out)


@pytest.mark.parametrize(
    ("hosted", "said"),
    [
        ('f3 = ["f1"]', "hosted.f3': 'f3' is already an agent's"),
        ('sim = ["f1", "zz"]', "hosted.sim.1': 'zz' is not an agent of lab kiruna"),
        ('sim = ["r1"]', "hosted.sim.0': 'r1' is not an agent of lab kiruna"),
        ("sim = []", "hosted.sim': runs no agent"),
        ('a = ["f1"]\nb = ["f2", "f1"]', "hosted.b.1': 'f1' is already run by 'a'"),
    ],
)
def test_a_bad_host_fails_naming_the_field(tmp_path: Path, hosted: str, said: str) -> None:
    with pytest.raises(ConfigError) as error:
        load_federation(write(tmp_path, BASE + "[labs.kiruna.hosted]\n" + hosted + "\n"))
    assert said in str(error.value)
    assert "federation.toml: field 'labs.kiruna.hosted." in str(error.value)


def test_a_real_platform_is_never_hosted(tmp_path: Path) -> None:
    text = BASE.replace(
        'agents.f2 = { role = "follower", follow = "kiruna/knatte" }',
        'agents.f2 = { role = "follower", follow = "kiruna/knatte", platform = "serial:/dev/x" }',
    )
    with pytest.raises(ConfigError, match=r"hosted\.sim\.1': 'f2' flies a real platform"):
        load_federation(write(tmp_path, text + '[labs.kiruna.hosted]\nsim = ["f1", "f2"]\n'))


def test_a_host_config_speaks_only_for_the_agents_it_lists(tmp_path: Path) -> None:
    out = tmp_path / "fed"
    gen.generate(load_federation(write(tmp_path, HOSTED)), out, local=True)
    sim = zenoh.Config.from_file(str(out / "kiruna" / "hosts" / "sim.json5"))
    f1, f2, f3 = (AgentId("kiruna", n) for n in ("f1", "f2", "f3"))
    check_hosted_identity(sim, [f1, f2], "sim.json5")
    check_hosted_identity(sim, [f2], "sim.json5")
    with pytest.raises(IdentityError, match=r"kiruna/f3 not among .* 'kiruna/hosts/sim'"):
        check_hosted_identity(sim, [f1, f3], "sim.json5")
    # An agent's own config speaks for it alone.
    knatte = zenoh.Config.from_file(str(out / "kiruna" / "agents" / "knatte.json5"))
    check_hosted_identity(knatte, [AgentId("kiruna", "knatte")], "knatte.json5")
    with pytest.raises(IdentityError, match="lists no hosted agents"):
        check_hosted_identity(knatte, [AgentId("kiruna", "knatte"), f3], "knatte.json5")
    check_hosted_identity(zenoh.Config(), [f1, f2, f3], "plain tcp")  # nothing to prove
    # The host's certificate beside another identity's user name: refused, whichever
    # of the two the router would judge it by (only the certificate had been read).
    sim.insert_json5("transport/auth/usrpwd/user", '"kiruna/knatte"')
    with pytest.raises(IdentityError, match="CN is 'kiruna/hosts/sim' and the user name is"):
        check_hosted_identity(sim, [f1, f2], "sim.json5")
    sim.insert_json5("transport/auth/usrpwd/user", '"kiruna/hosts/sim"')
    check_hosted_identity(sim, [f1, f2], "sim.json5")  # one identity, said twice


def test_a_host_named_like_a_former_agent_gets_a_new_identity(tmp_path: Path) -> None:
    """Agent f3 leaves and a host takes its name: the host's certificate is a new one
    (CN kiruna/hosts/f3), so f3's old key, wherever it still is, speaks for nothing."""
    out = tmp_path / "fed"
    source = write(tmp_path, BASE)
    gen.generate(load_federation(source), out)
    old_cert = (out / "ca" / "kiruna.f3.pem").read_bytes()
    text = BASE.replace('agents.f3 = { role = "follower", follow = "kiruna/knatte" }\n', "")
    source.write_text(text + '[labs.kiruna.hosted]\nf3 = ["f1", "f2"]\n')
    done = gen.generate(load_federation(source), out)
    assert "kiruna/hosts/f3" in done.issued
    assert (out / "kiruna" / "certs" / "kiruna.hosts.f3.pem").read_bytes() != old_cert
    router = gen.router_config(load_federation(source), "kiruna", gen.DEFAULT_ROOT)
    assert acl(router, "kiruna/f3") == (set(), set())
    assert acl(router, "kiruna/hosts/f3")[0] == own("kiruna/f1", "kiruna/f2")


@pytest.mark.parametrize("key", ["platform", "role", "follow", "lab", "name", "federation"])
def test_settings_cannot_override_what_the_entry_sets(tmp_path: Path, key: str) -> None:
    """A hosted agent's platform is checked on its entry: settings may not change it (nor
    any other field the entry or the file sets)."""
    value = "serial:/dev/ttyUSB0" if key == "platform" else "x"
    text = BASE.replace(
        'agents.f1 = { role = "follower", follow = "kiruna/knatte" }',
        f'agents.f1 = {{ role = "follower", follow = "kiruna/knatte", '
        f'settings = {{ {key} = "{value}" }} }}',
    )
    with pytest.raises(ConfigError, match=rf"labs\.kiruna\.agents\.f1\.settings\.{key}'"):
        load_federation(write(tmp_path, text))


def test_deploy_check_lists_each_labs_hosts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from federation import cli

    assert cli.main(["deploy", "check", str(write(tmp_path, HOSTED))]) == 0
    out = capsys.readouterr().out
    assert (
        "kiruna: certificate, 4 agent(s), 0 operator(s), 1 hosted process(es) (sim runs f1, f2)"
        in out
    )


def test_two_entries_making_one_access_control_id_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A host "a-link" of Kiruna and a neighbouring lab "host-a" would both make the
    policy id "host-a-link": refused by deploy check and generate, nothing written."""
    from federation import cli

    text = BASE.replace("[labs.rome]", "[labs.host-a]")
    source = write(tmp_path, text + '[labs.kiruna.hosted]\n"a-link" = ["f1"]\n')
    said = "labs.kiruna: two entries make the access-control policy id 'host-a-link'"
    assert cli.main(["deploy", "check", str(source)]) == 2
    assert f"{source}: {said}" in capsys.readouterr().err
    out = tmp_path / "fed"
    assert cli.main(["deploy", "generate", str(source), "--out", str(out), "--local"]) == 2
    assert f"{source}: {said}" in capsys.readouterr().err
    assert not (out / "kiruna" / "routers").exists()


def test_a_pair_issued_for_another_name_is_never_reused(tmp_path: Path) -> None:
    """A pair in the CA folder whose certificate names someone else (copied, renamed,
    or left by another layout) is replaced, not handed to the new name."""
    import shutil

    from federation.runtime.identity import certificate_cn

    out = tmp_path / "fed"
    gen.generate(load_federation(write(tmp_path, BASE)), out)
    ca = out / "ca"
    for suffix in (".pem", ".key"):  # f3's pair where sim's would be
        shutil.copyfile(ca / f"kiruna.f3{suffix}", ca / f"kiruna.sim{suffix}")
    text = BASE.replace("agents.knatte", 'agents.sim = { role = "member" }\nagents.knatte')
    done = gen.generate(load_federation(write(tmp_path, text)), out)
    assert "kiruna/sim" in done.issued
    fresh = (ca / "kiruna.sim.pem").read_bytes()
    assert certificate_cn(fresh, "sim") == "kiruna/sim"
    assert (ca / "kiruna.sim.key").read_bytes() != (ca / "kiruna.f3.key").read_bytes()


def test_a_lab_named_ca_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"labs\.ca': 'ca' is the CA's folder"):
        load_federation(write(tmp_path, BASE.replace("[labs.rome]", "[labs.ca]")))


def test_two_agents_of_one_host_writing_one_file_are_refused(tmp_path: Path) -> None:
    text = BASE
    for name in ("f1", "f2"):
        text = text.replace(
            f'agents.{name} = {{ role = "follower", follow = "kiruna/knatte" }}',
            f'agents.{name} = {{ role = "follower", follow = "kiruna/knatte", '
            'settings = { status_json = "s.jsonl" } }',
        )
    said = r"agents\.f2\.settings\.status_json': s\.jsonl is also f1"
    with pytest.raises(ConfigError, match=said):
        load_federation(write(tmp_path, text + '[labs.kiruna.hosted]\nsim = ["f1", "f2"]\n'))
    load_federation(write(tmp_path, text))  # apart, in two processes, they may


def test_a_hosts_config_run_as_an_agent_says_so(tmp_path: Path) -> None:
    from federation.runtime.identity import check_identity

    out = tmp_path / "fed"
    gen.generate(load_federation(write(tmp_path, HOSTED)), out, local=True)
    sim = zenoh.Config.from_file(str(out / "kiruna" / "hosts" / "sim.json5"))
    with pytest.raises(IdentityError, match=r"a hosted process's .* run it with fedlab host"):
        check_identity(sim, AgentId("kiruna", "f1"), "sim.json5")
