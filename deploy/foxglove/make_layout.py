"""Write deploy/foxglove/fedlab.json, the Foxglove layout of ``fedlab foxglove``'s live view
(and of recordings: the 3D panel reads /tf in both), with the Foxglove SDK's layout types.

    .venv/bin/python deploy/foxglove/make_layout.py

The panels every federation has, whatever its agents: 3D (fixed frame ``fedlab_common``:
every platform's frame and footprint, each work area), the run table (/fedlab/run: mode,
run time, hold) and the per-peer sync table (/fedlab/peers: offset, delay, error bound).
For plots of each agent's view of its peers, let the view write a layout of the agents
it sees: ``fedlab foxglove --layout FILE`` (the same panels and three plots).
"""

from __future__ import annotations

from pathlib import Path

import foxglove.layouts as fl

from federation.runtime.foxglove import layout as view_layout


def layout() -> fl.Layout:
    return view_layout(())


if __name__ == "__main__":
    out = Path(__file__).with_name("fedlab.json")
    out.write_text(layout().to_json() + "\n", encoding="utf-8")
    print(out)
