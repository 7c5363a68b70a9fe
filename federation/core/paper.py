"""The source paper's figures that fedlab relies on, written down once.

The paper: two air-bearing spacecraft-emulation platforms, KNATTE (Kiruna) and
PINOCCHIO (Rome), about 3900 km apart, fly a leader/follower attitude maneuver
over the internet with a three-timestamp clock synchronization. What was
measured, and under which conditions, is in ``docs/paper.md``; the code cites
that document and these names, never a number typed again.
"""

from __future__ import annotations

__all__ = [
    "CLOCK_OFFSET",
    "FOLLOWER_LAG",
    "MANEUVER_AMPLITUDE_DEG",
    "MANEUVER_DURATION",
    "MANEUVER_STILL",
    "OFFSET_STD",
    "ONE_WAY_DELAY",
    "ONE_WAY_DELAY_MEDIAN",
    "ONE_WAY_DELAY_STD",
    "RECEIVED_BEHIND_SENT",
    "SYNC_PHASE",
]

# -- the hardware run (docs/paper.md, "Hardware run") --------------------------------
MANEUVER_STILL = 10.0
"""s of reference time held still at the start: the sync phase (Eq. 6)."""
MANEUVER_DURATION = 60.0
"""s for the leader's rotation out and back."""
MANEUVER_AMPLITUDE_DEG = 45.0
"""degrees of the leader's rotation."""
SYNC_PHASE = MANEUVER_STILL
"""s over which the paper averages the offset before holding it (Eq. 6)."""
FOLLOWER_LAG = (4.0, 5.0)
"""s, (low, high) how far the follower's heading trailed the leader's
(a badly tuned PID, not the network)."""

# -- the validation over the internet (docs/paper.md, "Validation") ------------------
CLOCK_OFFSET = 26.42
"""s, median magnitude of the Kiruna-Rome clock offset; the demo skews a clock by it."""
ONE_WAY_DELAY = 0.040
"""s, median one-way delay Kiruna-Rome; the demo's link emulator delays by it."""
OFFSET_STD = (0.005, 0.009)
"""s, (low, high) standard deviation of the per-exchange offset over the two platforms."""
ONE_WAY_DELAY_MEDIAN = (0.0395, 0.040)
"""s, (low, high) median one-way delay over the two platforms."""
ONE_WAY_DELAY_STD = (0.005, 0.011)
"""s, (low, high) standard deviation of the one-way delay over the two platforms."""
RECEIVED_BEHIND_SENT = (0.060, 0.100)
"""s, how far received heading curves trailed the sent ones after offset correction."""
