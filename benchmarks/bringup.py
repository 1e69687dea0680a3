"""Bringup benchmark: what recording costs the closed loop, and recorder throughput.

1. The default scenario (archi_demo: ARCHI test motion, Gough in the loop, sensor
   space + inf-norm) as five processes, with and without the recorder, alternated
   ``--repeats`` times: lockstep rate (sim_hw steps per wall second) and the recording
   cost as a fraction of the loop period, and the same in one process.
2. Recorder throughput: BagWriter.write alone (JointState-sized CDR, lz4 chunks, as the recorder writes), and
   the recorder node end to end in the runs above (messages recorded per wall second).
3. The recorder process's CPU per tapped message (fed archi_demo-like tap batches).
4. The in-process recording cost inside one run, recording and silent windows
   alternated (``alternating_windows``, 200-step windows over a 20 s run): alternated
   runs of the same configuration differ by up to 20 % on this VM; adjacent windows
   share its slow phases, and the median over ~50 pairs is steadier (+-3 %).

Usage: python benchmarks/bringup.py [--scenario archi_demo] [--repeats 2] [--duration-s 0]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hoststat import CpuSteal  # noqa: E402  (benchmarks/hoststat.py)


def run_once(scenario: str, record: bool, in_process: bool, duration_s: float) -> dict:
    from pkm_bringup.orchestrator import run_scenario
    from pkm_bringup.scenario import load_scenario
    overrides = {"record": record}
    if duration_s:
        overrides["duration_s"] = duration_s
    s = load_scenario(scenario, overrides)
    with tempfile.TemporaryDirectory() as tmp, CpuSteal() as steal:
        run = run_scenario(s, Path(tmp) / "run", in_process=in_process, progress=False, report=False)
    if run["status"] != "completed":
        raise RuntimeError(run["error"])
    sim = run["summaries"]["sim_hw"]
    recorder = run["summaries"].get("recorder", {})
    return {"rate": sim["steps_per_s"], "wall_s": sim["wall_s"],
            "recorded": sum(recorder.get("recorded", {}).values()),
            "lost": sum(max(v, 0) for v in run["lost"].values()), "steal": steal.percent}


def alternating_windows(scenario: str, duration_s: float, window: int = 200) -> dict:
    """The in-process recording cost measured inside one run, so that this VM's slow
    phases (the same code runs up to 1.5-2x slower for seconds to minutes, without
    steal) fall on both sides alike: the taps record in every other window of
    ``window`` loop steps and are silent in the others (the benchmark gates
    ``TappedPublisher.publish`` and ``NodeTap.flush``; the recorder's own timers run
    throughout). Per pair of adjacent windows, the mean step period recording over the
    mean silent one; returns the median and the range of those ratios - 1."""
    import numpy as np

    from pkm_common import node_tap, tap
    from pkm_sim_hw.sim_hw_node import SimHwNode
    recording, stamps = [True], []
    publish, flush, advance = tap.TappedPublisher.publish, node_tap.NodeTap.flush, SimHwNode.advance

    def gated_publish(self, data):
        if recording[0]:
            publish(self, data)
        else:
            self.publisher.publish(data)

    def gated_flush(self):
        if recording[0]:
            flush(self)

    def timed_advance(self, effort):
        advance(self, effort)
        stamps.append(time.perf_counter())
        recording[0] = (len(stamps) // window) % 2 == 0

    tap.TappedPublisher.publish, node_tap.NodeTap.flush, SimHwNode.advance = gated_publish, gated_flush, timed_advance
    try:
        run = run_once(scenario, True, True, duration_s)
    finally:
        tap.TappedPublisher.publish, node_tap.NodeTap.flush, SimHwNode.advance = publish, flush, advance
    periods = np.diff(np.array(stamps))
    pairs = len(periods) // (2 * window)
    means = periods[:pairs * 2 * window].reshape(pairs, 2, window).mean(axis=2)
    ratios = means[1:, 0] / means[1:, 1] - 1.0           # the first pair: the start of the run
    return {"cost": float(np.median(ratios)), "low": float(ratios.min()), "high": float(ratios.max()),
            "pairs": len(ratios), "period_us": float(np.median(means[1:, 1]) * 1e6), "steal": run["steal"]}


def writer_throughput(messages: int = 200_000) -> float:
    from pkm_bringup.bag import BagWriter
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    js = store.types["sensor_msgs/msg/JointState"]
    header = store.types["std_msgs/msg/Header"](stamp=store.types["builtin_interfaces/msg/Time"](sec=1, nanosec=2),
                                                frame_id="")
    import numpy as np
    data = bytes(store.serialize_cdr(js(header=header, name=["q1", "q2", "q3", "q4"], position=np.ones(4),
                                        velocity=np.ones(4), effort=np.ones(4)), "sensor_msgs/msg/JointState"))
    with tempfile.TemporaryDirectory() as tmp:
        with BagWriter(Path(tmp) / "bag", compression="lz4") as writer:
            channel = writer.add_topic("/pkm/drives/state", "sensor_msgs/msg/JointState")
            start = time.perf_counter()
            for i in range(messages):
                writer.write(channel, i, data)
                if i % 500 == 0:
                    writer.flush()
            elapsed = time.perf_counter() - start
    return messages / elapsed, len(data)


@contextlib.contextmanager
def recorder_beside(tmp: Path, node_name: str, recorder_params: dict, make_publishers):
    """recorder_node in its own process (``recorder_params`` plus its output, ready
    file and summary in ``tmp``) and a node of this process whose publishers
    ``make_publishers(node)`` creates (before the recorder starts, so that it discovers
    them); yields (publishers, recorder process) once the recorder is ready, and stops
    both at the end."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    from pkm_bringup.orchestrator import init_context
    from pkm_bringup.processes import start_node, stop_nodes, use_ros_environment
    from pkm_bringup.scenario import params_file_text
    env = use_ros_environment()
    (tmp / "logs").mkdir()
    params = tmp / "recorder.yaml"
    params.write_text(params_file_text({"output": str(tmp / "bag"), "ready_file": str(tmp / "ready"),
                                        "summary_path": str(tmp / "rec.json"), **recorder_params}))
    context = init_context()
    node = rclpy.create_node(node_name, namespace="/bench", context=context)
    publishers = make_publishers(node)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    recorder = start_node("recorder", "/bench", params, tmp / "logs", env)
    try:
        deadline = time.monotonic() + 60
        while not (tmp / "ready").exists() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        yield publishers, recorder
    finally:
        stop_nodes([recorder])
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def recorder_throughput(messages: int = 20_000) -> tuple[float, float, int]:
    """recorder_node in its own process; this process publishes ``messages`` JointStates
    (RELIABLE, the graph's publisher history) as fast as it can. Returns (publish rate,
    recorded rate from the bag's first to last log time, messages lost)."""
    from rosbags.highlevel import AnyReader
    from sensor_msgs.msg import JointState

    from pkm_bringup.bag import read_counts
    from pkm_common.conversions import joint_state_msg
    from pkm_common.qos import STREAM_PUBLISHER_QOS
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with recorder_beside(tmp, "bench_publisher", {"expect_topics": "/bench/drives/state"},
                             lambda node: node.create_publisher(JointState, "drives/state", STREAM_PUBLISHER_QOS)
                             ) as (pub, _):
            msg = joint_state_msg(["q1", "q2", "q3", "q4"], 0, position=[1.0] * 4, velocity=[0.0] * 4,
                                  effort=[0.0] * 4)
            start = time.perf_counter()
            for i in range(messages):
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(i * 1_000_000, 1_000_000_000)
                pub.publish(msg)
            publish_rate = messages / (time.perf_counter() - start)
            time.sleep(2.0)
        with AnyReader([tmp / "bag"]) as reader:
            times = [t for _, t, _ in reader.messages()]
        recorded = read_counts(tmp / "bag").get("/bench/drives/state", 0)
        span = (max(times) - min(times)) * 1e-9 if len(times) > 1 else float("nan")
        return publish_rate, recorded / span, messages - recorded


