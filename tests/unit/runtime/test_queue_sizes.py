"""Transmit queue sizes Zenoh would panic on are refused at load (session.build_config)."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
from pathlib import Path

import pytest

from federation.fleet.launch import free_port
from federation.runtime.session import (
    DATA_QUEUE_BATCHES,
    QUEUE_BATCHES_MAX,
    ZenohConfigError,
    _invalid_because,
    build_config,
    config_value,
)
from schemas.config import ZenohOptions


def test_fedlab_queues_as_many_batches_as_zenoh_allows() -> None:
    assert 1 <= DATA_QUEUE_BATCHES <= QUEUE_BATCHES_MAX
    conf = build_config(ZenohOptions(), default_mode="router")
    assert config_value(conf, "transport/link/tx/queue/size/data") == DATA_QUEUE_BATCHES


@pytest.mark.parametrize("value", ["16", "1"])
def test_a_size_within_the_ring_is_taken(value: str) -> None:
    cfg = [f"transport/link/tx/queue/size/data_high:{value}"]
    conf = build_config(ZenohOptions(cfg=cfg), default_mode="client")
    assert config_value(conf, "transport/link/tx/queue/size/data_high") == int(value)


@pytest.mark.parametrize("value", ["17", "64", "0"])
def test_a_flag_beyond_the_ring_is_refused_naming_the_flag_and_setting(value: str) -> None:
    item = f"transport/link/tx/queue/size/data:{value}"
    with pytest.raises(ZenohConfigError) as error:
        build_config(ZenohOptions(cfg=[item]), default_mode="router")
    message = str(error.value)
    assert f"--cfg {item}" in message
    assert f"'transport/link/tx/queue/size/data' is {value}" in message
    assert f"1 to {QUEUE_BATCHES_MAX} batches" in message


def test_a_file_beyond_the_ring_is_refused_naming_the_file(tmp_path: Path) -> None:
    # Zenoh's own loader refuses this one (a setting made by a flag it takes).
    path = tmp_path / "router.json5"
    path.write_text(json.dumps({"mode": "router", "transport": {"link": {"tx": {"queue": {
        "size": {"background": 32}}}}}}))  # fmt: skip
    with pytest.raises(ZenohConfigError) as error:
        build_config(ZenohOptions(config=path), default_mode="router")
    message = str(error.value)
    assert message.startswith(f"{path}: not a valid Zenoh config: ")
    # Zenoh's loader dumps the whole configuration and names nothing; fedlab names it.
    assert "'transport/link/tx/queue/size/background' is 32" in message
    assert len(message) < 300 + len(str(path))


def test_a_refusal_fedlab_cannot_name_leaves_the_dump_out() -> None:
    dump = '{"mode":"router","transport":{"link":{"tx":{"queue":{"size":{"data":16}}}}}}'
    why = _invalid_because(f"Invalid configuration: {dump} at zenoh-config/src/lib.rs:1483.")
    assert why == "Zenoh refused one of its settings without naming it"
    assert _invalid_because("Invalid configuration: {not json") == why
    assert _invalid_because("missing field `mode`") == "missing field `mode`"  # as Zenoh said


def test_the_router_command_exits_at_once_instead_of_failing_every_link() -> None:
    # Without the check this router ran and panicked on every link that opened.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    started = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-m", "federation", "router", "--lab", "rome", "-l", endpoint,
         "--cfg", "transport/link/tx/queue/size/data:32"],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert out.returncode == 2, out.stderr
    assert "'transport/link/tx/queue/size/data' is 32" in out.stderr
    assert time.monotonic() - started < 30


def test_a_bad_size_in_the_callers_settings_is_refused() -> None:
    with pytest.raises(
        ZenohConfigError, match="fedlab's settings: 'transport/link/tx/queue/size/data' is 40"
    ):
        build_config(ZenohOptions(), "router", extra={"transport/link/tx/queue/size/data": 40})


def test_a_whole_table_zenoh_refuses_says_the_limit() -> None:
    sizes = ",".join(f"{p}:2" for p in ("control", "real_time", "interactive_high",
                                         "interactive_low", "data_high", "data_low",
                                         "background"))  # fmt: skip
    item = f"transport/link/tx/queue/size:{{{sizes},data:32}}"
    with pytest.raises(ZenohConfigError, match=f"1 to {QUEUE_BATCHES_MAX} batches per priority"):
        build_config(ZenohOptions(cfg=[item]), default_mode="router")


def _file(tmp_path: Path, settings: dict[str, object]) -> Path:
    path = tmp_path / "agent.json5"
    path.write_text(json.dumps({"mode": "client", **settings}))
    return path


def test_a_file_that_sets_no_queue_size_gets_fedlabs(tmp_path: Path) -> None:
    # Zenoh's loader fills in its own two batches: they count as unset.
    conf = build_config(ZenohOptions(config=_file(tmp_path, {})), default_mode="client")
    assert config_value(conf, "transport/link/tx/queue/size/data") == DATA_QUEUE_BATCHES


def test_a_file_that_sets_its_own_queue_size_keeps_it(tmp_path: Path) -> None:
    sizes = {"transport": {"link": {"tx": {"queue": {"size": {"data": 8}}}}}}
    conf = build_config(ZenohOptions(config=_file(tmp_path, sizes)), default_mode="client")
    assert config_value(conf, "transport/link/tx/queue/size/data") == 8


def test_a_flag_sets_zenohs_default_queue_size_over_a_file(tmp_path: Path) -> None:
    options = ZenohOptions(config=_file(tmp_path, {}), cfg=["transport/link/tx/queue/size/data:2"])
    conf = build_config(options, default_mode="client")
    assert config_value(conf, "transport/link/tx/queue/size/data") == 2


def test_a_file_keeps_its_transport_choice(tmp_path: Path) -> None:
    # A setting other than Zenoh's default is the file's choice: fedlab's does not win.
    path = _file(tmp_path, {"transport": {"unicast": {"qos": {"enabled": False}}}})
    conf = build_config(ZenohOptions(config=path), default_mode="client")
    assert config_value(conf, "transport/unicast/qos/enabled") is False
    assert config_value(conf, "scouting/multicast/enabled") is False  # unset: fedlab's


def test_a_file_that_names_zenohs_two_batches_gets_fedlabs_and_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # Zenoh's loader cannot tell this file from one that names no size (docs/deploy.md).
    sizes = {"transport": {"link": {"tx": {"queue": {"size": {"data": 2}}}}}}
    path = _file(tmp_path, sizes)
    with caplog.at_level(logging.INFO, logger="fedlab.session"):
        conf = build_config(ZenohOptions(config=path), default_mode="client")
    assert config_value(conf, "transport/link/tx/queue/size/data") == DATA_QUEUE_BATCHES
    assert f"{path} leaves 'transport/link/tx/queue/size/data' at Zenoh's 2" in caplog.text
    assert "--cfg transport/link/tx/queue/size/data:2 keeps Zenoh's" in caplog.text


def test_a_router_file_that_names_no_queue_size_gets_fedlabs(tmp_path: Path) -> None:
    from federation.runtime.router import load_router_config

    path = tmp_path / "kiruna.json5"
    path.write_text(json.dumps({"mode": "router", "metadata": {"lab": "kiruna"},
                                "listen": {"endpoints": ["tcp/127.0.0.1:0"]}}))  # fmt: skip
    _, conf = load_router_config(ZenohOptions(config=path), None)
    assert config_value(conf, "transport/link/tx/queue/size/data") == DATA_QUEUE_BATCHES
    assert config_value(conf, "connect/timeout_ms") == -1  # the router's own default
