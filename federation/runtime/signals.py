"""Signals that stop a process cleanly: an event set by a signal, with no lock taken in
the signal's handler.

Python runs a signal's handler in the main thread, between two bytecodes, possibly while
that thread holds a lock that cannot be taken twice. ``threading.Event.set`` and
``Event.wait`` both take the event's own: a handler calling ``stop.set()`` while the main
thread was inside ``stop.wait()`` (a loop's bounded wait, ten times a second) waited for
itself for ever. The process then never stopped: a bridge outlived SIGTERM until a
SIGKILL, its platform's stop path never run. Here the handler only writes the signal's
number to a pipe; a thread of its own reads it, logs it and sets the events.
"""

from __future__ import annotations

import contextlib
import faulthandler
import logging
import os
import signal
import threading
import weakref
from collections.abc import Iterable
from types import FrameType

__all__ = ["stop_event"]

log = logging.getLogger("fedlab")

_lock = threading.Lock()  # never taken by a handler: the relay's and stop_event's only
_pipe: tuple[int, int] | None = None  # (read, write), made at the first stop_event
# Events a signal sets: each with the signals it waits for and the seconds after which a
# stop still under way dumps every thread's stack (None: never).
_events: weakref.WeakKeyDictionary[threading.Event, tuple[frozenset[int], float | None]] = (
    weakref.WeakKeyDictionary()
)


def _forget_in_child() -> None:
    """A forked child has the pipe but not the relay thread: its signals would have set
    its parent's events. It makes its own at its first :func:`stop_event`."""
    global _pipe
    _pipe = None
    _events.clear()


os.register_at_fork(after_in_child=_forget_in_child)


def stop_event(signals: Iterable[int], report_after: float | None = None) -> threading.Event:
    """An event set when one of ``signals`` arrives (its handler replaces the one
    before). With ``report_after``, a process still running that many seconds after the
    event was set writes every thread's stack to stderr (a stop that hangs says where)."""
    global _pipe
    signals = frozenset(signals)
    stop = threading.Event()
    with _lock:
        if _pipe is None:
            read, write = os.pipe()
            os.set_blocking(write, False)  # a full pipe never blocks the handler
            _pipe = (read, write)
            threading.Thread(
                target=_relay, args=(read,), name="fedlab-signals", daemon=True
            ).start()
        _events[stop] = (signals, report_after)
    for sig in signals:
        signal.signal(sig, _handler)
    return stop


def _handler(signum: int, frame: FrameType | None) -> None:
    """The signal's handler: one write, no lock (see the module's docstring)."""
    if _pipe is not None:
        with contextlib.suppress(OSError):  # the pipe full: stops are already on their way
            os.write(_pipe[1], bytes([signum]))


def _relay(read: int) -> None:
    """Log each signal written to the pipe and set every event waiting for one."""
    while True:
        try:
            data = os.read(read, 64)
        except OSError:
            return
        if not data:
            return
        for signum in data:
            log.info("received %s, stopping", signal.Signals(signum).name)
            with _lock:
                waiting = list(_events.items())
            for event, (signals, report_after) in waiting:
                if signum not in signals:
                    continue
                if not event.is_set() and report_after is not None:
                    faulthandler.dump_traceback_later(report_after, exit=False)
                event.set()
