"""``fedlab bench network``: the federation on real network stacks, under loss,
cuts and a path-MTU black hole.

Each scenario builds a :class:`federation.testbed.Testbed` (Rome behind a
masquerading gateway with a stateful firewall, Kiruna with its router's ports
open, the paper's path in between: 40 ms one way, a few ms of jitter), starts both
lab routers from the shipped configs (``deploy/routers/``), a leader in Kiruna, a
follower in Rome (clock 26.42 s off) and an outside raw Zenoh subscriber on
Rome's router, runs, and scores the recordings against the truth (both labs share
this host's monotonic clock):

- **holds**: safe holds the follower entered (every one is spurious: the leader
  never stops) and the fraction of time held;
- **pose latency**: leader's send to follower's arrival, host time;
- **sender gap**: the leader's longest pause between two poses sent, host time: a
  hold on a pose the leader itself sent late (its host busy) is no fault of the path;
- **sync error**: |the follower's live offset estimate - truth| at each exchange
  after the sync phase (10 s, the paper's; ``sync_phase`` of :func:`run_one`);
- **heading error**: the follower's reference heading (what its controller is
  given, dead-reckoned) against the leader's actual heading at the same instant,
  outside holds;
- **cut**: the WAN is cut for ``cut`` seconds: time from the cut to the hold,
  from the return to the first pose, sync exchange and release, and the oldest
  pose delivered to the controller after the return;
- **NAT**: direct TCP connections from Kiruna into Rome's lab and to its gateway
  (both must fail while the federation works);
- **outside subscriber**: how many leader poses a raw zenoh-python subscriber on
  Rome's router received, beside the follower's count.

Transports (:data:`TRANSPORTS`): ``multilink`` (deploy/routers/multilink/: a TCP
link for declarations, queries and control, a UDP link beside it for best-effort
pose, 512-byte batches, 15 s lease, hosts with deploy/sysctl/90-fedlab-wan.conf),
``tcp`` (deploy/routers/, the default: one TCP link, universal transport with QoS, the
kernel's default TCP settings), ``tcp-tuned`` (the default routers on hosts with
the sysctl file), ``tls`` (the generated TLS deployment's lab link: mutual TLS with
lab certificates made per run), ``quic`` (the same certificates on a QUIC lab link,
best-effort pose as QUIC datagrams) and ``quic-stream`` (QUIC, one stream for all).
"""

from __future__ import annotations

import bisect
import json
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from federation.core import paper
from federation.core.sync import DELAY_WINDOW
from federation.fleet.launch import wait_for
from federation.link.packet import PacketOptions
from federation.testbed import ADDR, Testbed, TestbedError
from federation.testbed.topology import parse_sysctl_conf

__all__ = [
    "SCENARIOS",
    "TRANSPORTS",
    "Scenario",
    "count_samples",
    "make_certs",
    "run",
    "run_one",
    "score",
]

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
ROUTERS = DEPLOY / "routers"
SYSCTL = DEPLOY / "sysctl" / "90-fedlab-wan.conf"
LEADER, FOLLOWER = "kiruna/knatte", "rome/pinocchio"
PORT = 7447
SYNC_PHASE = paper.SYNC_PHASE

