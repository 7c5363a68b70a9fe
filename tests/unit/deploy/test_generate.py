"""One federation file -> every config (federation/deploy/generate.py, schemas/federation.py)
and identity = name (federation/runtime/identity.py). No processes: the generated
configs run with real routers in tests/integration/test_trust.py."""

from __future__ import annotations

import json
import shutil
import stat
import tomllib
from pathlib import Path
from typing import Any

import pytest
import zenoh

from federation import cli
from federation.core.keys import AgentId
from federation.deploy import generate as gen
from federation.runtime.identity import IdentityError, check_identity, identities
from schemas.base import ConfigError
from schemas.config import AgentConfig
from schemas.federation import load_federation

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "deploy" / "federation.example.toml"
THREE = ROOT / "deploy" / "federation.three-labs.toml"


def _policy(doc: dict[str, Any], subject_name: str) -> list[dict[str, Any]]:
    """The rules that apply to the subject listing ``subject_name``."""
    acl = doc["access_control"]
    ids = {
        s["id"]
        for s in acl["subjects"]
        if subject_name in s.get("cert_common_names", []) + s.get("usernames", [])
    }
    rules = {r["id"]: r for r in acl["rules"]}
    return [rules[r] for p in acl["policies"] if set(p["subjects"]) & ids for r in p["rules"]]


def _writes(doc: dict[str, Any], subject_name: str) -> set[str]:
    return {
        k
        for r in _policy(doc, subject_name)
        if r["flows"] == ["ingress"] and "put" in r["messages"]
        for k in r["key_exprs"]
    }


def test_the_shipped_tls_configs_are_the_examples_generated_output() -> None:
    fed = load_federation(EXAMPLE)
    for lab in fed.labs:
        shipped = ROOT / "deploy" / "routers" / "tls" / f"{lab}.json5"
        assert shipped.read_text() == gen.router_text(fed, lab), (
            f"{shipped} is stale: regenerate it from {EXAMPLE.name} (gen.router_text)"
        )


def test_each_agent_writes_only_its_own_keys_and_operators_only_control() -> None:
    fed = load_federation(EXAMPLE)
    kiruna = gen.router_config(fed, "kiruna", gen.DEFAULT_ROOT)
    rome = gen.router_config(fed, "rome", gen.DEFAULT_ROOT)
    # Its token and the protocol's keys: nothing else under its name (an insider's own
    # keys would otherwise carry whatever it likes across the lab link).
    own = "fedlab/default/kiruna/knatte"
    assert _writes(kiruna, "kiruna/knatte") == {
        own, f"{own}/pose", f"{own}/sync", f"{own}/status", f"{own}/recordings", f"{own}/role"
    }  # fmt: skip
    assert _writes(kiruna, "kiruna/ctl") == {"fedlab/default/control"}
    assert "fedlab/default/rome/pinocchio/**" not in _writes(rome, "rome/pinocchio")
    assert "fedlab/default/rome/pinocchio/pose" in _writes(rome, "rome/pinocchio")
    # Rome's agents by user name, Kiruna's by certificate.
    subjects = {s["id"]: s for s in rome["access_control"]["subjects"]}
    assert subjects["agent-pinocchio"] == {"id": "agent-pinocchio", "usernames": ["rome/pinocchio"]}
    assert subjects["kiruna-router"] == {"id": "kiruna-router", "cert_common_names": ["kiruna"]}
    # Nothing but an agent's own rule may write under its lab.
    for doc, lab in ((kiruna, "kiruna"), (rome, "rome")):
        for rule in doc["access_control"]["rules"]:
            if "put" in rule["messages"] and rule["id"].startswith("writes-"):
                name = rule["id"].removeprefix("writes-")
                assert all(k.startswith(f"fedlab/default/{lab}/{name}") for k in rule["key_exprs"])
    assert kiruna["access_control"]["default_permission"] == "deny"


def test_a_neighbour_router_writes_only_the_labs_behind_it() -> None:
    fed = load_federation(THREE)
    kiruna = gen.router_config(fed, "kiruna", gen.DEFAULT_ROOT)
    lund = gen.router_config(fed, "lund", gen.DEFAULT_ROOT)
    assert _writes(kiruna, "rome") == {"fedlab/default/rome/**", "fedlab/default/control"}
    # Lund lists no operator: its router carries no control (its pair could otherwise
    # start, or reset, every platform of the federation).
    assert _writes(kiruna, "lund") == {"fedlab/default/lund/**"}
    assert _writes(lund, "kiruna") == {
        "fedlab/default/kiruna/**",
        "fedlab/default/rome/**",
        "fedlab/default/control",
    }
    # Lund dials Kiruna (certificates) over QUIC: pose as datagrams (federation/deploy/lablink.py)
    assert lund["connect"]["endpoints"] == ["quic/kiruna.example.org:7447?mixed_rel=1"]
    assert kiruna["connect"]["endpoints"] == []


