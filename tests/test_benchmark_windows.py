"""benchmarks/bringup.py's in-run measurement of the recording cost: the tap gate of
benchmarks/window_gate and the estimator over its windows."""

from __future__ import annotations

import importlib.util
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pkm_recording import tap
from pkm_recording.tap import StreamTap, TappedPublisher, read_batch

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name: str, path: Path):
    saved = list(sys.path)           # bringup.py puts benchmarks/ first, which would shadow names
    try:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path[:] = saved
    return module


bringup = _load("pkm_benchmarks_bringup", BENCHMARKS / "bringup.py")
gate = _load("pkm_benchmarks_window_gate", BENCHMARKS / "window_gate" / "sitecustomize.py")


def _steps(periods_s: np.ndarray, dt_ns: int = 1_000_000) -> list[tuple[int, int]]:
    """(stamp ns, wall ns) of a run whose period from step k to step k + 1 took periods_s[k]."""
    wall = np.concatenate([[0], np.cumsum(np.round(periods_s * 1e9))]).astype(np.int64)
    return [(k * dt_ns, int(t)) for k, t in enumerate(wall)]


def test_the_estimator_recovers_a_cost_split_between_recording_and_draining_under_a_drift():
    window, n = 100, 1250                # 12 full windows of 100 steps and a partial one
    k = np.arange(n)                     # the period that starts at step k
    drift = 1e-3 * (1.0 + 0.5 * k / n)                     # the host slows by half over the run
    w = k // window
    # 4 % of the period per recorded step: 3 % while recording, the 1 % deferred to the next window
    periods = drift * np.where(w % 3 == 0, 1.03, np.where(w % 3 == 1, 1.01, 1.0))
    extra, clean, period, _ = bringup.window_costs(_steps(periods), window * 1_000_000, window // 2)
    # cycles at windows 3, 6 and 9 (0 has no clean window before it; 12 is cut short)
    assert len(extra) == 3
    # the drift cancels to first order (the cost scales with it: the rest, <6e-4, is its second order)
    np.testing.assert_allclose(extra / clean, 0.04, atol=1e-3)
    assert extra.sum() / clean.sum() == pytest.approx(0.04, abs=1e-3)
    without_drain = (periods - drift * np.where(w % 3 == 1, 0.01, 0.0))       # a two-window design's view
    extra, clean, _, _ = bringup.window_costs(_steps(without_drain), window * 1_000_000, window // 2)
    np.testing.assert_allclose(extra / clean, 0.03, atol=1e-3)
    assert 1e-3 < period < 1.5e-3


def test_the_two_stage_bootstrap_widens_with_the_spread_between_runs():
    rng = np.random.default_rng(1)
    runs = [(rng.normal(0.03, 0.1, 30), np.ones(30)) for _ in range(8)]

    def ratio(e, c):
        return e.sum() / c.sum()
    pooled = ratio(np.concatenate([e for e, _ in runs]), np.ones(240))
    low, high = bringup.two_stage_bootstrap_90(runs, ratio, draws=2000)
    assert low < pooled < high and high - low < 0.04      # the cycles' spread alone: sd 0.1 / sqrt(240)
    # the same cycles, each run shifted by +-0.06 (a VM phase): the runs are the units
    shifted = [(e + (0.06 if k % 2 else -0.06), c) for k, (e, c) in enumerate(runs)]
    low_s, high_s = bringup.two_stage_bootstrap_90(shifted, ratio, draws=2000)
    assert low_s < pooled < high_s and high_s - low_s > 1.5 * (high - low)


class _Publisher:
    def __init__(self, topic):
        self.topic_name, self.sent = topic, []

    def publish(self, data):
        self.sent.append(data)


def _stamped(stamp_ns: int) -> bytes:
    return b"\x00\x01\x00\x00" + struct.pack("<iI", *divmod(stamp_ns, 1_000_000_000)) + b"rest"


def test_the_gate_taps_only_the_messages_of_one_window_in_three(monkeypatch):
    monkeypatch.setattr(TappedPublisher, "publish", TappedPublisher.publish)    # restored afterwards
    steps, cpu = gate.install(window_ns=2_000_000, log_dir=None)
    streams = StreamTap()
    state = TappedPublisher(_Publisher("/pkm/drives/state"), streams, "sensor_msgs/msg/JointState", lambda: 7)
    pose = TappedPublisher(_Publisher("/pkm/metrology/pose"), streams, "geometry_msgs/msg/PoseStamped", lambda: 7)
    for k in range(10):                                     # 1 ms steps, windows of 2
        state.publish(_stamped(k * 1_000_000))
        pose.publish(_stamped(k * 1_000_000))
    assert len(state.publisher.sent) == len(pose.publisher.sent) == 10             # everything published
    tapped = [(topic, struct.unpack_from("<iI", data, 4)[1] // 1_000_000) for topic, _, _, data in
              read_batch(streams.take_batch())]
    assert [k for topic, k in tapped if topic == "/pkm/drives/state"] == [0, 1, 6, 7]
    assert [k for topic, k in tapped if topic == "/pkm/metrology/pose"] == [0, 1, 6, 7]
    assert [s for s, _ in steps] == [k * 1_000_000 for k in range(10)]             # drives/state: every step
    assert [w for w, _ in cpu] == [0, 1, 2, 3, 4]          # a CPU mark at the first message of each window
    assert all(a <= b for (_, a), (_, b) in zip(cpu, cpu[1:]))


def test_a_node_process_loads_the_gate_from_its_pythonpath_and_logs_its_steps_at_exit(tmp_path):
    """As the benchmark runs the node processes: the gate comes from PYTHONPATH and
    the drives/state steps reach the log folder when the process exits."""
    code = ("from pkm_recording.tap import StreamTap, TappedPublisher\n"
            "class P:\n    topic_name = '/pkm/drives/state'\n    def publish(self, data): pass\n"
            "pub = TappedPublisher(P(), StreamTap(), 'sensor_msgs/msg/JointState', lambda: 1)\n"
            "for k in range(4):\n"
            "    pub.publish(b'\\x00\\x01\\x00\\x00' + bytes(4) + (k * 1000).to_bytes(4, 'little') + b'x')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(BENCHMARKS / "window_gate"),
                                                        os.environ.get("PYTHONPATH", "")]),
           "PKM_TAP_WINDOW_NS": "1000000", "PKM_TAP_WINDOW_LOG": str(tmp_path)}
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=60)
    logs = list(tmp_path.glob("*.txt"))
    assert len(logs) == 1
    assert [int(line.split()[0]) for line in logs[0].read_text().splitlines()] == [0, 1000, 2000, 3000]
    module, *marks = next(tmp_path.glob("*.cpu")).read_text().splitlines()
    assert module == Path(sys.executable).name                      # run with -c: no module
    assert [int(line.split()[0]) for line in marks] == [0]            # all four stamps in window 0
    assert not list(tmp_path.glob("*.rec"))                           # not the recorder: no sampler


