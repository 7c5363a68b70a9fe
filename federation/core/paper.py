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
    "MANEUVER_AMPLITUDE_DEG",
    "MANEUVER_DURATION",
    "MANEUVER_STILL",
    "ONE_WAY_DELAY",
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

# -- the validation over the internet (docs/paper.md, "Validation") ------------------
CLOCK_OFFSET = 26.42
"""s, median magnitude of the Kiruna-Rome clock offset; the demo skews a clock by it."""
ONE_WAY_DELAY = 0.040
"""s, median one-way delay Kiruna-Rome; the demo's link emulator delays by it."""
RECEIVED_BEHIND_SENT = (0.060, 0.100)
"""s, how far received heading curves trailed the sent ones after offset correction."""
