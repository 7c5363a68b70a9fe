"""The federation file: one description of a whole federation, from which
``fedlab deploy generate`` writes every lab's router config, every agent's and
operator's Zenoh config, the certificates and the systemd units
(:mod:`federation.deploy.generate`). Example: ``deploy/federation.example.toml``.

::

    federation = "default"

    [labs.kiruna]                       # listens: other labs' routers dial it
    auth = "certificate"
    listen = ["tls/[::]:7447"]
    endpoint = "tls/kiruna.example.org:7447"
    agents.knatte = { role = "leader", platform = "knatte" }
    operators = ["ctl"]

    [labs.rome]                         # dials Kiruna; opens no inbound port
    auth = "password"
    listen = ["tls/192.0.2.2:7447"]
    dial = ["kiruna"]
    agents.pinocchio = { role = "follower", follow = "kiruna/knatte" }

A bad file fails at load naming the field, e.g.
``federation.toml: field 'labs.rome.dial': lab 'lund' is not in labs``.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, ValidationError, model_validator

from federation.core import keys
from federation.core.endpoints import endpoint_problem
from federation.core.keys import DEFAULT_FEDERATION
from schemas import base
from schemas.base import ConfigError, load_model
from schemas.config import AgentConfig
from schemas.messages import CHUNK_SIZE

__all__ = ["AgentEntry", "FederationFile", "LabEntry", "endpoint_host", "load_federation"]

Name = Annotated[str, base.name("name")]


def endpoint_host(endpoint: str) -> str:
    """The host of a ``tls/HOST:PORT[#options]`` endpoint (brackets of IPv6 removed)."""
    address = endpoint.partition("/")[2].split("#", 1)[0]
    host = address.rpartition(":")[0]
    return host[1:-1] if host.startswith("[") and host.endswith("]") else host


def _tls_endpoint(value: str) -> str:
    proto, sep, address = value.partition("/")
    if proto != "tls" or not sep:
        raise ValueError(
            f"invalid endpoint {value!r}: every link of a federation is TLS, e.g. "
            "tls/kiruna.example.org:7447"
        )
    problem = endpoint_problem(value)
    if problem is not None:
        raise ValueError(f"invalid endpoint {value!r}: {problem}")
    if int(address.split("#", 1)[0].split("?", 1)[0].rpartition(":")[2]) == 0:
        raise ValueError(
            f"invalid endpoint {value!r}: port 0 is any free port; a federation names its ports"
        )
    return value


TlsEndpoint = Annotated[str, AfterValidator(_tls_endpoint)]


def _is_wildcard(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


class AgentEntry(base.Model):
    """One agent of a lab: its fedlab address is ``<lab>/<name>``, the Common Name of its
    certificate (or its user name on a password lab), and the only keys it may write."""

    role: Literal["leader", "follower", "member"] = Field(
        "member", description="leader runs the maneuver; follower tracks follow"
    )
    follow: str | None = Field(None, description="LAB/NAME of the agent a follower tracks")
    platform: str = Field("kinematic", description="pose source (see AgentConfig.platform)")
    runs_dir: str | None = Field(
        None,
        description="where the agent records each run for fedlab collect; default: runs/ in "
        "the state folder of the service that runs it (/var/lib/fedlab/<name>/runs)",
    )
    settings: dict[str, Any] = Field(
        default_factory=dict,
        description="any other AgentConfig field, written to the agent's TOML as is",
    )


class LabEntry(base.Model):
    """One lab: its router, how its agents authenticate, and its agents and operators."""

    auth: Literal["certificate", "password"] = Field(
        "certificate",
        description="how this lab's agents and operators prove who they are: a client "
        "certificate (CN lab/name), or a user name lab/name and a password over TLS",
    )
    listen: list[TlsEndpoint] = Field(
        min_length=1,
        description="where this lab's router listens: its agents attach there, and so do "
        "the routers of the labs that dial it",
    )
    endpoint: TlsEndpoint | None = Field(
        None,
        description="the address other labs' routers dial to reach this router (its host "
        "goes into the lab certificate); needed when another lab dials this one",
    )
    agent_endpoint: TlsEndpoint | None = Field(
        None,
        description="the address this lab's agents and operators dial; default: endpoint, "
        "else the first listen endpoint",
    )
    hosts: list[str] = Field(
        default_factory=list,
        description="extra names and addresses for the lab certificate; the hosts of "
        "endpoint and agent_endpoint are always in it",
    )
    dial: list[Name] = Field(
        default_factory=list, description="labs whose routers this lab's router dials (outbound)"
    )
    agents: dict[Name, AgentEntry] = Field(
        default_factory=dict, description="this lab's agents by name"
    )
    operators: list[Name] = Field(
        default_factory=list,
        description="who may publish control commands (fedlab ctl) from this lab",
    )
    hosted: dict[Name, list[Name]] = Field(
        default_factory=dict,
        description="processes that run several of this lab's agents on one session "
        "(fedlab host), by name: the agents each runs. Its identity (certificate CN or user "
        "lab/hosts/NAME) writes for exactly those agents, which get none of their own; "
        "their platforms are virtual (a serial: platform runs as its own fedlab agent)",
    )

    def host_of(self, name: str) -> str | None:
        """The hosted process that runs agent ``name``, if one does."""
        return next((h for h, agents in self.hosted.items() if name in agents), None)

    def agents_endpoint(self) -> str:
        """What this lab's agents dial."""
        return self.agent_endpoint or self.endpoint or self.listen[0]

    def cert_hosts(self) -> list[str]:
        """The lab certificate's names: hosts of endpoint and agent_endpoint, then hosts;
        with an endpoint on ``localhost``, ``127.0.0.1`` too (another lab's router dials
        it there over QUIC: federation/deploy/lablink.py)."""
        out: list[str] = []
        dialled = [self.endpoint, self.agents_endpoint()]
        hosts = [endpoint_host(e) for e in dialled if e is not None]
        if self.endpoint is not None and endpoint_host(self.endpoint) == "localhost":
            hosts.append("127.0.0.1")
        for host in hosts + self.hosts:
            if host and not _is_wildcard(host) and host not in out:
                out.append(host)
        return out


_TABLE = frozenset({"role", "follow", "platform"})
_OWN_FIELDS = _TABLE | {"federation", "lab", "name"}
"""AgentConfig fields an agent's entry sets itself (its table, or where it sits in the
file): ``settings`` may not override them (a hosted agent's platform is checked here)."""


def _check_operators(lab: str, entry: LabEntry) -> None:
    """A lab's operators are named once each, and no operator has an agent's name."""
    clash = sorted(set(entry.agents) & set(entry.operators))
    if clash:
        raise _field_error(f"labs.{lab}.operators", f"{', '.join(clash)}: already an agent's name")
    if len(set(entry.operators)) != len(entry.operators):
        raise _field_error(f"labs.{lab}.operators", "a name is listed twice")


def _check_hosted(lab: str, entry: LabEntry) -> None:
    """A hosted process has a name of its own and runs agents of its lab, each on one
    host only, none with a real platform, no two writing one status or recording file."""
    owner: dict[str, str] = {}
    files: dict[tuple[str, str, str], str] = {}
    for host, names in entry.hosted.items():
        where = f"labs.{lab}.hosted.{host}"
        _check_host(entry, host, names, where)
        for i, name in enumerate(names):
            _check_hosted_agent(lab, entry, name, f"{where}.{i}", owner)
            owner[name] = host
            _claim_files(lab, entry, host, name, files)
            platform = entry.agents[name].platform
            if platform.startswith("serial:"):
                raise _field_error(
                    f"{where}.{i}",
                    f"{name!r} flies a real platform ({platform}): it runs as its own fedlab agent",
                )


def _check_host(entry: LabEntry, host: str, names: list[str], where: str) -> None:
    """A hosted process's name is its identity: no agent or operator has it; it runs
    at least one agent."""
    if host in entry.agents or host in entry.operators:
        kind = "an agent's" if host in entry.agents else "an operator's"
        raise _field_error(where, f"{host!r} is already {kind} name: one identity each")
    if not names:
        raise _field_error(where, "runs no agent: list the agents it runs")


def _check_hosted_agent(
    lab: str, entry: LabEntry, name: str, where: str, owner: dict[str, str]
) -> None:
    """A hosted agent is one of the lab's, and not run by another host (``owner``: the
    host of each agent so far)."""
    if name not in entry.agents:
        raise _field_error(where, f"{name!r} is not an agent of lab {lab}")
    if name in owner:
        raise _field_error(where, f"{name!r} is already run by {owner[name]!r}: one host per agent")


def _claim_files(
    lab: str, entry: LabEntry, host: str, name: str, files: dict[tuple[str, str, str], str]
) -> None:
    """Record the status and recording files hosted agent ``name`` writes in ``files``
    ((host, field, path) to the agent); two agents of one process may not write one."""
    for field in ("status_json", "record"):
        path = entry.agents[name].settings.get(field)
        if path is None:
            continue
        key = (host, field, str(path))
        if key in files:
            raise _field_error(
                f"labs.{lab}.agents.{name}.settings.{field}",
                f"{path} is also {files[key]}'s, in one process ({host}): one file each",
            )
        files[key] = name


class FederationFile(base.Model):
    """A whole federation: its labs, which dials which, their agents and operators."""

    federation: Name = Field(DEFAULT_FEDERATION, description="the federation's name (keys, CA)")
    max_message_size: int = Field(
        0,
        ge=0,
        description="bytes: the largest message a router or agent accepts; 0: what fedlab's "
        "largest message needs (a recording chunk, 32 KiB, plus 64 KiB)",
    )
    lab_link: Literal["quic", "tls"] = Field(
        "quic",
        description="how a router dials a certificate lab's router: quic (QUIC with mixed "
        "reliability: pose as datagrams, never behind a lost packet; UDP on the listener's "
        "port) or tls (TLS over TCP); agents always dial their own router over TLS",
    )
    labs: dict[Name, LabEntry] = Field(min_length=1, description="the labs by name")

    @model_validator(mode="after")
    def _topology(self) -> FederationFile:
        self._check_lab_names()
        for lab, entry in self.labs.items():
            self._check_dials(lab, entry)
            _check_operators(lab, entry)
            _check_hosted(lab, entry)
            for name, agent in entry.agents.items():
                self._check_agent(lab, name, agent)
        self._check_certificate_names()
        unreachable = sorted(set(self.labs) - self.reachable(next(iter(self.labs))))
        if unreachable:
            raise _field_error(
                "labs",
                f"{', '.join(unreachable)} linked to no other lab: give each lab a dial "
                "entry or have another lab dial it",
            )
        return self

    def _check_lab_names(self) -> None:
        """No lab is named as the CA's folder or as a reserved lab."""
        if "ca" in self.labs:
            raise _field_error(
                "labs.ca", "'ca' is the CA's folder (DIR/ca): name the lab otherwise"
            )
        if reserved := min(keys.RESERVED_LABS & set(self.labs), default=None):
            raise _field_error(
                f"labs.{reserved}",
                f"{reserved!r} is reserved: a lab of that name would be let publish the "
                f"federation's control key ({keys.control_key(self.federation)})",
            )

    def _check_dials(self, lab: str, entry: LabEntry) -> None:
        """Each lab ``lab`` dials is another lab of the file, has an endpoint to dial,
        authenticates by certificate, and does not dial ``lab`` too."""
        for i, other in enumerate(entry.dial):
            if other not in self.labs:
                raise _field_error(f"labs.{lab}.dial.{i}", f"lab {other!r} is not in labs")
            if other == lab:
                raise _field_error(f"labs.{lab}.dial.{i}", "a lab cannot dial itself")
            target = self.labs[other]
            if target.endpoint is None:
                raise _field_error(
                    f"labs.{other}.endpoint",
                    f"missing: {lab} dials {other}, so give the address it dials",
                )
            if target.auth == "password":
                raise _field_error(
                    f"labs.{other}.auth",
                    f"'password' on a lab other routers dial ({lab} dials it): a password "
                    "dictionary applies to every session, the dialling router's too; use "
                    "'certificate'",
                )
            if lab in target.dial:
                raise _field_error(
                    f"labs.{lab}.dial.{i}", f"{other} dials {lab} already: one link per pair"
                )

    def _check_agent(self, lab: str, name: str, agent: AgentEntry) -> None:
        """An agent's entry makes a valid agent config, its settings leave the fields its
        entry sets alone, and it follows an agent of the file."""
        own = sorted(_OWN_FIELDS & set(agent.settings))
        if agent.runs_dir is not None and "runs_dir" in agent.settings:
            raise _field_error(
                f"labs.{lab}.agents.{name}.settings.runs_dir",
                "runs_dir is given in the entry already: give it once",
            )
        if own:
            key = own[0]
            raise _field_error(
                f"labs.{lab}.agents.{name}.settings.{key}",
                f"set by the entry itself ({'its table' if key in _TABLE else 'the file'}),"
                " not in settings",
            )
        data = {**agent.settings, "federation": self.federation, "lab": lab, "name": name}
        data |= {"role": agent.role, "follow": agent.follow, "platform": agent.platform}
        if agent.runs_dir is not None:
            data["runs_dir"] = agent.runs_dir
        try:
            AgentConfig.model_validate(data)
        except ValidationError as error:
            raise _field_error(
                f"labs.{lab}.agents.{name}",
                base.format_validation_error("agent", error, AgentConfig),
            ) from None
        if agent.follow is not None and not self.has_agent(agent.follow):
            raise _field_error(
                f"labs.{lab}.agents.{name}.follow", f"{agent.follow} is not an agent here"
            )

    def _check_certificate_names(self) -> None:
        """No two labs' router certificates share a name (loopback names aside)."""
        named: dict[str, str] = {}
        for lab, entry in self.labs.items():
            for host in entry.cert_hosts():
                if _loopback(host):
                    continue  # a federation on one host (tests, rehearsals): all local
                if host in named:
                    # Each router's certificate would then pass the name check for the
                    # other: one lab's router could stand in for the other's.
                    raise _field_error(
                        f"labs.{lab}",
                        f"{host} is also a name of {named[host]}'s router certificate: "
                        "each lab's router needs names of its own",
                    )
                named[host] = lab

    def has_agent(self, address: str) -> bool:
        lab, _, name = address.partition("/")
        return lab in self.labs and name in self.labs[lab].agents

    def neighbours(self, lab: str) -> list[str]:
        """The labs whose routers share a link with ``lab``'s (either way round)."""
        out = list(self.labs[lab].dial)
        out += [other for other, e in self.labs.items() if lab in e.dial and other not in out]
        return out

    def reachable(self, start: str, without: str | None = None) -> set[str]:
        """The labs reached from ``start`` over router links, not passing ``without``."""
        seen, todo = {start}, [start]
        while todo:
            for other in self.neighbours(todo.pop()):
                if other != without and other not in seen:
                    seen.add(other)
                    todo.append(other)
        return seen

    def behind(self, lab: str, neighbour: str) -> list[str]:
        """The labs whose traffic may reach ``lab`` over its link with ``neighbour``."""
        return sorted(self.reachable(neighbour, without=lab))

    @property
    def message_limit(self) -> int:
        """Bytes: :attr:`max_message_size`, or fedlab's largest message."""
        return self.max_message_size or CHUNK_SIZE + 64 * 1024


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _field_error(where: str, message: str) -> ValueError:
    return ValueError(f"{where}: {message}")


def load_federation(path: str | Path) -> FederationFile:
    """Load and check a federation file; a :class:`ConfigError` names the file and field."""
    try:
        return load_model(FederationFile, path)
    except ConfigError as error:
        raise ConfigError(_lift(str(error))) from None


def _lift(message: str) -> str:
    """``file: field '(top level)': Value error, labs.x.dial.0: reason`` becomes
    ``file: field 'labs.x.dial.0': reason``."""
    lines = []
    for line in message.splitlines():
        head, marker, rest = line.partition(": field '(top level)': Value error, ")
        if marker:
            where, _, reason = rest.partition(": ")
            line = f"{head}: field '{where}': {reason}"
        lines.append(line)
    return "\n".join(lines)
