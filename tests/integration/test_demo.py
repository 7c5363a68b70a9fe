"""``fedlab demo`` end to end: routers, link emulator, simulated platforms, report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration


def test_demo_short_run_reproduces_the_paper_setup(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    result = subprocess.run(
        [sys.executable, "-m", "federation", "demo", "--duration", "25", "--out", str(out)],
        capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "this run beside the paper" in result.stdout
    summary = json.loads((out / "summary.json").read_text())

    pair = next(
        p
        for p in summary["sync"]
        if p["client"] == "rome/pinocchio" and p["peer"] == "kiruna/knatte"
    )
    print(json.dumps(pair, indent=1))
    assert pair["estimate_error_median_abs_s"] < 0.002
    assert abs(pair["delay_median_s"] - 0.040) < 0.005
    followers = {f["follower"]: f for f in summary["followers"]}
    compensated, raw = followers["rome/pinocchio"], followers["rome/pinocchio-raw"]
    print("separation compensated", compensated["reference_separation_s"])
    print("separation raw", raw["reference_separation_s"])
    assert abs(compensated["reference_separation_s"]) <= 0.005
    assert raw["reference_separation_s"] > 0.030  # one delay behind, at least

    pngs = sorted(p.name for p in out.glob("*.png"))
    assert "heading.png" in pngs and "sent_vs_received.png" in pngs
    assert any(p.startswith("sync_") for p in pngs)
    assert all((out / p).stat().st_size > 10_000 for p in pngs)
    assert "heading.png" in (out / "report.md").read_text()

    channels = read_messages(out / "rome-pinocchio.mcap")
    for topic in ("/pose/sent", "/pose/received", "/sync/exchange", "/reference", "/truth",
                  "/control", "/status"):  # fmt: skip
        assert channels[topic], topic
    assert any(e["event"] == "started" for e in channels["/control"])
