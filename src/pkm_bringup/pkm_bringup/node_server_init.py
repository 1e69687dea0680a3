"""The node server's first import (processes.PRELOAD): the server leaves pkm-run's
session and ignores the signals meant for pkm-run (a Ctrl-C, Ctrl-\\, a closed
terminal, ``timeout``'s SIGTERM to the process group), so that it lives exactly as long
as pkm-run does (multiprocessing ends it when pkm-run's end of its pipe closes) and
its nodes, which die with it (PR_SET_PDEATHSIG), are stopped by pkm-run in order. A
node restores the default dispositions (processes.run_forked). Imported anywhere but by
the server's preload, it does nothing."""

from __future__ import annotations

import os
import signal
import sys

IGNORED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


def _in_the_server() -> bool:
    """Imported by the fork server's preload: multiprocessing.forkserver.main is on the stack."""
    server = sys.modules.get("multiprocessing.forkserver")
    if server is None:
        return False
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code is server.main.__code__:
            return True
        frame = frame.f_back
    return False


if _in_the_server():
    try:
        os.setsid()
    except OSError:                      # already a session leader
        pass
    for _sig in IGNORED:
        signal.signal(_sig, signal.SIG_IGN)
