"""A whole federation from one file: ``fedlab deploy generate federation.toml --out DIR``.

From a :class:`schemas.federation.FederationFile` it writes, for every lab, the folder
that lab installs as ``/etc/fedlab`` (the ``root``), and beside them the CA::

    DIR/ca/                      the federation CA and every certificate it signed:
                                 keep it offline, the CA key never goes to a lab
    DIR/<lab>/routers/<lab>.json5        the lab router (TLS, per-agent access control)
    DIR/<lab>/agents/<name>.toml         an agent's settings (fedlab agent --agent-config);
                                         it records its runs in /var/lib/fedlab/<name>/runs
    DIR/<lab>/agents/<name>.json5        its Zenoh client config (certificate or password)
    DIR/<lab>/hosts/<host>.json5         a hosted process's Zenoh config (fedlab host -c ...)
    DIR/<lab>/hosts/<host>/<name>.toml   the settings of each agent it runs
    DIR/<lab>/operators/<name>.json5     an operator's Zenoh config (fedlab ctl -c ...)
    DIR/<lab>/certs/                     ca.pem, the lab's pair, its agents' and operators'
    DIR/<lab>/<lab>.users                user:password lines (password labs only, 0600)
    DIR/<lab>/systemd/                   fedlab-router@, fedlab-agent@, fedlab-host@.service

Every path inside a generated file is absolute under ``root`` (``/etc/fedlab`` by
default; ``local=True`` puts each lab's own ``DIR/<lab>`` there and its router on
loopback, to run a whole federation on one host: :mod:`federation.deploy.local`).
Generating again keeps the CA, every certificate whose names did not change and
every password: adding a lab or an agent is one edit of
the file and one run. Agents and operators no longer in the file lose their
generated configs and, above all, their access-control entries.

Access control (default deny), enforced by each lab's router on the sessions attached to
it: an agent may write (put, delete, declare a queryable or a liveliness token, reply)
only on its own address, ``fedlab/<fed>/<lab>/<name>``, and the protocol's keys below it
(pose, sync, status, recordings); a hosted process (``fedlab host``, the lab's
``hosted``) only on the addresses of the agents it runs, which have no identity of their
own; operators only put on the control key; another lab's router only under the labs
reached through it, and the control key if an operator is among those labs; every listed
identity reads the federation's keys. A certificate CN (or user name) no subject lists
can do nothing. What an identity that may write can send (sizes per key, its agents'
pose and status rates) is bounded by :mod:`federation.deploy.limits`.
"""

from __future__ import annotations

import ipaddress
import json
import secrets
import shutil
import textwrap
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography import x509

from federation.core.keys import control_key
from federation.deploy import certs, lablink, limits
from federation.deploy.local import localize
from federation.runtime.identity import HOSTED_FIELD, certificate_cn
from federation.runtime.session import DATA_QUEUE_BATCHES
from schemas.base import ConfigError
from schemas.federation import FederationFile, LabEntry

__all__ = [
    "DEFAULT_ROOT",
    "STATE_ROOT",
    "SYSTEMD_DIR",
    "WRITES",
    "Generated",
    "agent_zenoh",
    "generate",
    "host_zenoh",
    "router_config",
    "router_text",
    "toml_text",
]

DEFAULT_ROOT = Path("/etc/fedlab")
STATE_ROOT = Path("/var/lib/fedlab")
"""Where each service keeps its state (the units' ``StateDirectory=fedlab/<name>``): a
generated agent records its runs in ``STATE_ROOT/<name>/runs`` (a hosted one in its
host's), there for ``fedlab collect``."""
SYSTEMD_DIR = Path(__file__).resolve().parents[2] / "deploy" / "systemd"
"""The unit templates copied into each lab's folder."""

WRITES = ["put", "delete", "declare_queryable", "liveliness_token", "reply"]
"""The messages that speak for a key: who may send them under a key owns it."""
READS = ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"]
ALL_MESSAGES = [
    "put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
    "liveliness_token", "declare_liveliness_subscriber", "liveliness_query",
]  # fmt: skip
_PASSWORD_BYTES = 24


