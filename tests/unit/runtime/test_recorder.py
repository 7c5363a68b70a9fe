"""MCAP recording: buffered, written by one thread per process, nothing lost at close."""

from __future__ import annotations

import json
import math
import os
import threading
from pathlib import Path
from typing import Any

import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader

from federation.core.channels import Channel
from federation.fleet.launch import wait_for
from federation.runtime import recorder as recorder_module
from federation.runtime.collect import describe_incomplete, manifest_name
from federation.runtime.recorder import Recorder, Shared, read_messages, read_metadata
from federation.runtime.runs import RunRecording


def writers() -> int:
    return sum(1 for t in threading.enumerate() if t.name == "recorder")


def test_recorders_share_one_writer_and_lose_nothing_at_close(tmp_path: Path) -> None:
    assert wait_for(lambda: writers() == 0, timeout=2)  # none left by another test
    recorders = [Recorder(tmp_path / f"a{i}.mcap", f"lab/a{i}") for i in range(16)]
    try:
        assert writers() == 1
        for i, rec in enumerate(recorders):
            for k in range(100):
                rec.record("/pose/sent", {"t_exec": float(k), "host_monotonic": float(i)})
            rec.record("/truth", {"t_exec": 0.0})  # a channel recorded too
    finally:
        for rec in recorders:
            rec.close()
    for i in range(16):
        sent = read_messages(tmp_path / f"a{i}.mcap", ["/pose/sent"])["/pose/sent"]
        assert [m["t_exec"] for m in sent] == [float(k) for k in range(100)]
        assert {m["host_monotonic"] for m in sent} == {float(i)}
    assert wait_for(lambda: writers() == 0, timeout=2)  # gone with the last recorder


def test_unrecorded_channels_are_skipped_and_a_full_buffer_counts_drops(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "x.mcap", "lab/x", channels=["/status"], capacity=3)
    for k in range(5):
        rec.record("/pose/sent", {"t_exec": float(k)})
    rec.close()
    assert rec.dropped == 0 and rec.written == 0
    rec = Recorder(tmp_path / "y.mcap", "lab/y", capacity=3)
    with rec._write_lock:  # hold the writer off: the buffer fills
        for k in range(5):
            rec.record("/status", {"agent": "lab/y", "t_exec": float(k)})
    rec.close()
    assert rec.dropped == 2 and rec.written == 3
    rec.close()  # twice is harmless


class _NoWriter:
    """In place of the process's writer thread: the recorders write only at close,
    one after the other (a writer thread and a close racing may both encode one
    shared message, harmlessly, which the count below would catch)."""

    def add(self, recorder: Recorder) -> None:
        pass

    def remove(self, recorder: Recorder) -> None:
        pass


def test_a_shared_message_is_encoded_once_for_every_recorder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recorder_module, "_WRITER", _NoWriter())
    recorders = [
        Recorder(tmp_path / f"f{i}.mcap", f"lab/f{i}", ["/pose/received"]) for i in range(4)
    ]
    unshared = Recorder(tmp_path / "u.mcap", "lab/u", ["/pose/received"])
    encodings = 0
    dumps = recorder_module.json.dumps

    def counted(value: Any) -> str:
        nonlocal encodings
        encodings += 1
        return dumps(value)

    monkeypatch.setattr(recorder_module.json, "dumps", counted)  # the messages' encodings
    poses = [Shared({"agent": "lab/a0", "t": float(k), "x": 0.5}) for k in range(10)]
    try:
        for pose in poses:
            for rec in recorders:
                rec.record("/pose/received", pose)
    finally:
        for rec in recorders:
            rec.close()
    assert encodings == 10  # once per pose, not once per recorder
    for i in range(4):
        got = read_messages(tmp_path / f"f{i}.mcap", ["/pose/received"])["/pose/received"]
        assert got == [{"agent": "lab/a0", "t": float(k), "x": 0.5} for k in range(10)]
    unshared.record("/pose/received", {"t": 1.0})
    unshared.record("/pose/received", {"t": 1.0})
    unshared.close()
    assert encodings == 12  # a plain dict: encoded at each write


