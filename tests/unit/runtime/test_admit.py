"""``fedlab ctl admit`` (federation/runtime/admit.py): the command it publishes, and
what it makes of each agent's status (a session and a federation faked)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from federation.core.keys import AgentId
from federation.runtime import admit as admit_module
from federation.runtime.admit import admit, rejoined
from federation.runtime.session import ConnectError

ME = "kiruna/f"


class _Session:
    def __init__(self) -> None:
        self.puts: list[tuple[str, dict[str, Any]]] = []

    def put(self, key: str, payload: str, **options: Any) -> None:
        self.puts.append((key, json.loads(payload)))


def _federation(after: dict[str, dict[str, Any]], before: dict[str, dict[str, Any]]) -> type:
    """Agents reporting ``before`` until the admit is put, ``after`` since."""

    class Fed:
        def __init__(self, session: _Session, federation: str) -> None:
            self.session = session

        def snapshot(self) -> dict[str, dict[str, Any]]:
            return after if self.session.puts else before

        def discover(self, agents: frozenset[str] | None, timeout: float) -> None:
            pass

        def close(self) -> None:
            pass

    return Fed


WAITING = {"mode": "waiting", "admit_run": "r1", "rejoin": "waiting for an operator's admit"}
JOINED = {"mode": "running", "transition": {"event": "rejoined", "at": 5.0, "run_time": 6.5}}


def test_it_names_the_agent_and_reports_the_run_time_it_joined_at(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(admit_module, "Federation", _federation({ME: JOINED}, {ME: WAITING}))
    session = _Session()
    lines: list[str] = []
    result = admit(session, [AgentId.parse(ME)], wait=1.0, progress=lines.append)
    key, command = session.puts[0]
    assert key.endswith("control") and command["command"] == "admit"
    assert command["participants"] == [ME] and command["seq"] == 1
    assert result.ok and result.joined == {ME: 6.5} and result.modes == {ME: "running"}
    assert lines == [f"{ME}: admitting into r1"]
    assert result.as_json()["joined"] == {ME: 6.5}


def test_a_refusal_is_reported_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    refused = {
        "mode": "waiting",
        "commands": [],  # filled below with the admit's own issuer and seq
    }
    fed = _federation({ME: refused}, {ME: WAITING})
    monkeypatch.setattr(admit_module, "Federation", fed)
    session = _Session()

    real_put = session.put

    def put(key: str, payload: str, **options: Any) -> None:
        real_put(key, payload)
        sent = json.loads(payload)
        refused["commands"] = [
            {"command": "admit", "issuer": sent["issuer"], "seq": sent["seq"],
             "outcome": "ignored", "detail": "rejoin = never: no admit lets it rejoin"},
        ]  # fmt: skip

    session.put = put  # type: ignore[method-assign]
    result = admit(session, [AgentId.parse(ME)], wait=5.0)
    assert not result.ok and result.elapsed < 1.0
    assert result.reasons == {ME: "ignored: rejoin = never: no admit lets it rejoin"}


def test_an_agent_that_does_not_join_says_its_own_reason(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    still = WAITING | {"rejoin": "preflight: the reference clock's estimate is not locked"}
    monkeypatch.setattr(admit_module, "Federation", _federation({ME: still}, {ME: WAITING}))
    result = admit(_Session(), [AgentId.parse(ME)], wait=0.2)
    assert not result.ok and "not locked" in result.reasons[ME]


def test_no_agent_seen_admits_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(admit_module, "Federation", _federation({}, {}))
    session = _Session()
    with pytest.raises(ConnectError, match="nothing admitted"):
        admit(session, [AgentId.parse(ME)], wait=0.2)
    assert session.puts == []


@pytest.mark.parametrize(
    ("status", "expected"),
    [
        (None, None),
        (WAITING, None),
        (JOINED, 6.5),
        (JOINED | {"mode": "done"}, 6.5),
        (JOINED | {"mode": "aborted"}, None),
        ({"mode": "running", "transition": {"event": "started", "run_time": 0.0}}, None),
    ],
)
def test_rejoined(status: dict[str, Any] | None, expected: float | None) -> None:
    assert rejoined(status) == expected
