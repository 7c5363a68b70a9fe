"""The SDK's agent proves its name as ``fedlab agent`` does (federation/runtime/sdk.py):
a Zenoh config proving another identity is refused before any session opens."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from federation import Agent, Pose
from federation.fleet.launch import free_port
from federation.runtime.identity import IdentityError
from federation.runtime.session import ConnectError


def _user_config(tmp_path: Path, user: str) -> Path:
    path = tmp_path / "ghost.json5"
    auth = f'usrpwd: {{user: "{user}", password: "x"}}'
    path.write_text(f'{{mode: "client", transport: {{auth: {{{auth}}}}}}}')
    return path


def test_an_sdk_agent_whose_config_proves_another_name_is_refused(tmp_path: Path) -> None:
    # Before, the SDK took endpoints only: no way to join a federation whose routers
    # check identities, and nothing checked a name against one.
    ghost = Agent("lab3/ghost", lambda t: Pose(), config=_user_config(tmp_path, "lab3/other"))
    t0 = time.monotonic()
    with pytest.raises(
        IdentityError, match="user name is 'lab3/other' but this agent is lab3/ghost"
    ):
        ghost.__enter__()
    assert time.monotonic() - t0 < 1.0  # refused before any session
    assert ghost.runtime is None


def test_an_sdk_agent_proving_its_own_name_goes_on_to_its_router(tmp_path: Path) -> None:
    port = free_port()  # nothing listens there
    ghost = Agent(
        "lab3/ghost", lambda t: Pose(), connect=[f"tcp/127.0.0.1:{port}"], timeout=1.0,
        config=_user_config(tmp_path, "lab3/ghost"),
    )  # fmt: skip
    with pytest.raises(ConnectError, match=f"127.0.0.1:{port}"):
        ghost.__enter__()


def test_an_sdk_agent_dials_its_config_files_router(tmp_path: Path) -> None:
    # connect's default (this host's router) had replaced the file's endpoints: the
    # ghost dialled localhost in plain TCP, not its lab's router.
    port = free_port()
    path = tmp_path / "ghost.json5"
    auth = 'usrpwd: {user: "lab3/ghost", password: "x"}'
    path.write_text(
        f'{{mode: "client", connect: {{endpoints: ["tcp/127.0.0.1:{port}"]}}, '
        f"transport: {{auth: {{{auth}}}}}}}"
    )
    ghost = Agent("lab3/ghost", lambda t: Pose(), timeout=1.0, config=path)
    with pytest.raises(ConnectError, match=f"127.0.0.1:{port}"):
        ghost.__enter__()


def test_an_sdk_agent_whose_file_names_no_router_dials_this_hosts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Credentials only: it had been given no endpoint at all ("give -e/--connect").
    from federation.runtime import sdk
    from federation.runtime.session import endpoints

    dialled: list[list[str]] = []

    def stop_here(conf: object, timeout: float) -> None:
        dialled.append(endpoints(conf))  # type: ignore[arg-type]
        raise RuntimeError("no session in this test")

    monkeypatch.setattr(sdk, "fail_fast", stop_here)
    ghost = Agent("lab3/ghost", lambda t: Pose(), config=_user_config(tmp_path, "lab3/ghost"))
    with pytest.raises(RuntimeError, match="no session"):
        ghost.__enter__()
    assert dialled == [[sdk.LOCAL_ROUTER]]
