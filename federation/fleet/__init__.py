"""Processes on this host: starting routers, agents and link emulators by pid,
and the demo that orchestrates them.

Rule: library code (no argparse, no :mod:`federation.cli`); every process it
starts it stops by its pid.
"""
