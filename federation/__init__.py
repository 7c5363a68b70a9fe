"""fedlab's federation layer, in packages named by their layer.

========================  ==========================================================
package                   what, and what it may import
========================  ==========================================================
``federation.core``       pure protocol logic (wire, keys, sync, estimators, run
                          state, time base, schedules); imports nothing of fedlab
``federation.runtime``    the thin Zenoh layer: sessions, routers, agents, recorder,
                          ctl and monitor libraries, SDK; imports core, agents, schemas
``federation.link``       the link emulator; ``federation.report``: reports;
                          ``federation.bridge``: the legacy UDP bridge;
                          ``federation.deploy``: certificates; may import runtime
``federation.fleet``      processes on this host and the demo
``federation.bench``      benchmarks against baselines of the same run
``federation.cli``        the ``fedlab`` command: parses and calls; nothing imports it
========================  ==========================================================

The rules are import-linter contracts in pyproject.toml, checked by ``make test``.
"""

from federation.core.keys import AgentId
from federation.core.sync import Exchange, PaperEstimator, SyncClient
from federation.core.wire import Pose, PoseSample

__all__ = ["Agent", "AgentId", "Exchange", "PaperEstimator", "Pose", "PoseSample", "SyncClient"]


def __getattr__(name: str) -> object:
    # The SDK opens Zenoh sessions: import it only when asked for (``from federation
    # import Agent``), so the command line and the pure modules stay light.
    if name == "Agent":
        from federation.runtime.sdk import Agent

        return Agent
    raise AttributeError(f"module 'federation' has no attribute {name!r}")


__version__ = "0.1.0"
