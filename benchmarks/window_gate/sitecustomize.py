"""Benchmark-only: the recording taps record in one window of simulated time in three.

``benchmarks/bringup.py`` puts this folder first on the PYTHONPATH of a run's node
processes (Python imports ``sitecustomize`` at start-up), with

- ``PKM_TAP_WINDOW_NS``: the window length in simulated ns. A tapped message whose
  header stamp (CDR bytes 4-12, as in every per-step stream and in /clock) falls in
  a window w with w % ``CYCLE`` == 0 is published and tapped, in the others only
  published. The window after a recording one *drains* it: the taps' last batch
  (they flush every 0.2 s of wall time), its packing and writing by the recorder
  and the bag's compression (every 0.5 s) land there; the third window is clean.
  Every node decides from the stamp alone, so the processes agree on the windows
  without talking to each other.
- ``PKM_TAP_WINDOW_LOG``: a folder; the process that publishes drives/state (sim_hw,
  once per loop step) writes there, at exit, the (stamp ns, perf_counter ns) of every
  step, from which the benchmark compares the step periods of adjacent windows.

``install()`` does the same in the calling process (the in-process mode).
"""

from __future__ import annotations

import atexit
import os
import struct
import time

_STAMP = struct.Struct("<iI")
CYCLE = 3                  # recording, draining, clean


def install(window_ns: int, log_dir: str | None) -> list:
    """Gate ``TappedPublisher.publish`` on the stamp's window; returns the list the
    (stamp ns, perf_counter ns) pairs of drives/state are appended to (and, with
    ``log_dir``, written to ``<log_dir>/<pid>.txt`` at exit)."""
    from pkm_common import tap

    publish, steps = tap.TappedPublisher.publish, []

    def gated_publish(self, data):
        sec, nanosec = _STAMP.unpack_from(data, 4)
        stamp_ns = sec * 1_000_000_000 + nanosec
        if self.topic.endswith("/drives/state"):
            steps.append((stamp_ns, time.perf_counter_ns()))
        if (stamp_ns // window_ns) % CYCLE == 0:
            publish(self, data)
        else:
            self.publisher.publish(data)

    tap.TappedPublisher.publish = gated_publish
    if log_dir:
        def write():
            if steps:
                with open(os.path.join(log_dir, f"{os.getpid()}.txt"), "w") as out:
                    out.write("\n".join(f"{s} {t}" for s, t in steps))
        atexit.register(write)
    return steps


if os.environ.get("PKM_TAP_WINDOW_NS"):
    install(int(os.environ["PKM_TAP_WINDOW_NS"]), os.environ.get("PKM_TAP_WINDOW_LOG"))
