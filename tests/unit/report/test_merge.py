"""``fedlab merge`` on synthetic recordings (federation/report/merge.py): two labs whose
clocks are 26.42 s apart and whose offset estimate errs by a known amount within its
stated bound, one host's wall clock 3 s off. The merged log times land on reference
time within the stated bounds, the epoch within its uncertainty, every Foxglove-typed
channel decodes with the schemas the file carries, the original recordings can be
rebuilt from it, and memory does not grow with the run."""

from __future__ import annotations

import json
import math
import os
import random
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from federation.core.channels import CHANNEL_FIELDS, json_schema
from federation.report.merge import MERGE_METADATA, write_merged
from federation.report.mergeclock import THIN_S, Thinned, _Series
from federation.report.mergeview import FOXGLOVE_TYPES
from federation.runtime.replayfile import Recording
from federation.runtime.scene import corridor_points
from schemas.scenario import DockingConfig

KIRUNA, ROME = "kiruna/knatte", "rome/pinocchio"
ROME_AHEAD = 26.42  # s, Rome's clock minus Kiruna's (the reference)
WALL = 1_800_000_000.0  # s, UTC of reference time 0 on a right wall clock
BOUND = 0.0005  # s, the reference_bound Rome's statuses state
START = 5.0  # s, reference time the run starts


def _error(t: float) -> float:
    """Rome's offset estimate minus the truth at reference time ``t``: within BOUND."""
    return 0.0004 * math.sin(0.7 * t)


