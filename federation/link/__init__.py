"""The link emulator (``fedlab link``): delay, jitter, bursts, asymmetry and loss
between two routers, over TCP or UDP.

Rule: library code; no argparse, no :mod:`federation.cli`.
"""