@dataclass
class Generated:
    """What one run wrote: every file, and the certificates issued (not reused) now."""

    files: list[Path] = field(default_factory=list)
    issued: list[str] = field(default_factory=list)
    removed: list[Path] = field(default_factory=list)
    role_changed: list[str] = field(default_factory=list)  # identities now of another kind
    listening: dict[str, str] = field(default_factory=dict)  # lab -> its router's endpoint


LEASE_MS = 10000
"""Lab routers' Zenoh lease (Zenoh's default), measured against 15 s: after a WAN cut
longer than the lease a fresh session carries at once, while a longer lease keeps the
old one, whose TCP backlog must drain first (docs/deploy.md, "A WAN cut")."""


def _prefix(fed: str) -> str:
    return f"fedlab/{fed}"


def _common(limit: int) -> dict[str, Any]:
    """What routers, agents and operators share: no scouting, Zenoh's universal
    transport with QoS on (what a default Zenoh client uses; with QoS off a congested
    link drops pose for good: docs/deploy.md, "Transports under loss"), the largest
    message they accept, and no shared memory (a Zenoh 1.10 process keeps every
    same-host sender's pool mapped for good, and a message in one bypasses the size
    limits: docs/deploy.md, "Bounded resources")."""
    return {
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "unicast": {"lowlatency": False, "qos": {"enabled": True}},
            "link": {"protocols": ["tls"], "rx": {"max_message_size": limit}},
            "shared_memory": {"enabled": False},
        },
    }


def _subject(lab: LabEntry, id_: str, names: list[str]) -> dict[str, Any]:
    key = "usernames" if lab.auth == "password" else "cert_common_names"
    return {"id": id_, key: names}


def _rule(id_: str, flows: str, messages: list[str], keys: list[str]) -> dict[str, Any]:
    return {
        "id": id_,
        "permission": "allow",
        "flows": [flows],
        "messages": messages,
        "key_exprs": keys,
    }


def access_control(fed: FederationFile, lab: str) -> dict[str, Any]:
    """Lab ``lab``'s router's ``access_control`` section (see the module docstring)."""
    entry, prefix = fed.labs[lab], _prefix(fed.federation)
    control = control_key(fed.federation)
    rules = [
        _rule("control", "ingress", ["put"], [control]),
        _rule("reads", "ingress", READS, [f"{prefix}/**"]),
        _rule("deliver", "egress", ALL_MESSAGES, [f"{prefix}/**"]),
    ]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for other in fed.neighbours(lab):
        behind = fed.behind(lab, other)
        keys = [f"{prefix}/{far}/**" for far in behind]
        # Control crosses a link only when an operator sits behind it: a lab with no
        # operator has nobody whose start or abort its router may carry.
        if any(fed.labs[far].operators for far in behind):
            keys.append(control)
        rules.append(_rule(f"from-{other}", "ingress", WRITES, keys))
        subjects.append({"id": f"{other}-router", "cert_common_names": [other]})
        policies.append(
            {
                "id": f"{other}-link",
                "rules": [f"from-{other}", "reads", "deliver"],
                "subjects": [f"{other}-router"],
            }
        )
    for name in entry.agents:
        own = f"{prefix}/{lab}/{name}"
        keys = [own, *(f"{own}/{topic}" for topic in limits.AGENT_TOPICS)]
        rules.append(_rule(f"writes-{name}", "ingress", WRITES, keys))
        if entry.host_of(name) is not None:
            continue  # its host's identity speaks for it: none of its own
        subjects.append(_subject(entry, f"agent-{name}", [f"{lab}/{name}"]))
        policies.append(
            {
                "id": f"agent-{name}",
                "rules": [f"writes-{name}", "reads", "deliver"],
                "subjects": [f"agent-{name}"],
            }
        )
    for host, names in entry.hosted.items():
        subjects.append(_subject(entry, f"host-{host}", [certs.host_common_name(lab, host)]))
        policies.append(
            {
                "id": f"host-{host}",
                "rules": [*(f"writes-{name}" for name in names), "reads", "deliver"],
                "subjects": [f"host-{host}"],
            }
        )
    if entry.operators:
        subjects.append(_subject(entry, "operators", [f"{lab}/{o}" for o in entry.operators]))
        policies.append(
            {"id": "operators", "rules": ["control", "reads", "deliver"], "subjects": ["operators"]}
        )
    for kind, items in (("rule", rules), ("subject", subjects), ("policy", policies)):
        ids = [item["id"] for item in items]
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:  # e.g. a host "a-router" and the router of a neighbouring lab "host-a"
            raise ConfigError(
                f"labs.{lab}: two entries make the access-control {kind} id {twice[0]!r} "
                f"(an agent, host or neighbouring lab's name runs into another's): rename one"
            )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _listen(entry: LabEntry) -> list[str]:
    """A password lab's listeners take no client certificate (the password says who)."""
    if entry.auth == "certificate":
        return list(entry.listen)
    return [e if "enable_mtls" in e else f"{e}{'&' if '#' in e else '#'}enable_mtls=false"
            for e in entry.listen]  # fmt: skip