def recorder_cpu_per_tapped_message(batches: int = 400) -> tuple[float, int, int]:
    """recorder_node in its own process, fed tap batches like archi_demo's (7 topics
    of 96-200 bytes, 25 steps a batch, every 10 ms) from this process: the recorder's
    CPU time (user + system, all its threads, from /proc) per message recorded. Unlike
    a rate it hardly depends on what else the VM runs. Returns (us per message,
    recorded, sent)."""
    import json

    from sensor_msgs.msg import JointState
    from std_msgs.msg import UInt8MultiArray

    from pkm_common.qos import STREAM_PUBLISHER_QOS, TAP_QOS
    from pkm_common.tap import TAP_TOPIC, StreamTap

    def cpu_s(pid: int) -> float:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def publishers(node):   # the tap, and the streams it stands for (the recorder discovers their types)
        return ([node.create_publisher(UInt8MultiArray, TAP_TOPIC, TAP_QOS)]
                + [node.create_publisher(JointState, t, STREAM_PUBLISHER_QOS) for t in topics])

    topics, sizes = [f"/bench/stream{i}" for i in range(7)], (120, 200, 96, 150, 180, 110, 90)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with recorder_beside(tmp, "bench_tap", {"tapped_topics": ",".join(topics)}, publishers) as (pubs, recorder):
            time.sleep(1.0)
            tap, step, start = StreamTap(), 0, cpu_s(recorder.popen.pid)
            for _ in range(batches):
                for _ in range(25):
                    step += 1
                    for topic, size in zip(topics, sizes):       # a header stamp at bytes 4-12
                        data = b"\x00\x01\x00\x00" + step.to_bytes(4, "little") + bytes(size - 8)
                        tap.add(topic, "sensor_msgs/msg/JointState", data, time.time_ns())
                pubs[0].publish(tap.take_batch())
                time.sleep(0.01)
            time.sleep(1.5)
            used = cpu_s(recorder.popen.pid) - start
        recorded = sum(json.loads((tmp / "rec.json").read_text())["recorded"].get(t, 0) for t in topics)
        return used * 1e6 / max(recorded, 1), recorded, batches * 25 * len(topics)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="archi_demo")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--duration-s", type=float, default=0.0, help="override (0: the scenario's)")
    args = parser.parse_args(argv)

    rate, size = writer_throughput()
    print(f"BagWriter.write: {rate:,.0f} messages/s ({size}-byte JointState, lz4 chunks, flush every 500)")
    pub_rate, rec_rate, lost = recorder_throughput()
    print(f"recorder_node (own process), 20,000 JointState published at {pub_rate:,.0f}/s: recorded at "
          f"{rec_rate:,.0f} messages/s, lost {lost}")
    us, recorded, sent = recorder_cpu_per_tapped_message()
    print(f"recorder_node (own process) fed tap batches: {us:.2f} us of its CPU per message ({recorded:,} of "
          f"{sent:,} recorded)")
    print()
    print(f"{args.scenario}: lockstep rate (steps/s), {args.repeats} alternated runs per row")
    print("| mode | recording | steps/s (runs) | CPU steal % (runs) | median | loop period | recorded msgs/s | lost |")
    print("|---|---|---|---|---|---|---|---|")
    results = {}
    for in_process in (False, True):
        rows = {False: [], True: []}
        for _ in range(args.repeats):
            for record in (False, True):
                rows[record].append(run_once(args.scenario, record, in_process, args.duration_s))
        mode = "in-process" if in_process else "processes"
        for record in (False, True):
            rates = [r["rate"] for r in rows[record]]
            median = statistics.median(rates)
            results[(in_process, record)] = median
            thru = statistics.median(r["recorded"] / r["wall_s"] for r in rows[record]) if record else 0.0
            lost = sum(r["lost"] for r in rows[record])
            steal = ", ".join("n/a" if r["steal"] is None else f"{r['steal']:.1f}" for r in rows[record])
            print(f"| {mode} | {'on' if record else 'off'} | {', '.join(f'{x:.0f}' for x in rates)} | {steal} "
                  f"| {median:.0f} | "
                  f"{1e6 / median:.0f} us | {thru:,.0f} | {lost if record else '-'} |")
    print()
    for in_process in (False, True):
        off, on = results[(in_process, False)], results[(in_process, True)]
        cost = (1.0 / on - 1.0 / off) * off
        print(f"recording cost ({'in-process' if in_process else 'processes'}): {cost * 100:+.1f} % of the loop "
              f"period (target <= 5 %)")
    w = alternating_windows(args.scenario, 20.0)
    print(f"recording cost (in-process, alternating {w['pairs']} pairs of 200-step windows in one run): "
          f"{w['cost'] * 100:+.1f} % of the {w['period_us']:.0f} us loop period (pairs {w['low'] * 100:+.1f} "
          f"to {w['high'] * 100:+.1f} %; CPU steal {w['steal']:.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