def test_a_recording_killed_mid_run_loses_at_most_its_last_chunk(tmp_path: Path) -> None:
    """Each chunk reaches the file as soon as it is full: the messages of every chunk
    but the one gathering are on disk before the file is closed (a killed agent's)."""
    path = tmp_path / "a.mcap"
    rec = Recorder(path, "lab1/a", ["/pose/received"])
    pose = {"agent": "lab0/a0", "t": 0.0, "pad": "x" * 200}
    size = len(json.dumps(pose)) + 40  # an upper bound of one message's record, bytes
    written = 4 * recorder_module.CHUNK_SIZE // size  # more than three chunks' worth
    try:
        for k in range(written):
            rec.record("/pose/received", pose | {"t": float(k)})
        rec.flush()  # what the writer thread does
        on_disk = []
        with path.open("rb") as f:
            try:
                for record in StreamReader(f).records:
                    if isinstance(record, McapMessage):
                        on_disk.append(json.loads(record.data)["t"])
            except EndOfFile:
                pass  # the file is not finished: it ends mid-way
    finally:
        rec.close()
    assert on_disk == [float(k) for k in range(len(on_disk))]  # in order, none missing
    assert written - len(on_disk) <= recorder_module.CHUNK_SIZE // (size - 40) + 1


def _protobuf_class(schema: Any) -> Any:
    """The message class of a protobuf schema record (a FileDescriptorSet)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def test_a_recording_carries_the_pose_in_foxglove_types(tmp_path: Path) -> None:
    path = tmp_path / "kiruna-knatte.mcap"
    rec = Recorder(path, "kiruna/knatte")
    poses = [(0.5 * k, -0.25 * k, 0.1 * k) for k in range(5)]
    try:
        for k, (x, y, heading) in enumerate(poses):
            pose = {"x": x, "y": y, "heading": heading, "vx": 0.0, "vy": 0.0, "omega": 0.0}
            rec.record("/pose/sent", {"t_exec": float(k), "host_monotonic": float(k)} | pose)
        rec.record("/sync/exchange", {"peer": "rome/pinocchio", "offset": 0.001, "delay": 0.04})
    finally:
        rec.close()
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert schemas["/tf"].name == "foxglove.FrameTransforms"
        assert schemas["/pose"].name == "foxglove.PoseInFrame"
        assert schemas["/tf"].encoding == "protobuf"
        # fedlab's own channels: JSON with typed properties, so plots need no setup.
        sync = json.loads(schemas["/sync/exchange"].data)
        assert sync["properties"]["offset"] == {"type": "number"}
        assert sync["properties"]["peer"] == {"type": "string"}
        decoded: dict[str, list[Any]] = {"/tf": [], "/pose": []}
        for schema, channel, message in reader.iter_messages(topics=["/tf", "/pose"]):
            decoded[channel.topic].append(_protobuf_class(schema).FromString(message.data))
    assert len(decoded["/tf"]) == len(decoded["/pose"]) == len(poses)
    for (x, y, heading), tfs, pose in zip(poses, decoded["/tf"], decoded["/pose"], strict=True):
        (tf,) = tfs.transforms
        assert (tf.parent_frame_id, tf.child_frame_id) == ("fedlab_common", "kiruna/knatte")
        assert (tf.translation.x, tf.translation.y, tf.translation.z) == (x, y, 0.0)
        assert tf.rotation.z == pytest.approx(math.sin(heading / 2), abs=1e-15)
        assert tf.rotation.w == pytest.approx(math.cos(heading / 2), abs=1e-15)
        assert pose.frame_id == "fedlab_common" and pose.pose.position.x == x
        q = pose.pose.orientation
        assert (q.x, q.y, q.z, q.w) == (tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w)
    # read_messages gives the JSON channels only, as before.
    messages = read_messages(path)
    assert "/tf" not in messages and len(messages["/pose/sent"]) == len(poses)


def test_without_the_pose_channel_no_foxglove_channels(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    Recorder(path, "lab/a", channels=["/status"]).close()
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert {c.topic for c in summary.channels.values()} == {str(c) for c in Channel}


def test_the_report_reads_old_and_new_recordings_alike(tmp_path: Path) -> None:
    """An old recording (JSON channels, untyped schemas, no Foxglove types) and a new one
    load the same messages."""
    from mcap.writer import Writer

    from federation.core.channels import CHANNEL_FIELDS
    from federation.report.load import load_run

    pose = {"x": 1.0, "y": 2.0, "vx": 0.0, "vy": 0.0, "omega": 0.0}
    sent = [{"t_exec": float(k), "host_monotonic": float(k), "heading": 0.1 * k} | pose
            for k in range(10)]  # fmt: skip
    status = {"agent": "kiruna/knatte", "t_exec": 0.0, "host_monotonic": 0.0, "role": "leader",
              "peers": {}, "counters": {}}  # fmt: skip
    old_dir, new_dir = tmp_path / "old", tmp_path / "new"
    old_dir.mkdir()
    with (old_dir / "kiruna-knatte.mcap").open("wb") as f:  # the format before /tf and /pose
        writer = Writer(f)
        writer.start(profile="", library="fedlab")
        ids = {}
        for channel, fields in CHANNEL_FIELDS.items():
            schema = {
                "title": str(channel),
                "type": "object",
                "properties": {n: {} for n in fields},
            }
            sid = writer.register_schema(
                name=str(channel).strip("/").replace("/", "."), encoding="jsonschema",
                data=json.dumps(schema).encode(),
            )  # fmt: skip
            ids[str(channel)] = writer.register_channel(str(channel), "json", sid)
        for k, message in enumerate([status, *sent]):
            topic = "/status" if k == 0 else "/pose/sent"
            writer.add_message(ids[topic], k, json.dumps(message).encode(), k)
        writer.finish()  # type: ignore[no-untyped-call]
    rec = Recorder(new_dir / "kiruna-knatte.mcap", "kiruna/knatte")
    rec.record("/status", status)
    for message in sent:
        rec.record("/pose/sent", message)
    rec.close()
    old, new = load_run(old_dir), load_run(new_dir)
    for run in (old, new):
        agent = run.agents["kiruna/knatte"]
        assert agent.role == "leader"
        assert agent.channel("/pose/sent") == sent
        assert "/tf" not in agent.messages
    # A new recording whose end is damaged is read record by record, Foxglove's skipped.
    new_file = new_dir / "kiruna-knatte.mcap"
    new_file.write_bytes(new_file.read_bytes() + b"not mcap")
    recovered = load_run(new_dir)
    assert any("damaged or unfinished recording; 11 messages" in n for n in recovered.notes)
    assert recovered.agents["kiruna/knatte"].channel("/pose/sent") == sent


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="Linux /proc only")
def test_the_writer_thread_carries_its_name_for_the_os(tmp_path: Path) -> None:
    """``fedlab bench scale`` reports the writer's CPU apart from the agents' loop."""
    import os

    from federation.runtime.recorder import WRITER_THREAD

    recorder = Recorder(tmp_path / "a.mcap", "rome/a")

    def names() -> set[str]:
        out = set()
        for tid in os.listdir("/proc/self/task"):
            try:
                out.add(Path(f"/proc/self/task/{tid}/comm").read_text().strip())
            except OSError:  # a thread that ended meanwhile
                continue
        return out

    try:
        assert wait_for(lambda: WRITER_THREAD in names(), 5.0, 0.05), names()
    finally:
        recorder.close()


def test_one_message_that_cannot_be_written_loses_only_itself(tmp_path: Path) -> None:
    """A pose sent with an infinite heading (and a message that is not JSON) had left a
    31-byte file that could not be read, and no manifest: close skipped finish()."""
    path = tmp_path / "kiruna-knatte.mcap"
    rec = Recorder(path, "kiruna/knatte")
    pose = {"x": 0.0, "y": 0.0, "heading": math.inf, "vx": 0.0, "vy": 0.0, "omega": 0.0}
    rec.record("/pose/sent", {"t_exec": 1.0, "host_monotonic": 1.0} | pose)
    rec.record("/sync/exchange", {"peer": object()})  # not JSON
    rec.record("/sync/exchange", {"peer": "rome/pinocchio", "offset": 0.001})
    rec.close()
    messages = read_messages(path)  # a finished file: summary and index readable
    assert len(messages["/pose/sent"]) == 1 and len(messages["/sync/exchange"]) == 1
    assert rec.unwritable == 1


def test_a_write_that_fails_is_counted_and_the_recording_is_not_complete(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A full disk under the writer thread had only been logged: the run was finalized
    as complete, its gap unsaid."""
    run = RunRecording(tmp_path, "r1", "lab/x", None, "{}", None)
    rec = run.recorder
    real = rec._writer.add_message
    failures = []

    def full_disk(*args: Any, **kwargs: Any) -> None:
        if not failures:
            failures.append(1)
            raise OSError(28, "No space left on device")
        real(*args, **kwargs)

    monkeypatch.setattr(rec._writer, "add_message", full_disk)
    rec.record("/status", {"agent": "lab/x", "t_exec": 0.0})
    assert wait_for(lambda: rec.write_errors == 1, timeout=5)  # the writer thread's write
    rec.record("/status", {"agent": "lab/x", "t_exec": 1.0})
    run.finish(wait=True)
    assert rec.report()["write_errors"] == 1 and not rec.complete
    summary = read_metadata(run.mcap)["fedlab.recording"]
    assert summary["complete"] == "false" and summary["write_errors"] == "1"
    note = json.loads((tmp_path / "r1" / "lab-x.incomplete.json").read_text())
    assert note["write_errors"] == 1 and note["complete"] is False
    assert "1 write(s) failed" in describe_incomplete(note)
    manifest = json.loads((tmp_path / "r1" / manifest_name("lab-x")).read_text())
    assert "lab-x.incomplete.json" in {f["name"] for f in manifest["files"]}
    assert [m["t_exec"] for m in read_messages(run.mcap)["/status"]] == [1.0]


