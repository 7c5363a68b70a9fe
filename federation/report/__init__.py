"""Reports from a run's recordings: loading, analysis, summary, figures, markdown.

Rule: reads files only; no Zenoh, no argparse, no :mod:`federation.cli`.
"""
