"""Keep the garbage collector's full passes out of the control loop's way.

A full (generation 2) collection walks every container the process holds and
holds the interpreter lock while it does: with numpy, pydantic and Zenoh
imported and 16 agents in a process that was 30-40 ms of CPU each time,
measured with ``gc.callbacks``, and every pose sample arriving meanwhile waited.
Nearly all of those objects live as long as the process (modules, classes,
configuration), so an agent process moves them to the permanent generation once
it is up (:func:`gc.freeze`, as CPython's docs suggest for long-running servers);
later passes walk only what the run itself allocates (about 2 ms).
"""

from __future__ import annotations

import gc

__all__ = ["freeze_startup_heap"]


def freeze_startup_heap() -> None:
    """Collect once, then exempt every object alive now from later collections.

    For processes that own their interpreter (``fedlab agent``, the bridge, the
    benchmarks' workers), once they are up; not for the SDK, whose host program
    owns its heap.
    """
    gc.collect()
    gc.freeze()