TRANSPORTS: dict[str, dict[str, list[str]]] = {
    # deploy/routers/multilink/: TCP and UDP links in one transport (max_links 2),
    # 512-byte batches, 15 s lease; the lab hosts with deploy/sysctl's TCP settings.
    "multilink": {
        "config": ["multilink"],
        "kiruna": ["-l", f"tcp/0.0.0.0:{PORT}", "-l", f"udp/0.0.0.0:{PORT}"],
        "rome": ["-e", f"tcp/{ADDR.kiruna}:{PORT}", "-e", f"udp/{ADDR.kiruna}:{PORT}"],
        "ports": ["tcp/7447", "udp/7447"],
        "sysctl": [str(SYSCTL)],
    },
    # deploy/routers/ (the default): one TCP link, universal transport with QoS; the lab
    # hosts with the kernel's default TCP settings.
    "tcp": {
        "kiruna": ["-l", f"tcp/0.0.0.0:{PORT}"],
        "rome": ["-e", f"tcp/{ADDR.kiruna}:{PORT}"],
        "ports": ["tcp/7447"],
    },
    # The default router configs on hosts with deploy/sysctl's TCP settings.
    "tcp-tuned": {
        "kiruna": ["-l", f"tcp/0.0.0.0:{PORT}"],
        "rome": ["-e", f"tcp/{ADDR.kiruna}:{PORT}"],
        "ports": ["tcp/7447"],
        "sysctl": [str(SYSCTL)],
    },
    # The lab link of the generated TLS deployment (federation/deploy/generate.py): one
    # TLS link, mutual TLS with lab certificates from the federation's CA (made per run
    # by federation.deploy.certs), the dialler checking Kiruna's name; the default
    # router configs otherwise (universal transport, QoS on, 10 s lease), hosts with the
    # sysctl file. Agents reach their lab router on loopback over plain TCP, as in
    # every other transport here: only the lab link crosses the WAN.
    "tls": {
        "kiruna": ["-l", f"tls/{ADDR.kiruna}:{PORT}"],
        "rome": ["-e", f"tls/{ADDR.kiruna}:{PORT}"],
        "ports": ["tcp/7447"],
        "sysctl": [str(SYSCTL)],
        "certs": ["lab"],
    },
    # The same with a QUIC lab link (same certificates, same TLS settings: Zenoh's QUIC
    # link reads transport/link/tls) in Zenoh's mixed-reliability mode (mixed_rel=1,
    # eclipse-zenoh/zenoh#2476): reliable messages (declarations, queries, replies,
    # control, liveliness) on a QUIC stream, best-effort ones (pose) as QUIC datagrams
    # on the same encrypted connection. Kiruna opens UDP 7447 instead of TCP.
    "quic": {
        "kiruna": ["-l", f"quic/{ADDR.kiruna}:{PORT}?mixed_rel=1"],
        "rome": ["-e", f"quic/{ADDR.kiruna}:{PORT}?mixed_rel=1"],
        "ports": ["udp/7447"],
        "sysctl": [str(SYSCTL)],
        "certs": ["lab"],
    },
    # A QUIC lab link with every message on one stream (Zenoh's QUIC default): a lost
    # packet holds everything behind it, as on TCP.
    "quic-stream": {
        "kiruna": ["-l", f"quic/{ADDR.kiruna}:{PORT}"],
        "rome": ["-e", f"quic/{ADDR.kiruna}:{PORT}"],
        "ports": ["udp/7447"],
        "sysctl": [str(SYSCTL)],
        "certs": ["lab"],
    },
}


@dataclass(frozen=True)
class Scenario:
    """One run's path. Delays in seconds; ``cut`` is (at, length) after the sync phase."""

    name: str
    loss: float = 0.0
    loss_burst: float = 1.0
    mtu: int = 0
    icmp: bool = True
    cut: tuple[float, float] | None = None
    delay: float = paper.ONE_WAY_DELAY
    jitter: float = 0.003

    def path(self) -> PacketOptions:
        return PacketOptions(
            delay=self.delay,
            jitter=self.jitter,
            loss=self.loss,
            loss_burst=self.loss_burst,
            mtu=self.mtu,
            icmp=self.icmp,
        )


SCENARIOS = {
    s.name: s
    for s in (
        Scenario("clean"),
        Scenario("loss1", loss=0.01),
        Scenario("loss5", loss=0.05),
        Scenario("loss20", loss=0.20),
        Scenario("cut10", cut=(15.0, 10.0)),
        Scenario("mtu576", mtu=576, icmp=False),
    )
}


