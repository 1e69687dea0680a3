"""The node server's first import (processes.PRELOAD): the server leaves pkm-run's
session and ignores the signals meant for pkm-run (a Ctrl-C, Ctrl-\\, a closed
terminal, ``timeout``'s SIGTERM to the process group), so that it lives exactly as long
as pkm-run does (multiprocessing ends it when pkm-run's end of its pipe closes) and
its nodes, which die with it (PR_SET_PDEATHSIG), are stopped by pkm-run in order. A
node restores the default dispositions (processes.run_forked). Imported anywhere but in
the server, it does nothing."""

from __future__ import annotations

import os
import signal
import sys

IGNORED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


def _in_the_server() -> bool:
    return "multiprocessing.forkserver" in sys.modules and sys.argv[:1] == ["-c"]


if _in_the_server():
    try:
        os.setsid()
    except OSError:                      # already a session leader
        pass
    for _sig in IGNORED:
        signal.signal(_sig, signal.SIG_IGN)
