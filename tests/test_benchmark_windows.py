"""benchmarks/bringup.py's in-run measurement of the recording cost: the tap gate of
benchmarks/window_gate and the estimator over its windows."""

from __future__ import annotations

import importlib.util
import struct
import sys
from pathlib import Path

import numpy as np
from pkm_common import tap
from pkm_common.tap import StreamTap, TappedPublisher, read_batch

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
    """(stamp ns, wall ns) of a run whose step k took periods_s[k - 1]."""
    wall = np.concatenate([[0], np.cumsum(np.round(periods_s * 1e9))]).astype(np.int64)
    return [(k * dt_ns, int(t)) for k, t in enumerate(wall)]


def test_the_estimator_recovers_a_known_cost_under_a_drifting_host():
    window, n = 100, 1050                # 10 full windows of 100 steps and a partial one
    k = np.arange(1, n + 1)
    drift = 1e-3 * (1.0 + 0.5 * k / n)                     # the host slows by half over the run
    recording = ((k // window) % 2 == 0)                    # the step that ends at stamp k
    periods = drift * np.where(recording, 1.04, 1.0)
    ratios, silent = bringup.window_ratios(_steps(periods), window * 1_000_000, window // 2)
    # windows 2, 4, 6, 8 have both neighbours (0 is the start; 10 is partial, its right one missing)
    assert len(ratios) == 4
    np.testing.assert_allclose(ratios, 0.04, atol=1e-6)     # the drift cancels between neighbours
    assert 1e-3 < silent < 1.5e-3
    naive = [periods[(k // window) == w].mean() / periods[(k // window) == w + 1].mean() - 1 for w in (2, 4, 6, 8)]
    assert min(naive) < 0.035                               # against the next window only, it would not


def test_the_bootstrap_interval_brackets_the_median_of_a_sample():
    values = np.random.default_rng(1).normal(0.03, 0.1, 400)
    low, high = bringup.bootstrap_90(values, np.median)
    assert low < np.median(values) < high and high - low < 0.05


class _Publisher:
    def __init__(self, topic):
        self.topic_name, self.sent = topic, []

    def publish(self, data):
        self.sent.append(data)


def _stamped(stamp_ns: int) -> bytes:
    return b"\x00\x01\x00\x00" + struct.pack("<iI", *divmod(stamp_ns, 1_000_000_000)) + b"rest"


def test_the_gate_taps_only_the_messages_of_even_windows(monkeypatch):
    monkeypatch.setattr(TappedPublisher, "publish", TappedPublisher.publish)    # restored afterwards
    steps = gate.install(window_ns=3_000_000, log_dir=None)
    streams = StreamTap()
    state = TappedPublisher(_Publisher("/pkm/drives/state"), streams, "sensor_msgs/msg/JointState", lambda: 7)
    pose = TappedPublisher(_Publisher("/pkm/metrology/pose"), streams, "geometry_msgs/msg/PoseStamped", lambda: 7)
    for k in range(10):                                     # 1 ms steps, windows of 3
        state.publish(_stamped(k * 1_000_000))
        pose.publish(_stamped(k * 1_000_000))
    assert len(state.publisher.sent) == len(pose.publisher.sent) == 10             # everything published
    tapped = [(topic, struct.unpack_from("<iI", data, 4)[1] // 1_000_000) for topic, _, _, data in
              read_batch(streams.take_batch())]
    assert [k for topic, k in tapped if topic == "/pkm/drives/state"] == [0, 1, 2, 6, 7, 8]
    assert [k for topic, k in tapped if topic == "/pkm/metrology/pose"] == [0, 1, 2, 6, 7, 8]
    assert [s for s, _ in steps] == [k * 1_000_000 for k in range(10)]             # drives/state: every step
    assert all(b >= a for (_, a), (_, b) in zip(steps, steps[1:]))


def test_the_gate_is_off_without_its_environment(monkeypatch):
    monkeypatch.delenv("PKM_TAP_WINDOW_NS", raising=False)
    original = TappedPublisher.publish
    _load("pkm_benchmarks_window_gate_again", BENCHMARKS / "window_gate" / "sitecustomize.py")
    assert tap.TappedPublisher.publish is original
