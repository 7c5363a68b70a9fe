"""The Zenoh runtime: sessions, routers, agents, recorders, execution clocks.

A thin layer that moves bytes and timestamps between Zenoh and the pure core
(:mod:`federation.core`) and the platforms (:mod:`agents`).

Rule: may import :mod:`federation.core`, :mod:`agents` and :mod:`schemas`;
never :mod:`federation.cli` nor argparse.
"""