def router_config(fed: FederationFile, lab: str, root: Path) -> dict[str, Any]:
    """Lab ``lab``'s router config (a zenohd config as well as ``fedlab router -c``)."""
    entry, c = fed.labs[lab], root / "certs"
    doc: dict[str, Any] = {
        "mode": "router",
        "metadata": {"lab": lab, "federation": fed.federation},
        "listen": {"endpoints": _listen(entry) + lablink.listen_quic(fed, lab)},
        "connect": {
            "endpoints": lablink.dial(fed, lab),
            "timeout_ms": -1,
            "exit_on_failure": False,
        },
        **_common(limits.message_limit(fed)),
        "access_control": access_control(fed, lab),
        "low_pass_filter": limits.low_pass_filter(fed),
        "downsampling": limits.downsampling(fed, lab),
    }
    # Data batches queued as in fedlab's sessions (Zenoh's two dropped poses on a
    # busy host: docs/scale.md, "Loss on a busy host").
    doc["transport"]["link"]["protocols"] = lablink.protocols(fed, lab)
    doc["transport"]["link"]["tx"] = {
        "lease": LEASE_MS, "keep_alive": 4, "queue": {"size": {"data": DATA_QUEUE_BATCHES}}
    }  # fmt: skip
    doc["transport"]["link"]["tls"] = {
        "root_ca_certificate": str(c / "ca.pem"),
        "listen_certificate": str(c / f"{lab}.pem"),
        "listen_private_key": str(c / f"{lab}.key"),
        "connect_certificate": str(c / f"{lab}.pem"),
        "connect_private_key": str(c / f"{lab}.key"),
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }
    if entry.auth == "password":
        doc["transport"]["auth"] = {"usrpwd": {"dictionary_file": str(root / f"{lab}.users")}}
    return doc


def agent_zenoh(
    fed: FederationFile,
    lab: str,
    name: str,
    root: Path,
    password: str | None,
    identity: tuple[str, str] | None = None,
) -> dict[str, Any]:
    """The Zenoh client config of agent or operator ``lab/name``: its router, the CA, and
    its certificate (certificate labs) or user and password (password labs); another
    ``identity`` (its name and certificate stem: a hosted process's) if given."""
    user, stem = identity or (f"{lab}/{name}", certs.agent_stem(lab, name))
    entry, c = fed.labs[lab], root / "certs"
    doc: dict[str, Any] = {
        "mode": "client",
        "connect": {
            "endpoints": [entry.agents_endpoint()],
            "timeout_ms": -1,  # an agent waits for its router however long it takes
            "exit_on_failure": False,
        },
        **_common(limits.message_limit(fed)),
    }
    tls: dict[str, Any] = {"root_ca_certificate": str(c / "ca.pem")}
    if entry.auth == "certificate":
        tls |= {
            "connect_certificate": str(c / f"{stem}.pem"),
            "connect_private_key": str(c / f"{stem}.key"),
            "enable_mtls": True,  # a client shows its certificate only with this set
        }
    else:
        doc["transport"]["auth"] = {"usrpwd": {"user": user, "password": password}}
    doc["transport"]["link"]["tls"] = tls
    return doc