def test_generate_writes_valid_configs_and_keeps_secrets_on_regenerate(tmp_path: Path) -> None:
    fed = load_federation(THREE)
    out = tmp_path / "fed"
    first = gen.generate(fed, out)
    assert "default federation CA" in first.issued
    for path in first.files:
        if path.suffix == ".json5":
            zenoh.Config.from_file(str(path))  # a valid Zenoh config (zenohd's format)
    for lab in fed.labs:
        for toml in (out / lab / "agents").glob("*.toml"):
            AgentConfig.model_validate(tomllib.loads(toml.read_text()))
    router = json.loads(
        zenoh.Config.from_file(str(out / "rome" / "routers" / "rome.json5")).get_json("transport")
    )
    assert router["link"]["rx"]["max_message_size"] == fed.message_limit
    assert router["auth"]["usrpwd"]["dictionary_file"] == "/etc/fedlab/rome.users"
    users = out / "rome" / "rome.users"
    assert stat.S_IMODE(users.stat().st_mode) == 0o600
    assert stat.S_IMODE((out / "rome" / "agents" / "pinocchio.json5").stat().st_mode) == 0o600
    assert stat.S_IMODE((out / "kiruna" / "certs" / "kiruna.knatte.key").stat().st_mode) == 0o600
    assert not (out / "kiruna" / "certs" / "ca.key").exists()  # the CA key stays in ca/
    passwords = users.read_text()
    lab_cert = (out / "ca" / "kiruna.pem").read_bytes()
    agent_cert = (out / "ca" / "kiruna.knatte.pem").read_bytes()

    again = gen.generate(fed, out)
    assert again.issued == []  # nothing changed: every certificate and password kept
    assert users.read_text() == passwords
    assert (out / "ca" / "kiruna.pem").read_bytes() == lab_cert
    assert (out / "ca" / "kiruna.knatte.pem").read_bytes() == agent_cert


def test_one_edit_adds_or_removes_an_agent(tmp_path: Path) -> None:
    source = tmp_path / "federation.toml"
    text = EXAMPLE.read_text()
    source.write_text(text + '\n[labs.kiruna.agents.newbie]\nrole = "member"\n')
    out = tmp_path / "fed"
    done = gen.generate(load_federation(source), out)
    assert "kiruna/newbie" in done.issued
    router = (out / "kiruna" / "routers" / "kiruna.json5").read_text()
    assert '"kiruna/newbie"' in router
    source.write_text(text)  # and gone again
    done = gen.generate(load_federation(source), out)
    assert out / "kiruna" / "agents" / "newbie.json5" in done.removed
    assert '"kiruna/newbie"' not in (out / "kiruna" / "routers" / "kiruna.json5").read_text()


def test_local_points_every_path_into_the_labs_folder(tmp_path: Path) -> None:
    out = tmp_path / "fed"
    gen.generate(load_federation(EXAMPLE), out, local=True)
    conf = zenoh.Config.from_file(str(out / "kiruna" / "agents" / "knatte.json5"))
    cert = json.loads(conf.get_json("transport/link/tls/connect_certificate"))
    assert cert == str(out.resolve() / "kiruna" / "certs" / "kiruna.knatte.pem")
    unit = (out / "kiruna" / "systemd" / "fedlab-router@.service").read_text()
    assert str(out.resolve() / "kiruna") in unit and "/etc/fedlab" not in unit


