"""Baseline programs for the benchmarks: plain zenoh and plain sockets, no fedlab code,
run as scripts (``python FILE ...``) so the comparison shares nothing with fedlab."""