def agent_settings(fed: FederationFile, lab: str, name: str, state: Path) -> dict[str, Any]:
    """Agent ``lab/name``'s settings file (AgentConfig fields); ``state`` is the state
    folder of the service that runs it, under which it records its runs."""
    agent = fed.labs[lab].agents[name]
    data: dict[str, Any] = {"federation": fed.federation, "lab": lab, "name": name}
    # A deployed agent takes part in the federation's runs: it waits for ctl start
    # (held) instead of flying from the moment its service starts, and records each
    # run where collect finds it (unless its entry or its settings say elsewhere).
    data |= {"role": agent.role, "platform": agent.platform, "wait_start": True}
    data["runs_dir"] = agent.runs_dir or str(state / "runs")
    if agent.follow is not None:
        data["follow"] = agent.follow
    return data | agent.settings


def host_zenoh(
    fed: FederationFile, lab: str, host: str, root: Path, password: str | None
) -> dict[str, Any]:
    """The Zenoh client config of hosted process ``lab/hosts/host``: as an agent's, with
    the agents it runs listed in its metadata (``fedlab host`` checks them at start:
    :func:`federation.runtime.identity.check_hosted_identity`)."""
    identity = (certs.host_common_name(lab, host), certs.host_stem(lab, host))
    doc = agent_zenoh(fed, lab, host, root, password, identity)
    doc["metadata"] = {HOSTED_FIELD: [f"{lab}/{n}" for n in fed.labs[lab].hosted[host]]}
    return doc


def _write_hosts(
    fed: FederationFile,
    lab: str,
    folder: Path,
    lab_root: Path,
    state_root: Path,
    passwords: dict[str, str],
    header: str,
    out: Generated,
) -> None:
    """Each hosted process's Zenoh config and its agents' settings; what is no longer
    listed is removed."""
    entry, hosts = fed.labs[lab], folder / "hosts"
    kept: list[Path] = []
    for host, names in entry.hosted.items():
        conf = hosts / f"{host}.json5"
        doc = host_zenoh(fed, lab, host, lab_root, passwords.get(certs.host_common_name(lab, host)))
        _write(conf, json5_text(doc, header), 0o600, out)
        kept.append(conf)
        settings = [hosts / host / f"{name}.toml" for name in names]
        for name, path in zip(names, settings, strict=True):
            text = toml_text(agent_settings(fed, lab, name, state_root / host), header)
            _write(path, text, 0o644, out)
        _prune(hosts / host, settings, (".toml",), out)
    _prune(hosts, kept, (".json5",), out)
    if hosts.is_dir():
        gone = [p for p in hosts.iterdir() if p.is_dir() and p.name not in entry.hosted]
        for stale in sorted(gone):
            _prune(stale, [], (".toml",), out)
            if not any(stale.iterdir()):
                stale.rmdir()


def _header(fed: FederationFile, lab: str) -> str:
    return (
        f"Generated by `fedlab deploy generate` for lab {lab} of federation "
        f"{fed.federation}:\nedit the federation file and generate again, not this file."
    )


def router_text(fed: FederationFile, lab: str, root: Path = DEFAULT_ROOT) -> str:
    """Lab ``lab``'s router config file as generated (deploy/routers/tls/ holds the
    example federation's)."""
    entry = fed.labs[lab]
    dials = ", ".join(entry.dial) or "nothing (other labs dial it)"
    about = (
        f"\nLab {lab}: listens on {', '.join(entry.listen)}; dials {dials}; its agents and "
        f"operators authenticate by {entry.auth}.\nEach agent writes only under "
        f"fedlab/{fed.federation}/{lab}/<name>/**; operators publish control; see "
        "docs/deploy.md.\nlowlatency false, QoS on: the transport a default Zenoh client "
        "gets too (with QoS off, Zenoh 1.10 drops a congested link's pose and status for "
        "good). "
        f"Lease {LEASE_MS / 1000:g} s: after a longer WAN cut a fresh session carries at "
        "once, sooner than a kept one draining its backlog (measured: docs/deploy.md, A WAN "
        "cut)."
    )
    return json5_text(router_config(fed, lab, root), _header(fed, lab) + about)


