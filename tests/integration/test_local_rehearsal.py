"""The README's "Rehearse your federation on one machine" runs as written: its commands
are read from the README itself, only the output folder (``fed/``) and the first port
(``--port 7447``) changed to the test's own, so that the test runs beside others.

``fedlab deploy generate --local`` had kept the example's endpoints
(``kiruna.example.org``, ``192.0.2.10``) and certificate names: nothing connected on
one host without editing the federation file by hand.
"""

from __future__ import annotations

import shlex
import time
from pathlib import Path

import pytest
from lifecycle import fedlab

from federation.fleet.launch import Fleet, free_ports

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
SECTION = "### Rehearse your federation on one machine"
README_PORT = "7447"


def readme_commands() -> list[list[str]]:
    """The section's shell lines, each as ``fedlab`` arguments (comments and ``&`` off)."""
    text = (REPO / "README.md").read_text()
    assert SECTION in text, f"README.md has no section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n#", 1)[0]
    block = section.split("```sh\n", 1)[1].split("```", 1)[0]
    commands = []
    for line in block.splitlines():
        words = shlex.split(line, comments=True)
        if words and words[-1] == "&":
            words.pop()
        if words:
            assert words[0] == "fedlab", line
            commands.append(words[1:])
    return commands


def test_the_readme_rehearsal_runs_as_written(fleet: Fleet, tmp_path: Path) -> None:
    port = free_ports(2).start  # the two labs' routers: port and port + 1, both reserved
    fed = tmp_path / "fed"

    def here(word: str) -> str:
        if word.startswith("fed/"):
            return str(fed / word.removeprefix("fed/"))
        if word == "deploy/federation.example.toml":
            return str(REPO / word)
        return word

    commands = [[here(word) for word in command] for command in readme_commands()]
    generate, *services, status = commands
    assert generate[-2:] == ["--port", README_PORT], generate
    generate[-1] = str(port)
    started = time.monotonic()
    done, _ = fedlab(*generate)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"kiruna: its router listens on tls/127.0.0.1:{port}" in done.stdout
    assert f"rome: its router listens on tls/127.0.0.1:{port + 1}" in done.stdout
    # Nothing of the example's addresses is left in what the routers and agents read.
    for conf in fed.glob("*/*/*.json5"):
        text = conf.read_text()
        assert "example" not in text and "192.0.2." not in text, conf

    for i, args in enumerate(services):
        kind = args[0]
        fleet.start(f"{kind}-{i}", args)
    ready = None
    deadline = started + 40.0
    while time.monotonic() < deadline:  # bounded: one ctl status (~2 s) per round
        ready, _ = fedlab(*status, timeout=30)
        if ready.returncode == 0:
            break
    took = time.monotonic() - started
    assert ready is not None
    assert ready.returncode == 0, ready.stdout + ready.stderr
    out = ready.stdout
    print(f"\nrehearsal from the README: ctl status ready {took:.1f} s after generate\n{out}")
    assert "kiruna/knatte" in out and "rome/pinocchio" in out and "bound" in out
    for name in fleet.procs:
        assert fleet.alive(name), fleet.log_path(name).read_text()[-2000:]
