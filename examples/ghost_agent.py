"""A ghost platform: replays a CSV trajectory (t, x, y, heading) into a federation
and prints what it sees of the others. The whole agent, with the fedlab SDK.

    python examples/ghost_agent.py examples/ghost.csv tcp/127.0.0.1:7447 30
"""

import csv
import sys
import time

import numpy as np

from federation import Agent, Pose

path, endpoint, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
with open(path, newline="") as f:
    rows = np.array([[float(r[k]) for k in ("t", "x", "y", "heading")] for r in csv.DictReader(f)])
t, x, y, heading = rows.T


def where(now: float) -> Pose:  # replays the trajectory in a loop, on simulation time
    k = now % t[-1]
    return Pose(*(float(np.interp(k, t, v)) for v in (x, y, heading)))


with Agent("lab3/ghost", where, connect=[endpoint]) as ghost:
    for _ in range(int(seconds)):
        time.sleep(1.0)
        seen = {
            name: (round(t_sim, 3), round(p.heading, 3))
            for name, (t_sim, p) in ghost.others().items()
        }
        print({"time": ghost.time, "others": seen}, flush=True)