# -- writing ---------------------------------------------------------------------------
def toml_text(data: dict[str, Any], header: str = "") -> str:
    """TOML for plain settings (strings, numbers, booleans, lists of them, one level of
    tables); checked by reading it back."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    lines += [f"{k} = {_toml_value(v)}" for k, v in data.items() if k not in tables]
    for key, table in tables.items():
        lines += ["", f"[{key}]", *(f"{k} = {_toml_value(v)}" for k, v in table.items())]
    text = "\n".join(lines) + "\n"
    if tomllib.loads(text) != data:
        raise ValueError(f"cannot write these settings as TOML: {data!r}")
    return text


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise ValueError(f"cannot write {value!r} as a TOML value")


def json5_text(doc: dict[str, Any], header: str) -> str:
    """JSON (valid json5) under a ``//`` comment header; what fits on a line stays on one."""
    lines = [part for line in header.splitlines() for part in textwrap.wrap(line, 86) or [""]]
    comment = "".join(f"// {line}".rstrip() + "\n" for line in lines)
    return comment + _json(doc, 0) + "\n"


def _json(value: Any, indent: int) -> str:
    flat = json.dumps(value)
    if not isinstance(value, dict | list) or indent + len(flat) <= 88:
        return flat
    pad, inner = " " * indent, " " * (indent + 2)
    if isinstance(value, list):
        items = [inner + _json(v, indent + 2) for v in value]
        return "[\n" + ",\n".join(items) + f"\n{pad}]"
    items = [f"{inner}{json.dumps(k)}: {_json(v, indent + 2)}" for k, v in value.items()]
    return "{\n" + ",\n".join(items) + f"\n{pad}}}"


def _write(path: Path, text: str, mode: int, out: Generated) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.chmod(mode)
    tmp.replace(path)
    out.files.append(path)


def _passwords(users: Path) -> dict[str, str]:
    """The ``user:password`` lines of an existing dictionary file (kept when regenerating)."""
    if not users.exists():
        return {}
    out = {}
    for line in users.read_text(encoding="utf-8").splitlines():
        user, sep, password = line.partition(":")
        if sep and user and password:
            out[user] = password
    return out


def _sans(path: Path) -> set[str]:
    cert = x509.load_pem_x509_certificate(path.read_bytes())
    try:
        ext = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return set()
    names = {str(v) for v in ext.get_values_for_type(x509.DNSName)}
    return names | {str(v) for v in ext.get_values_for_type(x509.IPAddress)}


def _normal(host: str) -> str:
    try:
        return str(ipaddress.ip_address(host))
    except ValueError:
        return host


@dataclass(frozen=True)
class _Identity:
    """Who proves who they are in a lab: a certificate CN or a user name, its files'
    stem in the certificate folder, and whether it is a hosted process."""

    name: str
    stem: str
    host: bool = False
    kind: str = "agent"  # agent, operator or host: what its pair or password may do


def _identities(lab: str, entry: LabEntry) -> list[_Identity]:
    """The agents that run on their own, the operators, and the hosted processes (whose
    agents have no identity of their own: their host speaks for them)."""
    alone = [n for n in [*entry.agents, *entry.operators] if entry.host_of(n) is None]
    out = [
        _Identity(
            certs.agent_common_name(lab, n),
            certs.agent_stem(lab, n),
            kind="operator" if n in entry.operators else "agent",
        )
        for n in alone
    ]
    for host in entry.hosted:
        out.append(
            _Identity(certs.host_common_name(lab, host), certs.host_stem(lab, host), True, "host")
        )
    return out