@pytest.mark.parametrize(
    ("edit", "field", "reason"),
    [
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\ndial = ["oslo"]\n', "labs.lund.dial.0",
         "'oslo' is not in labs"),
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\n', "labs", "lund linked to no other lab"),
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\ndial = ["rome"]\n', "labs.rome.endpoint",
         "missing: lund dials rome"),
        ('[labs.lund]\nlisten = ["tcp/127.0.0.1:1"]\ndial = ["kiruna"]\n', "labs.lund.listen.0",
         "every link of a federation is TLS"),
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\ndial = ["kiruna"]\nagents.x = '
         '{ role = "follower" }\n', "labs.lund.agents.x", "a follower needs 'follow'"),
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\ndial = ["kiruna"]\nagents.x = '
         '{ role = "follower", follow = "rome/nobody" }\n', "labs.lund.agents.x.follow",
         "rome/nobody is not an agent here"),
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\ndail = ["kiruna"]\n', "labs.lund.dail",
         "unknown field"),
        # Its rules, fedlab/<fed>/control/**, would take in the control key.
        ('[labs.control]\nlisten = ["tls/127.0.0.1:1"]\ndial = ["kiruna"]\n', "labs.control",
         "'control' is reserved"),
        # Kiruna's router's name on Lund's certificate: either could stand in for the other.
        ('[labs.lund]\nlisten = ["tls/127.0.0.1:1"]\ndial = ["kiruna"]\n'
         'hosts = ["kiruna.example.org"]\n', "labs.lund",
         "kiruna.example.org is also a name of kiruna's router certificate"),
    ],
)  # fmt: skip
def test_a_bad_federation_file_fails_naming_the_field(
    tmp_path: Path, edit: str, field: str, reason: str
) -> None:
    source = tmp_path / "federation.toml"
    source.write_text(EXAMPLE.read_text() + "\n" + edit)
    with pytest.raises(ConfigError) as error:
        load_federation(source)
    assert f"{source}: field '{field}': " in str(error.value) and reason in str(error.value)


def test_a_password_lab_cannot_be_dialled(tmp_path: Path) -> None:
    source = tmp_path / "federation.toml"
    text = EXAMPLE.read_text().replace('auth = "password"', 'auth = "certificate"', 1)
    text = text.replace('auth = "certificate"', 'auth = "password"', 1)  # kiruna's, dialled
    source.write_text(text)
    with pytest.raises(ConfigError, match=r"field 'labs.kiruna.auth': 'password' on a lab"):
        load_federation(source)


def test_deploy_cli_reports_a_bad_file_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = tmp_path / "federation.toml"
    source.write_text('federation = "Bad Name"\n[labs.x]\nlisten = ["tls/a:1"]\n')
    assert cli.main(["deploy", "check", str(source)]) == 2
    assert "field 'federation'" in capsys.readouterr().err
    assert cli.main(["deploy", "check", str(EXAMPLE)]) == 0
    assert "rome: password, 1 agent(s), 1 operator(s), dials kiruna" in capsys.readouterr().out


# -- identity = name -----------------------------------------------------------------
def test_identity_is_the_certificate_cn_or_the_user_name(tmp_path: Path) -> None:
    out = tmp_path / "fed"
    gen.generate(load_federation(EXAMPLE), out, local=True)
    knatte = zenoh.Config.from_file(str(out / "kiruna" / "agents" / "knatte.json5"))
    pinocchio = zenoh.Config.from_file(str(out / "rome" / "agents" / "pinocchio.json5"))
    assert identities(knatte, "k") == {"certificate CN": "kiruna/knatte"}
    assert identities(pinocchio, "p") == {"user name": "rome/pinocchio"}
    check_identity(knatte, AgentId("kiruna", "knatte"), "knatte.json5")
    check_identity(pinocchio, AgentId("rome", "pinocchio"), "pinocchio.json5")
    with pytest.raises(IdentityError, match="CN is 'kiruna/knatte' but this agent is kiruna/x"):
        check_identity(knatte, AgentId("kiruna", "x"), "knatte.json5")
    with pytest.raises(IdentityError, match="user name is 'rome/pinocchio' but this agent is"):
        check_identity(pinocchio, AgentId("rome", "evil"), "pinocchio.json5")
    check_identity(zenoh.Config(), AgentId("rome", "any"), "plain tcp")  # nothing to prove
    missing = zenoh.Config()
    missing.insert_json5("transport/link/tls/connect_certificate", '"/nonexistent.pem"')
    with pytest.raises(IdentityError, match=r"nonexistent\.pem"):
        check_identity(missing, AgentId("rome", "any"), "x.json5")


