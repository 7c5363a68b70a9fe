"""Deployment artefacts: the federation CA and the labs' and agents' certificates
(:mod:`~federation.deploy.certs`), a whole federation's configs generated from one file
(:mod:`~federation.deploy.generate`), and the check that an agent's identity is its name
(:mod:`~federation.runtime.identity`).

Rule: library code; no Zenoh session, no argparse, no :mod:`federation.cli`.
"""