ROLES_FILE = "roles.json"
"""In the CA folder: each identity's kind (agent, operator, host) when it was last
generated. A pair or password is never carried over to another kind, nor to a name
listed again after it was removed (its key may be the leaked one)."""


def _retire_old_identities(
    fed: FederationFile, ca: Path, before: dict[str, str], now: dict[str, str], out: Generated
) -> None:
    """Move the pairs of identities no longer listed, or listed as another kind than
    ``before`` says, to ``ca/retired/``: listing the name again issues a new pair."""
    labs = {*fed.labs, "ca"}
    hosted = _hosted_names(fed)
    for pem in sorted(ca.glob("*.pem")):
        if pem.stem in labs:
            continue  # the CA and the labs' own pairs
        cn = _common_name(pem)
        if cn in hosted or (cn in now and before.get(cn, now[cn]) == now[cn]):
            continue
        retired = ca / "retired"
        retired.mkdir(exist_ok=True)
        serial = x509.load_pem_x509_certificate(pem.read_bytes()).serial_number
        for part in (pem, pem.with_suffix(".key")):
            if part.exists():
                part.rename(retired / f"{part.stem}.{serial:x}{part.suffix}")
                out.removed.append(part)


def _refuse_trusted_again(fed: FederationFile, ca: Path, before: dict[str, str]) -> None:
    """Refuse (ConfigError, naming the lab) to list, in a certificate lab, a name whose
    old certificate still chains to this CA: one removed before (its pair in
    ``ca/retired/``), or one listed now as another kind than before. Routers know an
    identity by its certificate's name alone and Zenoh has no revocation list, so a new
    pair would not shut the old one out: a leaked key, removed, would come back with the
    name, and an agent's old certificate recast as an operator's could publish control."""
    retired_dir = ca / "retired"
    retired = (
        {_common_name(p) for p in retired_dir.glob("*.pem")} if retired_dir.is_dir() else set()
    )
    for lab, entry in fed.labs.items():
        if entry.auth != "certificate":
            continue  # a password lab's recast or returning name gets a new password
        for who in _identities(lab, entry):
            was = before.get(who.name)
            recast = was is not None and was != who.kind and (ca / f"{who.stem}.pem").exists()
            if who.name not in retired and not recast:
                continue
            history = f"was a {was} until now" if recast else "was removed before"
            raise ConfigError(
                f"field 'labs.{lab}': {who.name} {history}, and its old certificate still "
                f"chains to this CA: routers know an identity by its certificate's name "
                f"alone (no revocation list), so listing it as a {who.kind} would trust that "
                f"certificate (its key perhaps the leaked one) again. Give it a new name, or "
                f"issue a new CA (delete {ca} and generate: every lab installs again)"
            )


def _hosted_names(fed: FederationFile) -> set[str]:
    """The common names of the agents run by a host. Moved into a host, an agent is not
    distrusted: its pair stays in the CA folder (unused: the host speaks for it, and no
    rule names it) for when it moves out again, and its kind stays in the roles file."""
    return {
        certs.agent_common_name(lab, n)
        for lab, entry in fed.labs.items()
        for n in entry.agents
        if entry.host_of(n) is not None
    }


