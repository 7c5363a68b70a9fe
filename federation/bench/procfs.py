"""What Linux's /proc says of a process, for the benchmarks (no fedlab imports: the
bare floor's measurements read it too)."""

from __future__ import annotations

__all__ = ["rss_mib"]


def rss_mib(pid: int) -> float:
    """Resident memory of process ``pid`` (MiB, Linux /proc: OSError without it, or
    for a process gone); NaN if its status has no resident size."""
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")
