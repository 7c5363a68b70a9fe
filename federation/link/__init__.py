"""The link emulator (``fedlab link``): delay, jitter, bursts, asymmetry and loss
between two routers, over TCP or UDP; a userspace stand-in for netem.

Placed between two Zenoh routers (``lab B router -> link -> lab A router``), it
delays, jitters and, for datagrams, drops and reorders traffic the way the
paper's internet path did (one-way delay ~40 ms, std 5-11 ms, bursts of larger
deviation every ~3 minutes).

Modules, by topic:

- :mod:`federation.link.model`: the path model and delivery times (pure: ``now``
  passed in, no sockets, clocks or threads);
- :mod:`federation.link.stats`: the counters and their summary (pure);
- :mod:`federation.link.relay`: what the relays share (the delivery-time queue);
- :mod:`federation.link.tcp`, :mod:`federation.link.udp`: the relays (asyncio);
- :mod:`federation.link.runner`: the event loop, ``duration``, signals, ``--stats-json``.

The settings are :class:`schemas.link.LinkOptions` (the flags' units) and
:class:`schemas.link.DirectionConfig` (the model's). Rule: library code; no
argparse, no :mod:`federation.cli`.
"""

from federation.link.model import (
    PARETO_SHAPE,
    DatagramScheduler,
    DirectionModel,
    LinkModel,
    StreamScheduler,
    datagram_deliver_at,
    stream_deliver_at,
)
from federation.link.runner import run_link, serve
from federation.link.stats import DirectionStats, LinkStats, summary
from schemas.link import DirectionConfig, JitterDist, LinkEndpoint, LinkOptions, parse_endpoint

__all__ = [
    "PARETO_SHAPE",
    "DatagramScheduler",
    "DirectionConfig",
    "DirectionModel",
    "DirectionStats",
    "JitterDist",
    "LinkEndpoint",
    "LinkModel",
    "LinkOptions",
    "LinkStats",
    "StreamScheduler",
    "datagram_deliver_at",
    "parse_endpoint",
    "run_link",
    "serve",
    "stream_deliver_at",
    "summary",
]