# -- the outside subscriber ------------------------------------------------------------
def count_samples(
    endpoint: str, key: str, out: Path, seconds: float, config: str | None = None
) -> None:
    """A raw zenoh-python client subscribing to ``key`` on ``endpoint``, as a third
    party would (Zenoh's default config, nothing of fedlab's): writes the samples
    counted per key and per second to ``out`` (JSON) every second. ``config``: a Zenoh
    config file to open instead (``endpoint`` unused), for routers that admit only
    known identities (the generated deployment's: an operator's config)."""
    import signal
    import threading

    import zenoh

    from federation.runtime.signals import stop_event

    if config is not None:
        conf = zenoh.Config.from_file(config)
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
    counts: dict[str, int] = {}
    arrivals: list[float] = []
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            k = str(sample.key_expr)
            counts[k] = counts.get(k, 0) + 1
            if k.endswith("/pose"):
                arrivals.append(time.monotonic())

    give_up = time.monotonic() + 20.0  # the router may still be starting
    while True:
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError:
            if time.monotonic() > give_up:
                raise
            time.sleep(0.5)

    def save() -> None:
        with lock:
            data = {"counts": dict(counts), "pose_arrivals": list(arrivals)}
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(out)

    # Stopped by the testbed (SIGTERM) before its time: save what arrived since the
    # last second's save, or the run's end would seem to have gone unheard.
    stop = stop_event([signal.SIGTERM])  # no lock in the handler: it cannot wait on itself
    with session:
        sub = session.declare_subscriber(key, on_sample)
        end = time.monotonic() + seconds
        while time.monotonic() < end and not stop.wait(1.0):
            save()
        sub.undeclare()
    save()


# -- a run -----------------------------------------------------------------------------
def _router_args(
    lab: str, transport: str, cfg: Sequence[str] = (), certs: Path | None = None
) -> list[str]:
    """``fedlab router`` arguments for ``lab``; a transport with certificates gets its
    lab's from ``certs`` (see :func:`make_certs`), before ``cfg``, which comes last."""
    t = TRANSPORTS[transport]
    # Agents reach the router on loopback; Kiruna's WAN listener covers it only when it
    # is a TCP one on every address.
    plain = lab == "rome" or not t[lab][1].startswith("tcp/0.0.0.0:")
    listen = ["-l", f"tcp/127.0.0.1:{PORT}"] if plain else []
    config = ROUTERS.joinpath(*t.get("config", []), f"{lab}.json5")
    secure: list[str] = []
    if t.get("certs"):
        if certs is None:
            raise ValueError(f"transport {transport!r} needs the lab certificates (certs=)")
        from federation.deploy.certs import cfg_flags, tls_settings

        settings = tls_settings(certs, lab, listen=True)
        settings["transport/link/tls/verify_name_on_connect"] = True  # as generated
        secure = cfg_flags(settings)
    # --open: the testbed's namespaces are the network, with nothing else on it.
    return ["router", "-c", str(config), "--open", *listen, *t[lab], *secure, *_cfg_flags(cfg)]


def make_certs(directory: Path) -> Path:
    """A federation CA and both labs' router certificates in ``directory``, Kiruna's
    naming its testbed address (the name Rome's router checks as it dials)."""
    from federation.deploy.certs import init_ca, issue_lab

    directory.mkdir(parents=True, exist_ok=True)
    init_ca(directory, force=True)
    issue_lab(directory, "kiruna", [ADDR.kiruna, "localhost"], force=True)
    issue_lab(directory, "rome", [ADDR.rome, "localhost"], force=True)
    return directory


def _cfg_flags(cfg: Sequence[str]) -> list[str]:
    return [flag for item in cfg for flag in ("--cfg", item)]