def test_the_deployment_docs_match_the_generators_output(tmp_path: Path) -> None:
    """docs/deploy.md, 'One federation file': its TOML is the example file, every file its
    table lists is what generate writes, and every command it shows parses."""
    docs = (ROOT / "docs" / "deploy.md").read_text()
    section = docs.split("## One federation file", 1)[1].split("\n## ", 1)[0]
    blocks = section.split("```")
    toml_block = next(b for b in blocks if b.startswith("toml\n")).removeprefix("toml\n")
    assert tomllib.loads(toml_block) == tomllib.loads(EXAMPLE.read_text())

    out = tmp_path / "fed"
    gen.generate(load_federation(EXAMPLE), out)
    written = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    rows = [line.split("|")[1].strip().strip("`") for line in section.splitlines()
            if line.startswith("| `fed/")]  # fmt: skip
    assert rows, "no table of generated files"
    for row in rows:
        prefixes = {
            row.removeprefix("fed/").replace("<lab>", lab).replace("<name>", name)
            for lab, names in (("kiruna", ["knatte", "ctl"]), ("rome", ["pinocchio", "ctl"]))
            for name in names
        }
        assert any(w.startswith(p) for p in prefixes for w in written), f"{row}: not generated"
    for lab in ("kiruna", "rome"):  # and what generate writes, the table lists
        for path in written:
            if path.startswith(f"{lab}/"):
                kind = path.split("/")[1]
                assert any(f"fed/<lab>/{kind}" in r for r in rows) or kind == f"{lab}.users"
    for line in section.splitlines():  # the commands shown parse as fedlab commands
        if line.startswith("fedlab "):
            argv = line.split("#")[0].split()[1:]
            args = cli.build_parser().parse_args(argv)
            assert args.command == "deploy"


def _serial(path: Path) -> int:
    from cryptography import x509

    return x509.load_pem_x509_certificate(path.read_bytes()).serial_number


def test_a_removed_or_recast_identity_never_gets_its_old_key_or_password_back(
    tmp_path: Path,
) -> None:
    """Removing an agent is how a leaked key is shut out: listing the name again (as an
    agent, or worse as an operator, whose CN has the same form) must not trust it."""
    text = THREE.read_text()
    pin = (
        'agents.pinocchio = { role = "follower", platform = "pinocchio", '
        + 'follow = "kiruna/knatte" }'
    )
    y = 'agents.y = { role = "follower", platform = "pinocchio", follow = "kiruna/knatte" }'
    assert pin in text
    with_x = text.replace(
        'agents.knatte = { role = "leader", platform = "knatte" }',
        'agents.knatte = { role = "leader", platform = "knatte" }\n'
        'agents.x = { role = "follower", platform = "knatte", follow = "kiruna/knatte" }',
    ).replace(pin, f"{pin}\n{y}")
    as_operator = with_x.replace(
        'agents.x = { role = "follower", platform = "knatte", follow = "kiruna/knatte" }', ""
    ).replace('operators = ["ctl"]\nagents.knatte', 'operators = ["ctl", "x"]\nagents.knatte')
    as_operator = as_operator.replace(y, "").replace(
        'operators = ["ctl"]\nagents.pinocchio', 'operators = ["ctl", "y"]\nagents.pinocchio'
    )
    files = {}
    for name, body in (("x", with_x), ("none", text), ("op", as_operator)):
        files[name] = tmp_path / f"{name}.toml"
        files[name].write_text(body)
    out = tmp_path / "fed"
    pem = out / "ca" / "kiruna.x.pem"

    def password(user: str) -> str | None:
        for line in (out / "rome" / "rome.users").read_text().splitlines():
            if line.startswith(f"{user}:"):
                return line.split(":", 1)[1]
        return None

    gen.generate(load_federation(files["x"]), out)
    first = _serial(pem)
    gen.generate(load_federation(files["x"]), out)
    assert _serial(pem) == first  # kept while listed as the same kind
    before = password("rome/y")
    assert before is not None
    # Recast in one run, agent to operator: refused in the certificate lab (the router
    # knows kiruna/x by its certificate's name alone: its old one would publish control),
    # and nothing moved.
    with pytest.raises(ConfigError, match=r"labs\.kiruna'.*kiruna/x was a agent until now"):
        gen.generate(load_federation(files["op"]), out)
    assert _serial(pem) == first
    # A password lab's name recast gets a new password (the old one no longer logs in).
    y_op = with_x.replace(y, "").replace(
        'operators = ["ctl"]\nagents.pinocchio', 'operators = ["ctl", "y"]\nagents.pinocchio'
    )
    files["y_op"] = tmp_path / "y_op.toml"
    files["y_op"].write_text(y_op)
    recast = gen.generate(load_federation(files["y_op"]), out)
    assert password("rome/y") not in (None, before)
    assert recast.role_changed == ["rome/y"] and _serial(pem) == first
    # Removed (its key leaked, say): retired. Listed again, as an agent or an operator,
    # it is refused: a new pair would not shut the old certificate out.
    gen.generate(load_federation(files["none"]), out)
    assert not pem.exists() and (out / "ca" / "retired" / f"kiruna.x.{first:x}.pem").exists()
    for again in ("x", "op"):
        with pytest.raises(ConfigError, match="kiruna/x was removed before"):
            gen.generate(load_federation(files[again]), out)
    # A new CA trusts no old certificate: the name may come back.
    shutil.rmtree(out / "ca")
    gen.generate(load_federation(files["op"]), out)
    assert _serial(pem) != first