def test_the_recorder_s_cpu_sampler_writes_its_samples_at_exit(tmp_path):
    code = ("import sitecustomize as gate, time\n"
            "gate.sample_cpu(%r, period_s=0.005)\n"
            "end = time.perf_counter() + 0.2\n"
            "while time.perf_counter() < end: pass\n" % str(tmp_path))
    env = {**os.environ, "PYTHONPATH": str(BENCHMARKS / "window_gate")}
    env.pop("PKM_TAP_WINDOW_NS", None)
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=60)
    samples = np.array([list(map(int, line.split())) for line in
                        next(tmp_path.glob("*.rec")).read_text().splitlines()])
    assert len(samples) >= 5 and (np.diff(samples, axis=0) >= 0).all()
    # a busy loop: the process's CPU time grows, at most as fast as the wall time (one
    # thread busy; how much less depends on what else the host runs)
    wall_s, cpu_s = (samples[-1] - samples[0]) * 1e-9          # columns: perf_counter, CPU
    assert 0.0 < cpu_s < 1.1 * wall_s + 0.01


def test_cpu_costs_recover_a_known_extra_cpu_per_recorded_step():
    window_steps, cycle_cpu = 100, {0: 0.05, 1: 0.02, 2: 0.0}     # extra CPU s per window, by w % 3
    base = 0.4                                                    # s of CPU per clean window
    marks, total = [], 0.0
    for w in range(13):
        marks.append((w, int(round(total * 1e9))))
        total += base * (1.0 + 0.02 * w) + cycle_cpu[w % 3]         # with a slow drift
    costs = bringup.cpu_costs(bringup.window_cpu(marks), window_steps, [3, 6, 9, 12])
    np.testing.assert_allclose(costs[:3], 0.07 / window_steps, rtol=1e-6)     # the drift cancels
    assert np.isnan(costs[3])                                     # window 13, 14 never marked


def test_the_recorder_s_samples_become_marks_at_each_window_s_first_step():
    steps = [(k * 1_000_000, 5_000_000_000 + k * 2_000_000) for k in range(40)]   # 2 ms per step
    samples = [(5_000_000_000 + i * 10_000_000, i * 3_000_000) for i in range(10)]  # 0.3 CPU s per wall s
    marks = bringup.marks_from_samples(samples, steps, window_ns=10_000_000)
    # windows of 10 steps start at 0, 20, 40, 60 ms of wall time; the samples reach 90 ms
    assert [w for w, _ in marks] == [0, 1, 2, 3]
    np.testing.assert_allclose([c for _, c in marks], [0.0, 6e6, 12e6, 18e6])


def test_the_gate_is_off_without_its_environment(monkeypatch):
    monkeypatch.delenv("PKM_TAP_WINDOW_NS", raising=False)
    monkeypatch.setattr(TappedPublisher, "publish", TappedPublisher.publish)    # restored even if it fails
    original = TappedPublisher.publish
    _load("pkm_benchmarks_window_gate_again", BENCHMARKS / "window_gate" / "sitecustomize.py")
    assert tap.TappedPublisher.publish is original