def run_one(
    scenario: Scenario,
    transport: str,
    seconds: float,
    out: Path,
    seed: int = 1,
    cfg: Sequence[str] = (),
    sync_phase: float = SYNC_PHASE,
) -> dict[str, Any]:
    """One scenario on one transport; the scores (see :func:`score`).

    Scored from the follower's first sync exchange plus ``sync_phase`` seconds to
    the first agent's end; the agents run ``sync_phase + seconds + 5`` seconds from
    their own start (the 5 s cover their start-up), so about ``seconds + 5`` are
    scored. A scenario's ``cut`` is timed from ``sync_phase`` after they are started.

    ``cfg`` (``KEY:VALUE`` Zenoh settings) is given to both routers and both agents,
    never to the outside subscriber, which keeps Zenoh's defaults as a third party's
    client would: e.g. ``transport/unicast/lowlatency:true`` with
    ``transport/unicast/qos/enabled:false`` measures the configs used before.
    """
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("*.mcap"):
        stale.unlink()
    lead, follow = out / "leader.mcap", out / "follower.mcap"
    subscriber = out / "subscriber.json"
    path = scenario.path()
    events: dict[str, Any] = {}
    t = TRANSPORTS[transport]
    sysctls: dict[str, str] = {}
    for conf in t.get("sysctl", []):
        sysctls |= parse_sysctl_conf(Path(conf).read_text())
    certs = make_certs(out / "certs") if t.get("certs") else None
    with Testbed(out, path, kiruna_ports=t["ports"], sysctls=sysctls, seed=seed) as bed:
        bed.fedlab("kiruna", "router-kiruna", _router_args("kiruna", transport, cfg, certs))
        bed.fedlab("rome", "router-rome", _router_args("rome", transport, cfg, certs))
        run_for = seconds + sync_phase
        common = ["-e", f"tcp/127.0.0.1:{PORT}", "--status-period", "0.5"]
        common += ["--duration", f"{run_for + 5:g}", *_cfg_flags(cfg)]
        bed.fedlab(
            "kiruna",
            "leader",
            ["agent", "--role", "leader", "--lab", "kiruna", "--name", "knatte",
             "--record", str(lead), "--status-json", str(out / "leader.jsonl"), *common],
        )  # fmt: skip
        bed.fedlab(
            "rome",
            "follower",
            ["agent", "--role", "follower", "--lab", "rome", "--name", "pinocchio",
             "--follow", LEADER, "--clock-offset", f"{paper.CLOCK_OFFSET}",
             "--record", str(follow), "--status-json", str(out / "follower.jsonl"), *common],
        )  # fmt: skip
        code = (
            "from pathlib import Path; from federation.bench.network import count_samples; "
            f"count_samples('tcp/127.0.0.1:{PORT}', 'fedlab/**', Path({str(subscriber)!r}), "
            f"{run_for + 5:g})"
        )
        bed.spawn("rome", "subscriber", [sys.executable, "-c", code])
        started = time.monotonic()
        if scenario.cut is not None:
            at, length = scenario.cut
            time.sleep(max(0.0, sync_phase + at - (time.monotonic() - started)))
            events["cut_at"] = bed.cut()
            time.sleep(length)
            events["restored_at"] = bed.restore()
        time.sleep(max(0.0, run_for - 12 - (time.monotonic() - started)))
        events["nat_probe"] = {
            "rome_host": bed.probe("kiruna", ADDR.rome, PORT, 2.0),
            "rome_gateway": bed.probe("kiruna", ADDR.rome_gw_wan, PORT, 2.0),
        }
        wait_for(lambda: not bed.alive("follower"), timeout=run_for + 60, interval=0.5)
        wait_for(lambda: not bed.alive("leader"), timeout=15, interval=0.2)
        events["stage"] = bed.stage_stats()
    sub = json.loads(subscriber.read_text()) if subscriber.exists() else {}
    header = _header(scenario, transport, cfg, seconds, seed) | {"sync_phase": sync_phase}
    return {**header, **score(follow, lead, events, sub, sync_phase)}


def _header(
    scenario: Scenario, transport: str, cfg: Sequence[str], seconds: float, seed: int
) -> dict[str, Any]:
    """What a run's result says of how it ran."""
    return {
        "scenario": asdict(scenario),
        "transport": transport,
        "cfg": list(cfg),
        "seconds": seconds,
        "seed": seed,
    }


def _pct(values: list[float] | np.ndarray, q: float) -> float | None:
    a = np.asarray(values, dtype=float)
    return None if a.size == 0 else float(np.percentile(a, q))


