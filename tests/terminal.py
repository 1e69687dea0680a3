"""How a terminal starts a program in the foreground, for tests that press Ctrl-C."""

import signal


def default_sigint() -> None:
    """A ``preexec_fn``: SIGINT back to its default in the child. A shell without job
    control starts background jobs with SIGINT ignored, the ignored disposition passes
    to every child, and Python keeps an ignored SIGINT ignored (no KeyboardInterrupt):
    a suite run in the background (or a test process whose SIGINT some earlier code
    left ignored) would then not test Ctrl-C at all, and a Ctrl-C test fails."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
