"""The transport every shipped router config and fedlab's session defaults agree on
(docs/deploy.md, "Transports under loss"): Zenoh's universal transport with QoS on,
the one a default Zenoh client gets too; and the lab routers' 15 s lease. No processes
(the loopback congestion test is tests/integration/test_network_congestion.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from federation.bench import network
from federation.runtime.session import build_config
from schemas.config import ZenohOptions

ROOT = Path(__file__).resolve().parents[3]
ROUTERS = sorted((ROOT / "deploy" / "routers").rglob("*.json5"))


def _get(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


def test_there_are_router_configs_to_check() -> None:
    names = {p.relative_to(ROOT / "deploy" / "routers").as_posix() for p in ROUTERS}
    assert {"rome.json5", "kiruna.json5", "tls/rome.json5", "multilink/rome.json5"} <= names


@pytest.mark.parametrize("path", ROUTERS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_router_is_universal_with_qos(path: Path) -> None:
    conf = zenoh.Config.from_file(str(path))
    # QoS off makes Zenoh 1.10 drop a congested link's pose for good.
    assert _get(conf, "transport/unicast/qos/enabled") is True, path
    assert _get(conf, "transport/unicast/lowlatency") is False, path


@pytest.mark.parametrize("path", ROUTERS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_router_queues_sixteen_data_batches_as_fedlab_sessions(path: Path) -> None:
    # Two (Zenoh's default) dropped poses on a busy host (docs/scale.md).
    assert _get(zenoh.Config.from_file(str(path)), "transport/link/tx/queue/size/data") == 16
    for mode in ("client", "peer", "router"):
        ours = build_config(ZenohOptions(), mode)
        assert _get(ours, "transport/link/tx/queue/size/data") == 16, mode
        assert _get(ours, "transport/link/tx/queue/size/control") == 2, mode  # the rest as is


@pytest.mark.parametrize("path", [p for p in ROUTERS if p.parent.name != "multilink"])
def test_the_tcp_and_tls_lab_links_keep_the_measured_10_s_lease(path: Path) -> None:
    # 10 s measured better than 15 s after a WAN cut (docs/deploy.md, "A WAN cut").
    assert _get(zenoh.Config.from_file(str(path)), "transport/link/tx/lease") == 10000


@pytest.mark.parametrize("mode", ["client", "peer", "router"])
def test_fedlab_sessions_match_the_routers_and_a_default_client(mode: str) -> None:
    ours = build_config(ZenohOptions(), mode)
    default = zenoh.Config()
    for key in ("transport/unicast/lowlatency", "transport/unicast/qos/enabled"):
        assert _get(ours, key) == _get(default, key), key


def test_bench_cfg_goes_to_routers_not_elsewhere() -> None:
    args = network._router_args("rome", "tcp", ["transport/link/tx/lease:10000"])
    assert args[:3] == ["router", "-c", str(network.ROUTERS / "rome.json5")]
    assert args[-2:] == ["--cfg", "transport/link/tx/lease:10000"]
    assert "--cfg" not in network._router_args("kiruna", "tcp")