def test_every_recording_unit_shares_one_promises_ledger(tmp_path: Path) -> None:
    # Each unit's /tmp is its own (PrivateTmp): with the ledger's default folder, agents
    # in units of their own had each taken half of the same free space.
    out = tmp_path / "fed"
    gen.generate(load_federation(EXAMPLE), out)
    for name in ("fedlab-agent@.service", "fedlab-host@.service"):
        unit = (out / "kiruna" / "systemd" / name).read_text()
        assert "PrivateTmp=yes" in unit
        assert "Environment=FEDLAB_PROMISES=/var/lib/fedlab/promises\n" in unit, name
        states = next(line for line in unit.splitlines() if line.startswith("StateDirectory="))
        assert "fedlab/promises" in states.split("=", 1)[1].split(), name


def _settings(folder: Path, lab: str, name: str, hosted: str | None = None) -> dict[str, Any]:
    where = folder / lab / ("agents" if hosted is None else f"hosts/{hosted}")
    return tomllib.loads((where / f"{name}.toml").read_text())


def test_a_generated_agent_records_its_runs_where_collect_finds_them(tmp_path: Path) -> None:
    # In its service's state folder (the unit's StateDirectory), a hosted agent in its
    # host's; on one host (--local), in the lab folder's state/.
    text = EXAMPLE.read_text() + '\n[labs.kiruna.hosted]\nsim = ["ghost"]\n'
    text += '[labs.kiruna.agents.ghost]\nrole = "member"\nplatform = "kinematic"\n'
    source = tmp_path / "federation.toml"
    source.write_text(text)
    fed = load_federation(source)
    gen.generate(fed, tmp_path / "fed")
    assert _settings(tmp_path / "fed", "kiruna", "knatte")["runs_dir"] == (
        "/var/lib/fedlab/knatte/runs"
    )
    assert _settings(tmp_path / "fed", "rome", "pinocchio")["runs_dir"] == (
        "/var/lib/fedlab/pinocchio/runs"
    )
    assert _settings(tmp_path / "fed", "kiruna", "ghost", hosted="sim")["runs_dir"] == (
        "/var/lib/fedlab/sim/runs"
    )
    gen.generate(fed, tmp_path / "local", local=True)
    settings = _settings(tmp_path / "local", "kiruna", "knatte")
    runs = tmp_path / "local" / "kiruna" / "state" / "knatte" / "runs"
    assert settings["runs_dir"] == str(runs)
    # What the agent makes of it: a config that records (preflight's "recording").
    config = AgentConfig.model_validate(settings)
    assert config.runs_dir == runs
    assert config.wait_start


def test_runs_dir_is_taken_in_the_agents_entry_or_its_settings_but_once(tmp_path: Path) -> None:
    entry = '[labs.kiruna.agents.knatte]\nrole = "leader"\nplatform = "knatte"\n'
    base = EXAMPLE.read_text()
    assert entry in base
    source = tmp_path / "federation.toml"
    source.write_text(base.replace(entry, entry + 'runs_dir = "/data/runs"\n'))
    gen.generate(load_federation(source), tmp_path / "a")
    assert _settings(tmp_path / "a", "kiruna", "knatte")["runs_dir"] == "/data/runs"
    source.write_text(base.replace(entry, entry + 'settings = { runs_dir = "/data/other" }\n'))
    gen.generate(load_federation(source), tmp_path / "b")
    assert _settings(tmp_path / "b", "kiruna", "knatte")["runs_dir"] == "/data/other"
    both = entry + 'runs_dir = "/data/runs"\nsettings = { runs_dir = "/data/other" }\n'
    source.write_text(base.replace(entry, both))
    with pytest.raises(ConfigError, match=r"labs\.kiruna\.agents\.knatte\.settings\.runs_dir"):
        load_federation(source)