def _record(
    path: Path,
    agent: str,
    steps: int,
    wall_off: float = 0.0,
    pad: int = 0,
    dt: float = 0.02,
    first: int = 0,
    experiment: str = "",
) -> None:
    """A recording as the recorder writes it: JSON channels with their schemas, log time
    the host's wall clock (``wall_off`` s off UTC) a millisecond after each stamp; steps
    ``first`` to ``steps`` (a later segment, from its ``rejoined`` event, if ``first``)."""
    rome = agent == ROME
    ahead = ROME_AHEAD if rome else 0.0
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=64 * 1024)
        writer.start(profile="", library="test")
        ids = {}
        for channel in CHANNEL_FIELDS:
            schema = writer.register_schema(
                str(channel).strip("/").replace("/", "."), "jsonschema",
                json.dumps(json_schema(channel)).encode(),
            )  # fmt: skip
            ids[str(channel)] = writer.register_channel(str(channel), "json", schema, {})
        writer.add_metadata(
            "fedlab.run", {"agent": agent, "host": "one-host", "experiment": experiment}
        )

        def put(topic: str, t_ref: float, message: dict[str, Any]) -> None:
            ns = round((WALL + wall_off + t_ref + 0.001) * 1e9)
            writer.add_message(ids[topic], ns, json.dumps(message).encode(), ns)

        for k in range(first, steps):
            t = k * dt  # reference time
            own, host = t + ahead, 1000.0 + t
            heading = 0.3 * math.sin(0.5 * max(t - START, 0.0))
            pose = {"x": 0.1, "y": -0.2, "heading": heading, "vx": 0.0, "vy": 0.0, "omega": 0.0}
            sent = {"t_exec": own, "host_monotonic": host, **pose}
            put("/pose/sent", t, sent | ({"pad": os.urandom(pad // 2).hex()} if pad else {}))
            t_sim = own - ahead + (_error(t) if rome else 0.0)
            put("/reference", t, {
                "t_exec": own, "host_monotonic": host, "t_sim": t_sim, "run_time": t_sim - START,
                "heading_ref": heading, "rate_ref": 0.0, "mode": "running", "valves_open": 0,
            })  # fmt: skip
            if rome:
                put("/pose/received", t, {"agent": KIRUNA, "t": t - 0.04, "t_recv": own,
                                          "host_monotonic": host, **pose})  # fmt: skip
            if k % 50 == 0:
                put("/status", t, {
                    "agent": agent, "reference": KIRUNA, "role": "follower" if rome else "leader",
                    "t_exec": own, "host_monotonic": host, "platform": "pinocchio",
                    "hold": "link_lost" if rome and k == 100 else None,
                    "ready": {"reference_bound": BOUND if rome else 0.0},
                    "peers": {KIRUNA if rome else ROME: {"offset": -ahead, "delay": 0.04,
                              "error_bound": BOUND, "samples": k, "alive": True}},
                    "workspace": {"frame": {"origin": [1.0, 2.0], "rotation_deg": 90.0},
                                  "area": [-1.0, 1.0, -1.0, 1.0]},
                })  # fmt: skip
            if first and k == first:
                put("/control", t, {"event": "rejoined", "command": None, "run_time": t - START,
                                    "t_exec": own, "host_monotonic": host, "mode": "running",
                                    "detail": ""})  # fmt: skip
            if abs(t - START) < dt / 2:
                put("/control", t, {"event": "started", "command": None, "at": START,
                                    "t_exec": own, "t_sim": START, "host_monotonic": host,
                                    "mode": "running", "detail": ""})  # fmt: skip
        writer.finish()


@pytest.fixture
def run(tmp_path: Path) -> Path:
    folder = tmp_path / "run"
    folder.mkdir()
    _record(folder / "kiruna-knatte.mcap", KIRUNA, 1000)
    _record(folder / "rome-pinocchio.mcap", ROME, 1000, wall_off=3.0)
    return folder


def _read(path: Path) -> tuple[dict[str, str], list[Any]]:
    with path.open("rb") as f:
        reader = make_reader(f)
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        return meta, list(reader.iter_messages(log_time_order=False))


def test_merged_log_times_land_on_reference_time_within_the_stated_bounds(run: Path) -> None:
    result, layout = write_merged(run)
    meta, messages = _read(run / "merged.mcap")
    merged = meta[MERGE_METADATA]
    epoch_ns, start = int(merged["epoch_ns"]), float(merged["reference_start_s"])
    assert start == START and merged["reference_agent"] == KIRUNA
    checked = 0
    for _schema, channel, message in messages:
        if channel.message_encoding != "json" or "source_topic" not in channel.metadata:
            continue
        data = json.loads(message.data)
        ahead = ROME_AHEAD if channel.topic.startswith(f"/{ROME}/") else 0.0
        field = channel.metadata["stamp_field"]
        truth = data[field] - ahead  # the stamp on reference time
        t_ref = start + (message.log_time - epoch_ns) / 1e9
        bound = data["t_ref_bound"]
        assert bound is not None and bound >= (BOUND if ahead else 0.0)
        assert abs(t_ref - truth) <= bound + 2e-9, (channel.topic, t_ref, truth, bound)
        assert abs(data["t_ref"] - t_ref) <= 2e-9
        checked += 1
    assert checked == 1000 * 5 + 20 * 2 + 2
    assert result.late == 0 and not result.notes
    # Rome's host wall clock is 3 s off: the epoch's uncertainty says so and covers it,
    # but for the recorder's latency (log time 1 ms after each stamp here), which no
    # recording shows.
    uncertainty = float(merged["epoch_uncertainty_s"])
    assert 1.5 <= uncertainty < 1.6
    assert abs(epoch_ns / 1e9 - (WALL + START)) <= uncertainty + 0.001
    assert json.loads(layout.read_text())["content"]


def test_a_host_wall_clock_off_does_not_move_the_samples(tmp_path: Path) -> None:
    """The same run with Rome's host wall clock 3 s or 0 s off: the same log times but
    for the epoch, which moves by half the disagreement (the median of two hosts)."""
    times = []
    for off in (0.0, 3.0):
        folder = tmp_path / f"off{off}"
        folder.mkdir()
        _record(folder / "kiruna-knatte.mcap", KIRUNA, 300)
        _record(folder / "rome-pinocchio.mcap", ROME, 300, wall_off=off)
        write_merged(folder)
        meta, messages = _read(folder / "merged.mcap")
        epoch_ns = int(meta[MERGE_METADATA]["epoch_ns"])
        times.append(sorted(m.log_time - epoch_ns for _s, c, m in messages))
    assert times[0] == times[1]


def _protobuf_class(schema: Any) -> Any:
    """The message class of a protobuf schema record (a FileDescriptorSet)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def test_every_foxglove_typed_channel_decodes_with_the_schema_the_file_carries(run: Path) -> None:
    write_merged(run)
    _, messages = _read(run / "merged.mcap")
    decoded: dict[str, list[Any]] = {}
    for schema, channel, message in messages:
        assert schema is not None, channel.topic
        if schema.encoding == "protobuf":
            assert schema.name in FOXGLOVE_TYPES
            decoded.setdefault(channel.topic, []).append(
                _protobuf_class(schema).FromString(message.data)
            )
        else:
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            properties = json.loads(schema.data)["properties"]
            data = json.loads(message.data)
            assert isinstance(data, dict) and set(data) & set(properties), channel.topic
            if "source_topic" in channel.metadata:  # a recorded channel: its schema grew
                assert {"t_ref", "t_ref_bound"} <= set(properties) & set(data)
    assert {f"/{KIRUNA}/pose", f"/{ROME}/pose", "/tf", "/scene", f"/{ROME}/log"} <= set(decoded)
    children = {t.child_frame_id for m in decoded["/tf"] for t in m.transforms}
    assert {KIRUNA, ROME, "kiruna", "rome"} <= children  # each platform and each lab's table
    areas = {e.id for m in decoded["/scene"] for e in m.entities}
    assert {f"area:{KIRUNA}", f"platform:{ROME}"} <= areas
    rome_log = [m.message for m in decoded[f"/{ROME}/log"]]
    assert any(line.startswith("started") for line in rome_log)
    assert "hold: link_lost" in rome_log and any("hold lifted" in line for line in rome_log)
    assert any(f"peer {KIRUNA} joined" in line for line in rome_log)


DOCKING = f"""name = "dock"
kind = "docking"
[docking]
target = "{KIRUNA}"
chaser = "{ROME}"
contact_distance = 0.6
corridor_deg = 20.0
"""


def _scene(folder: Path) -> list[Any]:
    """Every entity of the merged file's ``/scene``, decoded."""
    _, messages = _read(folder / "merged.mcap")
    return [
        entity
        for schema, channel, message in messages
        if channel.topic == "/scene"
        for entity in _protobuf_class(schema).FromString(message.data).entities
    ]


def test_a_docking_run_draws_its_corridor_locked_to_the_target(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    _record(folder / "kiruna-knatte.mcap", KIRUNA, 300, experiment=DOCKING)
    _record(folder / "rome-pinocchio.mcap", ROME, 300, experiment=DOCKING)
    write_merged(folder)
    corridors = [e for e in _scene(folder) if e.id == f"corridor:{KIRUNA}"]
    assert len(corridors) == 6  # one with each of the target's statuses
    drawn = corridors[0]
    assert drawn.frame_id == KIRUNA and drawn.frame_locked  # moves and turns with the target
    docking = DockingConfig(target=KIRUNA, chaser=ROME, contact_distance=0.6, corridor_deg=20.0)
    lines = [[(p.x, p.y) for p in line.points] for line in drawn.lines]
    assert lines == corridor_points(docking)
    # The edges open at the corridor's half-angle from the contact point, the hold
    # tolerance either side of the axis, as the chaser's guidance checks it.
    (x0, y0), (x1, y1) = lines[0]
    assert (x0, y0) == (0.6, docking.hold_tolerance)
    assert math.degrees(math.atan2(y1 - y0, x1 - x0)) == pytest.approx(20.0)
    assert lines[2][0][0] == pytest.approx(0.6 + docking.hold_distance)  # the hold point


def test_no_corridor_without_a_docking_table_that_loads(run: Path, tmp_path: Path) -> None:
    write_merged(run)
    assert not [e for e in _scene(run) if e.id.startswith("corridor:")]  # attitude tracking
    folder = tmp_path / "broken"
    folder.mkdir()
    broken = DOCKING.replace("corridor_deg = 20.0", "corridor_deg = 95.0")
    _record(folder / "kiruna-knatte.mcap", KIRUNA, 100, experiment=broken)
    _record(folder / "rome-pinocchio.mcap", ROME, 100)
    result, _ = write_merged(folder)
    assert not [e for e in _scene(folder) if e.id.startswith("corridor:")]
    (note,) = [n for n in result.notes if "corridor" in n]
    assert "[docking] table does not load" in note and "corridor_deg" in note, note


def test_a_merged_file_replays_each_agent_as_its_own_recording_does(run: Path) -> None:
    # fedlab replay reads a merged file too: each agent's poses on their recorded run
    # time, the same as from its own recording, and the platform it flew.
    write_merged(run)
    for agent in (KIRUNA, ROME):
        own = list(Recording(run / f"{agent.replace('/', '-')}.mcap", agent).poses())
        merged = Recording(run / "merged.mcap", agent)
        assert merged.merged and merged.platform_of(agent) == "pinocchio"
        assert len(own) > 500 and list(merged.poses()) == own, agent
    assert Recording(run / "merged.mcap", KIRUNA).knows(ROME)
    with pytest.raises(ValueError, match="no poses sent by lab/nobody recorded"):
        Recording(run / "merged.mcap", "lab/nobody")


def test_each_original_recording_can_be_rebuilt_from_the_merged_file(run: Path) -> None:
    original = {}
    with (run / "rome-pinocchio.mcap").open("rb") as f:
        for _s, channel, message in make_reader(f).iter_messages():
            original[(channel.topic, message.log_time)] = message.data
    write_merged(run)
    meta, messages = _read(run / "merged.mcap")
    rebuilt = {}
    for _s, channel, message in messages:
        if channel.metadata.get("agent") == ROME and "source_topic" in channel.metadata:
            data = json.loads(message.data)
            del data["t_ref"], data["t_ref_bound"]
            rebuilt[(channel.metadata["source_topic"], message.publish_time)] = json.dumps(
                data
            ).encode()
    assert rebuilt == original
    clock = meta[f"{ROME} clock"]
    assert clock["source"] == "estimate" and meta[f"{ROME} fedlab.run"]["host"] == "one-host"


def test_thinned_points_interpolate_every_point_within_twice_the_tolerance() -> None:
    rng = random.Random(4)
    t, y, points = 0.0, 0.0, []
    thin = Thinned(1e-6)
    for _ in range(20_000):
        t += 0.02
        y += 5e-7 * 0.02 + rng.gauss(0.0, 2e-8)  # a drift of 0.5 ppm and noise
        points.append((t, y))
        thin.add(t, y)
    kept_t, kept_y = thin.points()
    ts, ys = np.array(points).T
    assert np.max(np.abs(np.interp(ts, kept_t, kept_y) - ys)) <= 2e-6
    assert len(kept_t) < len(points) / 20
    assert THIN_S <= 1e-6


def _peak_mib(folder: Path) -> tuple[float, float]:
    tracemalloc.start()
    start = time.perf_counter()
    write_merged(folder)
    took = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return peak, took


def test_memory_does_not_grow_with_the_run(tmp_path: Path) -> None:
    """Runs of 1 and 4 units (about 3 and 12 MiB of recordings, random padding): the merge's peak of
    Python allocations stays within a fixed budget and grows by under 25 %."""
    peaks = []
    for steps in (600, 2400):
        folder = tmp_path / f"run{steps}"
        folder.mkdir()
        _record(folder / "kiruna-knatte.mcap", KIRUNA, steps, pad=4000)
        _record(folder / "rome-pinocchio.mcap", ROME, steps, wall_off=3.0, pad=4000)
        size = sum(p.stat().st_size for p in folder.glob("*.mcap")) / 2**20
        peak, took = _peak_mib(folder)
        print(f"{size:.1f} MiB of recordings: peak {peak:.1f} MiB, {took:.2f} s")
        peaks.append(peak)
    assert peaks[1] < 40.0
    assert peaks[1] < 1.25 * peaks[0]


def _rejoined_run(folder: Path) -> None:
    """Kiruna flies 20 s; Rome flies 0 to 8 s, is killed, and rejoins at 12 s (its
    second segment, ``rome-pinocchio.seg2.mcap``): 4 s of reference time unrecorded."""
    folder.mkdir()
    _record(folder / "kiruna-knatte.mcap", KIRUNA, 1000)
    _record(folder / "rome-pinocchio.mcap", ROME, 400, wall_off=3.0)
    _record(folder / "rome-pinocchio.seg2.mcap", ROME, 1000, wall_off=3.0, first=600)


def test_a_later_segment_is_the_same_agent_with_its_gap_shown(tmp_path: Path) -> None:
    run = tmp_path / "run"
    _rejoined_run(run)
    result, layout = write_merged(run)
    assert result.agents == [KIRUNA, ROME]  # one agent, not two
    meta, messages = _read(run / "merged.mcap")
    sent = {}  # segment -> (channel ids, their publish times)
    for _s, channel, message in messages:
        if channel.topic == f"/{ROME}/pose/sent":
            assert channel.metadata["agent"] == ROME
            seg = channel.metadata["segment"]
            file = channel.metadata["source_file"]
            assert file == {"1": "rome-pinocchio.mcap", "2": "rome-pinocchio.seg2.mcap"}[seg]
            sent.setdefault(seg, []).append(message.log_time)
    assert sorted(sent) == ["1", "2"] and len(sent["1"]) == 400 and len(sent["2"]) == 400
    assert not {c for _s, c, _m in messages if ".seg" in c.topic}  # no topic of its own
    # Its records: the first segment's under LAB/NAME, the second's under LAB/NAME.seg2.
    assert meta[f"{ROME} clock"]["segment"] == "1"
    assert meta[f"{ROME}.seg2 clock"]["segment"] == "2"
    assert meta[f"{ROME}.seg2 clock"]["file"] == "rome-pinocchio.seg2.mcap"
    assert f"{ROME}.seg2 fedlab.run" in meta
    # The gap: from the first segment's last message to the second's first, on the log.
    gaps = json.loads(meta[MERGE_METADATA]["segment_gaps"])
    assert [(g["agent"], g["segment"]) for g in gaps] == [(ROME, 2)]
    expected = (600 - 399) * 0.02  # s of reference time between the two sent poses
    assert abs(gaps[0]["gap_s"] - expected) < 2 * BOUND
    assert gaps[0]["to_log_time_ns"] == min(sent["2"])
    assert gaps[0]["from_log_time_ns"] == max(sent["1"])
    logs = [
        (m.log_time, m.data)
        for _s, c, m in messages
        if c.topic == f"/{ROME}/log" and b"segment 2" in m.data
    ]
    assert len(logs) == 1 and logs[0][0] == min(sent["2"])
    assert f"{gaps[0]['gap_s']:.3f} s".encode() in logs[0][1]
    assert any("segment 2 (rome-pinocchio.seg2.mcap) begins after a gap" in n for n in result.notes)
    assert layout.read_text().count(f"/{ROME}/pose/sent.heading") == 1


def test_a_series_on_disk_interpolates_and_searches_as_over_every_row() -> None:
    """Points across several blocks of a temporary file (:class:`_Series`): the value at
    any time, before, between, on and after the points, in any order and in time order
    (the last bracket reused), is numpy's over every point to the bit, and the rows
    either side of it are bisect's; a lookup holds two blocks."""
    rng = random.Random(2)
    series = _Series(3)
    t = np.cumsum([rng.uniform(0.01, 0.1) for _ in range(3 * _Series.BLOCK + 17)])
    y, z = np.array([rng.gauss(0, 1) for _ in t]), np.array([rng.gauss(0, 1) for _ in t])
    for row in zip(t, y, z, strict=True):
        series.append(*row)
    queries = [t[0] - 1, t[-1] + 1, *t[:: _Series.BLOCK], *t[_Series.BLOCK - 2 : _Series.BLOCK + 2]]
    queries += [rng.uniform(t[0] - 0.5, t[-1] + 0.5) for _ in range(2000)]
    # And in time order, several in each bracket, as a recording's messages come.
    queries += sorted(rng.uniform(t[0] - 0.5, t[-1] + 0.5) for _ in range(4 * len(t)))
    try:
        for q in queries:
            assert series.interp(q) == float(np.interp(q, t, y)), q
            k = int(np.searchsorted(t, q, side="right"))
            assert series.near(q, 2) == [float(z[i]) for i in (k - 1, k) if 0 <= i < len(t)], q
            assert len(series._cache) <= 2
        assert np.array_equal(series.column(1), y) and len(series) == len(t)
    finally:
        series.close()


def test_the_offset_estimate_is_in_the_clock_channel(run: Path) -> None:
    """The merged file's /LAB/NAME/clock rows marked ``point`` are the thinned estimate:
    interpolated, they give Rome's estimate at every /reference stamp within twice the
    thinning tolerance; the clock record is a summary that counts them."""
    write_merged(run)
    meta, messages = _read(run / "merged.mcap")
    rows = [json.loads(m.data) for _s, c, m in messages if c.topic == f"/{ROME}/clock"]
    points = sorted((r["t_exec"], r["offset_s"]) for r in rows if r["point"])
    assert len(points) == int(meta[f"{ROME} clock"]["offset_points"]) > 2
    assert sum(not r["point"] for r in rows) == int(meta[f"{ROME} clock"]["status_lines"]) == 20
    assert float(meta[f"{ROME} clock"]["reference_bound_max_s"]) == BOUND + 0.04  # + delay
    kt, ky = np.array(points).T
    checked = 0
    for _s, channel, message in messages:
        if channel.topic == f"/{ROME}/reference":
            data = json.loads(message.data)
            estimate = data["t_sim"] - data["t_exec"]
            assert abs(np.interp(data["t_exec"], kt, ky) - estimate) <= 2 * THIN_S + 1e-12
            checked += 1
    assert checked == 1000
    assert not any(c.topic == f"/{KIRUNA}/clock" and json.loads(m.data)["point"]
                   for _s, c, m in messages)  # fmt: skip  # the reference: no estimate


def test_a_recording_cut_short_merges_up_to_its_end_with_a_note(run: Path) -> None:
    """Rome's file cut at two thirds (its agent killed, no footer): what it holds is
    merged and a note names the file; its metadata records (written at the end) are not."""
    path = run / "rome-pinocchio.mcap"
    data = path.read_bytes()
    path.write_bytes(data[: 2 * len(data) // 3])
    result, _ = write_merged(run)
    assert any(n.startswith("rome-pinocchio.mcap: damaged") for n in result.notes), result.notes
    meta, messages = _read(run / "merged.mcap")
    sent = [m for _s, c, m in messages if c.topic == f"/{ROME}/pose/sent"]
    assert 300 < len(sent) < 1000 and f"{ROME} fedlab.run" not in meta
    assert result.late == 0


def test_a_merged_file_in_the_folder_is_not_read_as_a_recording(run: Path) -> None:
    """A merged file already in the run folder under another name (told by its header,
    without reading its summary) is left out: merging again gives the same agents,
    messages and notes, and no record of it."""
    first, _ = write_merged(run, run / "earlier.mcap")
    again, _ = write_merged(run)
    assert again.agents == first.agents == [KIRUNA, ROME]
    assert again.messages_in == first.messages_in and again.messages_out == first.messages_out
    assert again.notes == first.notes  # read as a recording, it would be one with no clock
    meta, _ = _read(run / "merged.mcap")
    assert not [name for name in meta if "earlier" in json.dumps(meta[name])]
