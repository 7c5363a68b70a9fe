"""The federation's pure core: protocol logic that takes data and ``now``.

=================  ==============================================================
module             what
=================  ==============================================================
``wire``           the paper's binary packets, byte for byte
``keys``           Zenoh key names and agent ids
``sync``           the sync exchange: client (``SyncClient``) and server
                   (``serve``) halves, the paper's estimator
``clockfilter``    offset and drift by delay-weighted regression
``estimators``     the estimators by name (``ESTIMATORS``: the one list)
``timebase``       own clock, reference (simulation) time, a peer's clock
``runstate``       run modes: start, freeze, resume, abort
``schedule``       the periodic tasks' deadlines
``linkwatch``      the stale-pose safe hold
``channels``       the recording channels' names and fields
``angles``         the one angle wrap
``paper``          the paper's figures, written down once
=================  ==============================================================

Rule: nothing here imports zenoh, socket, time, threading, argparse, or any
other fedlab package (checked by import-linter in ``make test``). Time comes in
as an argument, so a test replays the paper's timestamps exactly.
"""
