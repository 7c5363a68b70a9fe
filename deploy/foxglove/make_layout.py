"""Write deploy/foxglove/fedlab.json, the Foxglove layout of ``fedlab foxglove``'s live view
(and of recordings: the 3D panel reads /tf in both), with the Foxglove SDK's layout types.

    .venv/bin/python deploy/foxglove/make_layout.py

3D (fixed frame ``fedlab_common``: every platform's frame and footprint), the per-peer
sync table (/fedlab/peers: offset, delay, error bound), the run table (/fedlab/run: mode,
run time, hold) and a plot of the demo's follower's offset and delay to its leader
(/fedlab/sync/rome/pinocchio/kiruna/knatte; edit the topic for other agents).
"""

from __future__ import annotations

from pathlib import Path

import foxglove.layouts as fl

SYNC = "/fedlab/sync/rome/pinocchio/kiruna/knatte"


def layout() -> fl.Layout:
    three_d = fl.ThreeDeePanel(
        title="Platforms in the common frame",
        config=fl.ThreeDeeConfig(fixed_frame="fedlab_common", follow_tf="fedlab_common"),
    )
    plot = fl.PlotPanel(
        title="rome/pinocchio's view of kiruna/knatte (ms)",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=f"{SYNC}.offset_ms"),
                fl.PlotSeries(value=f"{SYNC}.delay_ms"),
                fl.PlotSeries(value=f"{SYNC}.error_bound_ms"),
            ],
            show_legend=True,
        ),
    )
    peers = fl.TablePanel(
        title="Sync per peer", config=fl.TableConfig(topic_path="/fedlab/peers.rows")
    )
    run = fl.TablePanel(title="Run", config=fl.TableConfig(topic_path="/fedlab/run.rows"))
    right = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(proportion=1, content=run),
            fl.SplitItem(proportion=1, content=peers),
            fl.SplitItem(proportion=1, content=plot),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3, content=three_d),
                fl.SplitItem(proportion=2, content=right),
            ],
        )
    )


if __name__ == "__main__":
    out = Path(__file__).with_name("fedlab.json")
    out.write_text(layout().to_json() + "\n", encoding="utf-8")
    print(out)
