"""The federation ``fedlab deploy generate`` writes, at the testbed's addresses, run in
the testbed's namespaces from its generated files alone.

One federation file (:func:`federation_toml`) names the testbed's addresses: Kiruna's
router listens on Kiruna's public address (certificates; TLS, and QUIC with mixed
reliability for the lab link, as :mod:`federation.deploy.lablink` writes it), Rome's
router is on Rome's lab network behind the NAT (passwords) and dials Kiruna. Its agents
are the leader ``kiruna/knatte`` and the follower ``rome/pinocchio``, each recording its
runs under a folder given here, an insider ``kiruna/evil`` with no settings, and an
operator ``ctl`` in each lab. :func:`generate` writes the labs' folders
(:func:`federation.deploy.generate.generate`, as ``fedlab deploy generate`` does);
:meth:`Deployment.binds` installs a lab's folder at the root its files name, for that
lab's processes alone (:func:`federation.testbed.bed.with_binds`), as a lab installs it
at /etc/fedlab. :func:`start_routers`, :func:`start_agent` and :func:`start_run` start
the routers, the agents and a run by Kiruna's operator in their labs' namespaces.

Used by the insider's attacks (tests/integration/test_testbed_insider.py) and by
``fedlab bench network --deployment generated`` (:mod:`federation.bench.generated`).
"""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from federation.deploy.generate import generate as generate_files
from federation.testbed.bed import Binds, Testbed, TestbedError
from federation.testbed.topology import ADDR
from schemas.federation import FederationFile, load_federation

__all__ = [
    "AGENTS",
    "KIRUNA_PORTS",
    "PORT",
    "Deployment",
    "federation_toml",
    "generate",
    "locked_and_recording",
    "start_agent",
    "start_routers",
    "start_run",
    "toml_inline",
]

PORT = 7447
KIRUNA_PORTS = (f"tcp/{PORT}", f"udp/{PORT}")
"""What Kiruna's firewall opens: TLS for its agents and for a TLS lab link, UDP for the
QUIC lab link."""
AGENTS = {"knatte": ("kiruna", "leader"), "pinocchio": ("rome", "follower")}
"""The agents that fly: name -> (lab, role); the follower follows the leader."""
LEADER, FOLLOWER = "kiruna/knatte", "rome/pinocchio"


def toml_inline(values: Mapping[str, Any]) -> str:
    """``values`` (strings, numbers, booleans) as a TOML inline table."""
    items = []
    for key, value in values.items():
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, int | float):
            if not math.isfinite(value):
                raise ValueError(f"settings {key!r}: {value!r} is not a finite number")
            text = repr(value)
        elif isinstance(value, str):
            text = json.dumps(value)  # a TOML basic string for these characters
        else:
            raise TypeError(f"settings {key!r}: {type(value).__name__} is not a TOML scalar")
        items.append(f"{key} = {text}")
    return "{ " + ", ".join(items) + " }" if items else "{}"


def federation_toml(runs: Path, settings: Mapping[str, Mapping[str, Any]] | None = None) -> str:
    """The testbed's federation: Kiruna public (certificates), Rome behind its NAT
    (passwords) dialling Kiruna; each agent of :data:`AGENTS` records its runs under
    ``runs/<name>``, with ``settings[name]`` (AgentConfig fields) as its settings."""
    settings = settings or {}
    unknown = set(settings) - set(AGENTS)
    if unknown:
        raise ValueError(f"settings for {sorted(unknown)}: the agents are {sorted(AGENTS)}")

    def agent(name: str) -> str:
        _, role = AGENTS[name]
        follow = f', follow = "{LEADER}"' if role == "follower" else ""
        return (
            f'agents.{name} = {{ role = "{role}"{follow}, runs_dir = "{runs / name}", '
            f"settings = {toml_inline(settings.get(name, {}))} }}"
        )

    return f"""
federation = "default"

[labs.kiruna]
auth = "certificate"
listen = ["tls/{ADDR.kiruna}:{PORT}"]
endpoint = "tls/{ADDR.kiruna}:{PORT}"
operators = ["ctl"]
{agent("knatte")}
agents.evil = {{ role = "member" }}

[labs.rome]
auth = "password"
listen = ["tls/{ADDR.rome}:{PORT}"]
agent_endpoint = "tls/{ADDR.rome}:{PORT}"
dial = ["kiruna"]
operators = ["ctl"]
{agent("pinocchio")}
"""


