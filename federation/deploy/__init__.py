"""Deployment artefacts: the federation CA and the labs' and agents' certificates.

Rule: library code; no Zenoh session, no argparse, no :mod:`federation.cli`.
"""
