"""What a collector takes from the manifests it is sent (federation/runtime/collect.py),
with a fetch function in place of the network: only each agent's own manifest, on its
own key, listing its own files, once."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import zenoh

from federation.runtime.collect import Fetched, collect, nothing_to_collect
from federation.runtime.session import ConnectError
from schemas.messages import FileEntry, Manifest

RUN = "r1"
KEY = "fedlab/default/{}/recordings"


def _manifest(agent: str, name: str, data: bytes) -> bytes:
    entry = FileEntry(name=name, size=len(data), sha256=hashlib.sha256(data).hexdigest())
    return Manifest(agent=agent, run_id=RUN, files=[entry]).model_dump_json().encode()


def _fetcher(manifests: list[Fetched], files: dict[str, bytes]):  # type: ignore[no-untyped-def]
    """Manifests for the wildcard query; each file's bytes for a chunk query."""

    def fetch(key: str, parameters: str, timeout: float) -> list[Fetched]:
        if "file=" not in parameters:
            return manifests
        params = dict(p.split("=", 1) for p in parameters.split(";"))
        data = files[params["file"]]
        start = int(params["offset"])
        chunk = data[start : start + int(params["length"])]
        from federation.core.chunking import chunk_attachment

        return [Fetched(chunk, chunk_attachment(start, chunk), None, key)]

    return fetch


def test_one_lab_cannot_replace_anothers_recording(tmp_path: Path) -> None:
    real, forged = b"rome's run" * 100, b"FORGED" * 100
    manifests = [
        Fetched(_manifest("rome/ref", "rome-ref.mcap", real), None, None, KEY.format("rome/ref")),
        # zz/evil lists a file named like rome/ref's, with its own content.
        Fetched(_manifest("zz/evil", "rome-ref.mcap", forged), None, None, KEY.format("zz/evil")),
        # ... and sends a manifest for rome/ref on its own key.
        Fetched(_manifest("rome/ref", "rome-ref.mcap", forged), None, None, KEY.format("zz/evil")),
        # A manifest naming no agent at all had ended the whole collection.
        Fetched(b'{"agent": "bogus", "run_id": "r1", "files": []}', None, None, None),
    ]
    files = {"rome-ref.mcap": real}
    out = tmp_path / "out"
    result = collect(None, "default", RUN, out, fetch=_fetcher(manifests, files))
    assert (out / "rome-ref.mcap").read_bytes() == real
    assert result.files == {"rome/ref": ["rome-ref.mcap"]}
    assert len(result.errors) == 3 and not result.ok
    assert any("files not its own" in e for e in result.errors)
    assert any("sent on fedlab/default/zz/evil/recordings" in e for e in result.errors)
    assert any("malformed manifest" in e for e in result.errors)


def test_two_manifests_for_one_agent_keep_the_first_and_say_so(tmp_path: Path) -> None:
    a, b = b"first" * 10, b"second" * 10
    manifests = [
        Fetched(_manifest("rome/ref", "rome-ref.mcap", a), None, None, None),
        Fetched(_manifest("rome/ref", "rome-ref.mcap", b), None, None, None),
    ]
    out = tmp_path / "out"
    result = collect(None, "default", RUN, out, fetch=_fetcher(manifests, {"rome-ref.mcap": a}))
    assert (out / "rome-ref.mcap").read_bytes() == a
    assert result.errors == [
        "two manifests for rome/ref: neither is more genuine; the first was kept"
    ]


def test_chunks_wait_while_a_run_is_under_way(session: zenoh.Session, tmp_path: Path) -> None:
    """Its chunks (48 KiB a reply) had shared the agent's uplink with the run's poses and
    sync replies; the manifest (small) is still served."""
    from federation.core.keys import AgentId
    from federation.runtime.collect import RecordingServer, finalize, zenoh_fetch

    folder = tmp_path / "runs" / RUN
    folder.mkdir(parents=True)
    path = folder / "rome-ref.mcap"
    path.write_bytes(b"x" * 1000)
    finalize(folder, "rome/ref", RUN, [path])
    busy: list[str | None] = ["run r2 running"]
    server = RecordingServer(
        session, "default", AgentId("rome", "ref"), tmp_path / "runs", busy=lambda: busy[0]
    )
    try:
        fetch = zenoh_fetch(session)
        key = KEY.format("rome/ref")
        manifest = fetch(key, f"run={RUN}", 2.0)
        assert manifest and manifest[0].error is None and manifest[0].key == key
        chunk = f"run={RUN};file=rome-ref.mcap;offset=0;length=1000"
        assert [r.error for r in fetch(key, chunk, 2.0)] == ["busy: run r2 running"]
        busy[0] = None
        assert fetch(key, chunk, 2.0)[0].payload == b"x" * 1000
    finally:
        server.close()


def _nothing(fetch, out: Path) -> str:  # type: ignore[no-untyped-def]
    with pytest.raises(ConnectError) as error:
        collect(None, "default", RUN, out, fetch=fetch, timeout=5.0)
    return str(error.value)


def test_a_run_no_agent_has_says_who_answered_and_how_long_it_took(tmp_path: Path) -> None:
    declined = [
        Fetched(b"", None, "kiruna/knatte: no finished run r1"),
        Fetched(b"", None, "rome/pinocchio: no finished run r1\x1b[2J"),
    ]
    message = _nothing(lambda key, parameters, timeout: declined, tmp_path)
    head = (
        "no agent of federation 'default' has a finished run 'r1': "
        "asked fedlab/default/*/*/recordings; "
    )
    assert message.startswith(head + "2 agent(s) answered in 0.0"), message
    assert message.endswith(
        "s, none has it (kiruna/knatte: no finished run r1; "
        "rome/pinocchio: no finished run r1\ufffd[2J)"
    )
    assert "for 5 s" not in message


def test_no_answer_says_whether_the_query_ended_at_once_or_timed_out() -> None:
    assert nothing_to_collect("default", "r1", 5.0, 0.02, []).endswith(
        "no agent answered, and the query ended after 0.020 s: no agent that records runs "
        "(--experiment or --runs-dir) is reachable"
    )
    assert nothing_to_collect("default", "r1", 5.0, 5.01, []).endswith("; no answer within 5 s")
    assert "(1 manifest(s) refused, printed above)" in nothing_to_collect(
        "default", "r1", 5.0, 0.1, [], not_taken=1
    )
