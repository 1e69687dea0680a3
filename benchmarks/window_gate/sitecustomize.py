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
- ``PKM_TAP_WINDOW_LOG``: a folder; at exit
  - the process that publishes drives/state (sim_hw, once per loop step) writes there
    ``<pid>.txt``: the (stamp ns, perf_counter ns) of every step, from which the
    benchmark compares the step periods of adjacent windows;
  - every process that publishes tapped streams writes ``<pid>.cpu``: its module, then
    (window, CPU time ns of the process, all threads) at its first tapped message of
    each window, from which the benchmark compares the CPU used in adjacent windows;
  - the recorder process writes ``<pid>.rec``: (perf_counter ns, CPU time ns)
    sampled every 20 ms by a thread of its own (it publishes nothing tapped; its
    windows come from sim_hw's step times).

``install()`` does the same in the calling process (the in-process mode).
"""

from __future__ import annotations

import atexit
import os
import struct
import sys
import threading
import time

_STAMP = struct.Struct("<iI")
CYCLE = 3                  # recording, draining, clean


def _module() -> str:
    argv = getattr(sys, "orig_argv", sys.argv)
    return argv[argv.index("-m") + 1] if "-m" in argv[:-1] else os.path.basename(argv[0] if argv else "python")


def install(window_ns: int, log_dir: str | None) -> tuple[list, list]:
    """Gate ``TappedPublisher.publish`` on the stamp's window; returns the lists the
    (stamp ns, perf_counter ns) pairs of drives/state and the (window, process CPU ns)
    marks are appended to (with ``log_dir``, written to ``<log_dir>/<pid>.txt`` and
    ``<pid>.cpu`` at exit)."""
    from pkm_recording import tap

    publish, steps, cpu = tap.TappedPublisher.publish, [], []
    last = [None]

    def gated_publish(self, data):
        sec, nanosec = _STAMP.unpack_from(data, 4)
        stamp_ns = sec * 1_000_000_000 + nanosec
        window = stamp_ns // window_ns
        if window != last[0]:
            last[0] = window
            cpu.append((window, time.process_time_ns()))
        if self.topic.endswith("/drives/state"):
            steps.append((stamp_ns, time.perf_counter_ns()))
        if window % CYCLE == 0:
            publish(self, data)
        else:
            self.publisher.publish(data)

    tap.TappedPublisher.publish = gated_publish
    if log_dir:
        def write():
            if steps:
                with open(os.path.join(log_dir, f"{os.getpid()}.txt"), "w") as out:
                    out.write("\n".join(f"{s} {t}" for s, t in steps))
            if cpu:
                with open(os.path.join(log_dir, f"{os.getpid()}.cpu"), "w") as out:
                    out.write("\n".join([_module()] + [f"{w} {c}" for w, c in cpu]))
        atexit.register(write)
    return steps, cpu


def sample_cpu(log_dir: str, period_s: float = 0.02) -> list:
    """A daemon thread appends (perf_counter ns, process CPU ns) every ``period_s``;
    written to ``<log_dir>/<pid>.rec`` at exit (the recorder process)."""
    samples, stop = [], threading.Event()

    def sample():
        while not stop.wait(period_s):
            samples.append((time.perf_counter_ns(), time.process_time_ns()))

    def write():
        stop.set()
        sampler.join(timeout=1.0)     # its last sample first: taken before ours, appended after it otherwise
        samples.append((time.perf_counter_ns(), time.process_time_ns()))
        with open(os.path.join(log_dir, f"{os.getpid()}.rec"), "w") as out:
            out.write("\n".join(f"{t} {c}" for t, c in samples))
    sampler = threading.Thread(target=sample, name="window_gate_cpu", daemon=True)
    sampler.start()
    atexit.register(write)
    return samples


if os.environ.get("PKM_TAP_WINDOW_NS"):
    install(int(os.environ["PKM_TAP_WINDOW_NS"]), os.environ.get("PKM_TAP_WINDOW_LOG"))
    if os.environ.get("PKM_TAP_WINDOW_LOG") and _module() == "pkm_recording.recorder_node":
        sample_cpu(os.environ["PKM_TAP_WINDOW_LOG"])
