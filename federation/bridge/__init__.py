"""Bridges that join agents speaking other protocols (the paper's UDP packets).

Rule: library code; no argparse, no :mod:`federation.cli`.
"""