def _read_roles(ca: Path) -> dict[str, str]:
    path = ca / ROLES_FILE
    try:
        data = json.loads(path.read_text()) if path.exists() else {}
    except ValueError:
        return {}
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def _issue_certificates(fed: FederationFile, ca: Path, out: Generated) -> None:
    """The CA if missing, each lab's certificate (again if its names changed) and each
    certificate lab's agents' and operators' (if missing)."""
    if not (ca / "ca.pem").exists():
        certs.init_ca(ca, fed.federation)
        out.issued.append(certs.ca_common_name(fed.federation))
    before = _read_roles(ca)
    now = {who.name: who.kind for lab, e in fed.labs.items() for who in _identities(lab, e)}
    _refuse_trusted_again(fed, ca, before)  # before anything is moved
    _retire_old_identities(fed, ca, before, now, out)
    for lab, entry in fed.labs.items():
        hosts = entry.cert_hosts() or list(certs.DEFAULT_HOSTS)
        existing = ca / f"{lab}.pem"
        if not existing.exists() or _sans(existing) != {_normal(h) for h in hosts}:
            certs.issue_lab(ca, lab, hosts, force=True)
            out.issued.append(lab)
        if entry.auth == "certificate":
            for who in _identities(lab, entry):
                existing = ca / f"{who.stem}.pem"
                # A pair made for another name (an earlier layout's) is never reused.
                if not existing.exists() or _common_name(existing) != who.name:
                    if who.host:
                        certs.issue_host(ca, lab, who.name.rsplit("/", 1)[1], force=True)
                    else:
                        certs.issue_agent(ca, lab, who.name.split("/", 1)[1], force=True)
                    out.issued.append(who.name)
    kept = {cn: before[cn] for cn in _hosted_names(fed) if cn in before}
    roles = {**kept, **now}
    _write(ca / ROLES_FILE, json.dumps(roles, indent=2, sort_keys=True) + "\n", 0o644, out)
    out.role_changed = sorted(n for n, k in now.items() if before.get(n, k) != k)


def _common_name(path: Path) -> str:
    """The Common Name of the certificate at ``path``."""
    return certificate_cn(path.read_bytes(), str(path))


def _copy(src: Path, dst: Path, out: Generated) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)
    dst.chmod(0o600 if src.suffix == ".key" else 0o644)
    out.files.append(dst)


def _prune(folder: Path, keep: Iterable[Path], suffixes: tuple[str, ...], out: Generated) -> None:
    """Remove generated files (``suffixes``) of agents or operators no longer listed."""
    wanted = set(keep)
    if not folder.is_dir():
        return
    for path in sorted(folder.iterdir()):
        if path.suffix in suffixes and path not in wanted:
            path.unlink()
            out.removed.append(path)


def _write_users(
    lab: str, entry: LabEntry, folder: Path, identities: list[_Identity], out: Generated
) -> dict[str, str]:
    """A password lab's passwords by user: each identity keeps its password unless its
    kind changed (a password is never carried to another kind), a new one gets one, and
    the dictionary file is written (0600); a certificate lab's file is removed and it
    has none."""
    users = folder / f"{lab}.users"
    if entry.auth != "password":
        if users.exists():
            users.unlink()
            out.removed.append(users)
        return {}
    passwords = _passwords(users)
    for name in out.role_changed:
        passwords.pop(name, None)
    for who in identities:
        passwords.setdefault(who.name, secrets.token_urlsafe(_PASSWORD_BYTES))
    wanted = {who.name for who in identities}
    passwords = {u: p for u, p in passwords.items() if u in wanted}
    _write(users, "".join(f"{u}:{p}\n" for u, p in passwords.items()), 0o600, out)
    return passwords


def _write_agents(
    fed: FederationFile,
    lab: str,
    folder: Path,
    lab_root: Path,
    state_root: Path,
    passwords: dict[str, str],
    header: str,
    out: Generated,
) -> None:
    """Each agent's Zenoh config and settings, but a hosted agent's (under its host's
    folder); what is no longer listed is removed."""
    entry, kept = fed.labs[lab], []
    for name in entry.agents:
        if entry.host_of(name) is not None:
            continue  # under hosts/<host>/
        conf = folder / "agents" / f"{name}.json5"
        doc = agent_zenoh(fed, lab, name, lab_root, passwords.get(f"{lab}/{name}"))
        _write(conf, json5_text(doc, header), 0o600, out)
        settings = folder / "agents" / f"{name}.toml"
        text = toml_text(agent_settings(fed, lab, name, state_root / name), header)
        _write(settings, text, 0o644, out)
        kept += [conf, settings]
    _prune(folder / "agents", kept, (".json5", ".toml"), out)