@dataclass
class Deployment:
    """The generated folders (``dir/<lab>``), the root their files name and the
    federation file they were generated from."""

    dir: Path
    root: Path
    source: Path

    def binds(self, lab: str) -> list[tuple[Path, Path]]:
        """Lab ``lab``'s folder installed at the root, for its processes alone."""
        return [(self.dir / lab, self.root)]

    def installed(self, *parts: str) -> str:
        """A generated file as a lab's process sees it."""
        return str(self.root.joinpath(*parts))

    def federation(self) -> FederationFile:
        return load_federation(self.source)

    def router_config(self, lab: str) -> dict[str, Any]:
        """Lab ``lab``'s generated router config (JSON5 as written: plain JSON)."""
        path = self.dir / lab / "routers" / f"{lab}.json5"
        text = "\n".join(
            line for line in path.read_text().splitlines() if not line.lstrip().startswith("//")
        )
        config: dict[str, Any] = json.loads(text)
        return config


def generate(folder: Path, text: str) -> Deployment:
    """Write ``text`` to ``folder/federation.toml`` and generate it into ``folder/fed``
    for the root ``folder/root`` (as ``fedlab deploy generate ... --root``)."""
    folder = folder.resolve()
    folder.mkdir(parents=True, exist_ok=True)
    source = folder / "federation.toml"
    source.write_text(text)
    root = folder / "root"
    root.mkdir(exist_ok=True)
    generate_files(load_federation(source), folder / "fed", root=root)
    return Deployment(folder / "fed", root, source)


def start_routers(bed: Testbed, dep: Deployment) -> None:
    """Both labs' routers (``router-kiruna``, ``router-rome``) from their generated files."""
    for lab in ("kiruna", "rome"):
        config = dep.installed("routers", f"{lab}.json5")
        bed.fedlab(lab, f"router-{lab}", ["router", "-c", config], dep.binds(lab))


def start_agent(
    bed: Testbed, dep: Deployment, name: str, status: Path, extra: Sequence[str] = ()
) -> subprocess.Popen[bytes]:
    """Agent ``name`` of :data:`AGENTS` (process ``name``) from its generated settings and
    Zenoh config, writing its status lines to ``status``; ``extra``: more flags."""
    lab, _ = AGENTS[name]
    return bed.fedlab(
        lab, name,
        ["agent", "--agent-config", dep.installed("agents", f"{name}.toml"),
         "-c", dep.installed("agents", f"{name}.json5"), "--status-json", str(status), *extra],
        dep.binds(lab),
    )  # fmt: skip


def locked_and_recording(line: Mapping[str, Any] | None) -> bool:
    """Whether an agent's status line says it may start: its reference clock locked,
    recording."""
    ready = (line or {}).get("ready") or {}
    return bool(line and ready.get("reference_locked", True) and ready.get("recording"))


def start_run(
    bed: Testbed,
    dep: Deployment,
    duration: float,
    start_in: float = 1.5,
    timeout: float = 60.0,
    discover: float | None = None,
) -> None:
    """Kiruna's operator starts a run of ``duration`` s in ``start_in`` s (``fedlab ctl
    start``, process ``ctl``), ctl listening ``discover`` s for the agents' statuses
    (None: its default, for agents publishing once a second). A start that does not
    exit with 0 within ``timeout`` s raises :class:`TestbedError` with its log."""
    binds: Binds = dep.binds("kiruna")
    listen = [] if discover is None else ["--discover", f"{discover:g}"]
    proc = bed.fedlab(
        "kiruna", "ctl",
        ["ctl", "start", "--duration", f"{duration:g}", "--in", f"{start_in:g}", *listen,
         "--json", "-c", dep.installed("operators", "ctl.json5")],
        binds,
    )  # fmt: skip
    try:
        code = proc.wait(timeout)
    except subprocess.TimeoutExpired:
        raise TestbedError(
            f"ctl start still running after {timeout:g} s\n{bed.log('ctl')[-2000:]}"
        ) from None
    if code != 0:
        raise TestbedError(f"ctl start exited with {code}\n{bed.log('ctl')[-3000:]}")