def _beyond_delay(
    poses: list[dict[str, Any]], latency: list[float], exchanges: list[dict[str, Any]]
) -> list[float]:
    """Each received pose's latency (s) less the follower's estimate of the one-way
    delay when it arrived: the median of the last ``DELAY_WINDOW`` exchanges with the
    leader before it, as the follower's sync client keeps it (poses before the first
    exchange left out)."""
    with_leader = [x for x in exchanges if x.get("peer") == LEADER]
    at = [x["host_monotonic"] for x in with_leader]
    delays = [x["delay"] for x in with_leader]
    beyond = []
    for pose, late in zip(poses, latency, strict=True):
        k = bisect.bisect_right(at, pose["host_monotonic"])
        if k:
            beyond.append(late - statistics.median(delays[max(0, k - DELAY_WINDOW) : k]))
    return beyond


def score(
    follower: Path,
    leader: Path,
    events: dict[str, Any],
    subscriber: dict[str, Any],
    sync_phase: float = SYNC_PHASE,
) -> dict[str, Any]:
    """The figures of one run from the two recordings, the cut times and the
    outside subscriber's counts, scored from ``sync_phase`` seconds after the
    follower's first sync exchange."""
    from federation.report.status import clock_line
    from federation.runtime.recorder import read_messages

    topics = ["/status", "/pose/received", "/sync/exchange", "/control", "/reference"]
    f = read_messages(follower, topics)
    lmsg = read_messages(leader, ["/status", "/pose/sent"])
    a_l, b_l = clock_line(lmsg["/status"])

    def leader_host(t: float) -> float:
        return (t - a_l) / b_l

    start = f["/sync/exchange"][0]["host_monotonic"] + sync_phase if f["/sync/exchange"] else 0.0
    # The run ends when either agent stops: a hold after the leader left is no fault.
    end = min(f["/status"][-1]["host_monotonic"], lmsg["/pose/sent"][-1]["host_monotonic"])
    poses = [p for p in f["/pose/received"] if start <= p["host_monotonic"] <= end]
    latency = [p["host_monotonic"] - leader_host(p["t"]) for p in poses]
    beyond = _beyond_delay(poses, latency, f["/sync/exchange"])
    errors = []
    for x in f["/sync/exchange"]:
        if x["host_monotonic"] < start or x.get("estimate") is None:
            continue
        truth = (a_l + b_l * x["host_monotonic"]) - x["t3"]  # leader clock - follower clock
        errors.append(abs(x["estimate"] - truth))
    holds = [c for c in f["/control"] if c["event"] == "stale_hold" and c["host_monotonic"] < end]
    resumes = [c for c in f["/control"] if c["event"] == "link_resumed"]
    held = _held_intervals(holds, resumes, end)
    held_time = sum(min(b, end) - max(a, start) for a, b in held if b > start)
    # Heading: the follower's reference against the leader's actual heading.
    sent = lmsg["/pose/sent"]
    lh = np.array([s["host_monotonic"] for s in sent])
    scored_sends = lh[(lh >= start) & (lh <= end)]
    lhead = np.unwrap(np.array([s["heading"] for s in sent]))
    herr = []
    for r in f["/reference"]:
        h = r["host_monotonic"]
        if h < start or any(a <= h < b for a, b in held):
            continue
        actual = float(np.interp(h, lh, lhead))
        herr.append(abs(math.remainder(r["heading_ref"] - actual, 2 * math.pi)))
    herr_deg = np.degrees(herr) if herr else np.array([])
    minutes = max(end - start, 1e-9) / 60
    out: dict[str, Any] = {
        "holds": len([h for h in holds if h["host_monotonic"] >= start]),
        "holds_per_min": len([h for h in holds if h["host_monotonic"] >= start]) / minutes,
        "held_fraction": held_time / max(end - start, 1e-9),
        "poses_received": len(poses),
        "sender_gap_max_ms": _ms(float(np.diff(scored_sends).max()))
        if scored_sends.size > 1
        else None,
        "pose_latency_ms": {
            "p50": _ms(_pct(latency, 50)),
            "p99": _ms(_pct(latency, 99)),
            "max": _ms(max(latency) if latency else None),
        },
        # A pose's age on arrival beyond the follower's estimate of the link's delay
        # then: it is dropped on arrival once past the stale threshold.
        "pose_age_beyond_delay_ms": {"max": _ms(max(beyond) if beyond else None)},
        "sync_error_ms": {
            "p50": _ms(_pct(errors, 50)),
            "p95": _ms(_pct(errors, 95)),
            "max": _ms(max(errors) if errors else None),
            "n": len(errors),
        },
        "heading_error_deg": {
            "rms": float(np.sqrt(np.mean(herr_deg**2))) if herr else None,
            "p99": _pct(herr_deg, 99),
            "max": float(herr_deg.max()) if herr else None,
        },
        "counters": f["/status"][-1].get("counters", {}),
        "nat_probe": events.get("nat_probe"),
        "stage": events.get("stage"),
    }
    leader_key = "fedlab/default/" + LEADER + "/pose"
    counts = subscriber.get("counts", {})
    pose_counts = {k: v for k, v in counts.items() if k.endswith(LEADER + "/pose")}
    arrivals = subscriber.get("pose_arrivals", [])
    out["outside_subscriber"] = {
        "leader_poses": sum(pose_counts.values()) if pose_counts else counts.get(leader_key, 0),
        "last_pose_before_end_s": (end - max(arrivals)) if arrivals else None,
        "status_samples": sum(v for k, v in counts.items() if k.endswith("/status")),
        "follower_poses_all_run": len(f["/pose/received"]),
    }
    if "cut_at" in events:
        cut, back = events["cut_at"], events["restored_at"]
        first_hold = [h["host_monotonic"] for h in holds if h["host_monotonic"] >= cut - 0.5]
        after = [p for p in f["/pose/received"] if p["host_monotonic"] > back]
        sync_after = [
            x["host_monotonic"] for x in f["/sync/exchange"] if x["host_monotonic"] > back
        ]
        resumed = [r["host_monotonic"] for r in resumes if r["host_monotonic"] > back]
        late = [p["host_monotonic"] - leader_host(p["t"]) for p in after[:40]]
        out["cut"] = {
            "length_s": back - cut,
            "hold_after_cut_ms": _ms(first_hold[0] - cut if first_hold else None),
            "holds_from_cut": len(first_hold),  # 1: the cut's, none flapping after it
            "pose_back_after_s": after[0]["host_monotonic"] - back if after else None,
            "sync_back_after_s": sync_after[0] - back if sync_after else None,
            "released_after_s": resumed[0] - back if resumed else None,
            "oldest_pose_after_return_ms": _ms(max(late) if late else None),
        }
    return out


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else round(seconds * 1e3, 3)


