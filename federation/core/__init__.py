"""The federation's pure core: protocol logic that takes data and ``now``.

Wire codecs, key names, the sync exchange (client and server halves), clock
estimators, run state, time bases and schedules.

Rule: nothing here imports zenoh, socket, time, threading, argparse, or any
other fedlab package (checked by import-linter in ``make test``). Time comes in
as an argument, so a test replays the paper's timestamps exactly.
"""