def _write_operators(
    fed: FederationFile,
    lab: str,
    folder: Path,
    lab_root: Path,
    passwords: dict[str, str],
    header: str,
    out: Generated,
) -> None:
    """Each operator's Zenoh config; what is no longer listed is removed."""
    kept = []
    for name in fed.labs[lab].operators:
        conf = folder / "operators" / f"{name}.json5"
        doc = agent_zenoh(fed, lab, name, lab_root, passwords.get(f"{lab}/{name}"))
        _write(conf, json5_text(doc, header), 0o600, out)
        kept.append(conf)
    _prune(folder / "operators", kept, (".json5",), out)


def _copy_certificates(
    ca: Path, lab: str, entry: LabEntry, identities: list[_Identity], folder: Path, out: Generated
) -> None:
    """The CA's certificate, the lab's pair and (a certificate lab) its identities' pairs
    into the lab's ``certs/``; what is no longer listed is removed."""
    stems = ["ca", lab]
    if entry.auth == "certificate":
        stems += [who.stem for who in identities]
    kept = []
    for stem in stems:
        for suffix in (".pem", ".key"):
            if stem == "ca" and suffix == ".key":
                continue  # the CA key stays in DIR/ca
            dst = folder / "certs" / f"{stem}{suffix}"
            _copy(ca / f"{stem}{suffix}", dst, out)
            kept.append(dst)
    _prune(folder / "certs", kept, (".pem", ".key"), out)


def _write_units(folder: Path, lab_root: Path, out: Generated) -> None:
    """The systemd unit templates, their paths under ``lab_root``."""
    for unit in sorted(SYSTEMD_DIR.glob("*.service")):
        text = unit.read_text(encoding="utf-8")
        if lab_root != DEFAULT_ROOT:
            text = text.replace(str(DEFAULT_ROOT), str(lab_root))
        _write(folder / "systemd" / unit.name, text, 0o644, out)


def _write_lab(
    fed: FederationFile,
    lab: str,
    ca: Path,
    folder: Path,
    roots: tuple[Path, Path],
    out: Generated,
) -> None:
    """Lab ``lab``'s folder; ``roots``: where it is installed, and its services' state."""
    lab_root, state_root = roots
    entry = fed.labs[lab]
    header = _header(fed, lab)
    identities = _identities(lab, entry)
    passwords = _write_users(lab, entry, folder, identities, out)
    router = folder / "routers" / f"{lab}.json5"
    _write(router, router_text(fed, lab, lab_root), 0o644, out)
    _prune(folder / "routers", [router], (".json5",), out)
    _write_agents(fed, lab, folder, lab_root, state_root, passwords, header, out)
    _write_hosts(fed, lab, folder, lab_root, state_root, passwords, header, out)
    _write_operators(fed, lab, folder, lab_root, passwords, header, out)
    _copy_certificates(ca, lab, entry, identities, folder, out)
    _write_units(folder, lab_root, out)


def generate(
    fed: FederationFile,
    out_dir: Path,
    *,
    root: Path = DEFAULT_ROOT,
    local: bool = False,
    port: int | None = None,
) -> Generated:
    """Write the federation's files into ``out_dir`` (see the module docstring).

    ``root`` is where each lab installs its folder; ``local`` makes it each lab's own
    folder under ``out_dir`` (absolute), its services' state (each agent's runs) in the
    lab folder's ``state/``, and moves every lab's router onto loopback
    (:func:`federation.deploy.local.localize`, ``port`` the first lab's), to run the
    federation on this host as generated.
    """
    if local:
        fed = localize(fed, port)
    out = Generated(listening={lab: entry.listen[0] for lab, entry in fed.labs.items()})
    out_dir = out_dir.resolve()
    ca = out_dir / "ca"
    _issue_certificates(fed, ca, out)
    for lab in fed.labs:
        folder = out_dir / lab
        roots = (folder, folder / "state") if local else (root, STATE_ROOT)
        _write_lab(fed, lab, ca, folder, roots, out)
    return out