def _held_intervals(
    holds: list[dict[str, Any]], resumes: list[dict[str, Any]], end: float
) -> list[tuple[float, float]]:
    out = []
    ends = sorted(r["host_monotonic"] for r in resumes)
    for h in sorted(x["host_monotonic"] for x in holds):
        later = [e for e in ends if e > h]
        out.append((h, later[0] if later else end))
    return out


def run(
    names: list[str],
    transports: list[str],
    seconds: float,
    out: Path,
    repeats: int = 1,
    seed: int = 1,
    cfg: Sequence[str] = (),
    progress: Callable[[list[dict[str, Any]]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every scenario on every transport, ``repeats`` times (seeds ``seed``, ``seed+1``...);
    ``cfg`` as in :func:`run_one`. A run whose testbed cannot be built is kept as
    ``{"error": ...}`` and the others go on; ``progress`` gets the results so far after
    every run (to save them)."""
    results: list[dict[str, Any]] = []
    for name in names:
        for transport in transports:
            for k in range(repeats):
                scenario = replace(SCENARIOS[name])
                where = out / f"{name}-{transport}-{k}"
                try:
                    result = run_one(scenario, transport, seconds, where, seed + k, cfg)
                except TestbedError as error:
                    header = _header(scenario, transport, cfg, seconds, seed + k)
                    result = {**header, "error": str(error)}
                results.append(result)
                if progress is not None:
                    progress(results)
    return results
