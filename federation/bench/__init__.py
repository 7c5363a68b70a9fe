"""Benchmarks that compare against baselines measured in the same run (``fedlab bench``).

- :mod:`federation.bench.sync`: offset error of each estimator under emulated paths;
- :mod:`federation.bench.latency`: pose latency beside bare Zenoh and raw UDP;
- :mod:`federation.bench.scale`: CPU, latency and loss as the number of agents grows.

Rule: library code; every run returns its results, :mod:`federation.cli.bench`
parses the flags and prints them. No argparse here.
"""

__all__: list[str] = []
