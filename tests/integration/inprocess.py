"""``fedlab`` commands run in the test's own process, for the integration tests.

:func:`federation.cli.main` is the ``fedlab`` command itself; called here it parses the
same arguments, opens its own Zenoh session (closed when it returns) and prints the
same output, without the interpreter's start and ``federation``'s imports that a
child process pays each time (a second of CPU, several on cores shared with parallel
tests). A claim about the command's own process (its signals, its exit on a kill)
keeps a child process; a command that talks to agents over Zenoh or reads files runs
here. It must run on the main thread (the command sets signal handlers, and puts
back the ones it found).
"""

from __future__ import annotations

import contextlib
import io
import subprocess

from federation.cli import main

__all__ = ["fedlab_here"]


def fedlab_here(*args: str) -> subprocess.CompletedProcess[str]:
    """Run ``fedlab ARGS`` in this process; its exit code and what it printed."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return subprocess.CompletedProcess(["fedlab", *args], code, out.getvalue(), err.getvalue())
