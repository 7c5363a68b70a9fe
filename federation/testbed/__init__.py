"""The network testbed: two labs' real network stacks on this host, in network
namespaces, with kernel NAT and stateful firewalls (nftables) and a packet-level
impairment stage on a TUN device in the WAN between them.

- :mod:`federation.testbed.topology`: the namespaces, addresses, routes and
  firewall rules, written down (pure);
- :mod:`federation.testbed.bed`: :class:`Testbed`, which builds them, runs
  processes in them and removes everything on exit.

Rule: library code (no argparse); it may import the fleet and everything below.
"""

from federation.testbed.bed import (
    PREFIX,
    Testbed,
    TestbedError,
    leftover_namespaces,
    missing,
    probe_tcp,
)
from federation.testbed.topology import ADDR, Addresses

__all__ = [
    "ADDR",
    "PREFIX",
    "Addresses",
    "Testbed",
    "TestbedError",
    "leftover_namespaces",
    "missing",
    "probe_tcp",
]