def test_a_write_failing_at_close_still_finalizes_the_run_marked_incomplete(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its last messages lost, the file finished all the same: finalized, and said."""
    run = RunRecording(tmp_path, "r1", "lab/x", None, "{}", None)
    rec = run.recorder
    recorder_module._WRITER.remove(rec)  # only close() writes: its failure is the one
    for k in range(3):
        rec.record("/status", {"agent": "lab/x", "t_exec": float(k)})

    def full_disk(*args: Any, **kwargs: Any) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(rec._writer, "add_message", full_disk)
    run.finish(wait=True)
    assert rec.write_errors == 1 and not rec.complete
    assert read_metadata(run.mcap)["fedlab.recording"]["write_errors"] == "1"
    manifest = json.loads((tmp_path / "r1" / manifest_name("lab-x")).read_text())
    assert {f["name"] for f in manifest["files"]} == {
        "lab-x.mcap",
        "lab-x.jsonl",
        "lab-x.incomplete.json",
    }
    note = json.loads((tmp_path / "r1" / "lab-x.incomplete.json").read_text())
    assert note["write_errors"] == 1


def test_a_closed_recording_is_on_disk_whole_before_close_returns(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A run's manifest marks its recording finished: after a power cut, such a file
    # must not be the part of it the kernel had not written yet.
    synced: list[int] = []
    real_fsync = recorder_module.os.fsync

    def fsync(fd: int) -> None:
        synced.append(os.fstat(fd).st_size)
        real_fsync(fd)

    monkeypatch.setattr(recorder_module.os, "fsync", fsync)
    path = tmp_path / "a.mcap"
    rec = Recorder(path, "lab/a")
    rec.record("/pose/sent", {"t_exec": 1.0})
    rec.close()
    assert synced == [path.stat().st_size]  # the whole file, summary and all
    assert read_messages(path, ["/pose/sent"])["/pose/sent"] == [{"t_exec": 1.0}]
