"""Bringup benchmark: what recording costs the closed loop, and recorder throughput.

1. The default scenario (archi_demo: ARCHI test motion, Gough in the loop, sensor
   space + inf-norm) as five processes, with and without the recorder, alternated
   ``--repeats`` times: lockstep rate (sim_hw steps per wall second) and the recording
   cost as a fraction of the loop period, and the same in one process.
2. Recorder throughput: BagWriter.write alone (JointState-sized CDR, zstd chunks), and
   the recorder node end to end in the runs above (messages recorded per wall second).

Usage: python benchmarks/bringup.py [--scenario archi_demo] [--repeats 2] [--duration-s 0]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path


def run_once(scenario: str, record: bool, in_process: bool, duration_s: float) -> dict:
    from pkm_bringup.orchestrator import run_scenario
    from pkm_bringup.scenario import load_scenario
    overrides = {"record": record}
    if duration_s:
        overrides["duration_s"] = duration_s
    s = load_scenario(scenario, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        run = run_scenario(s, Path(tmp) / "run", in_process=in_process, progress=False, report=False)
    if run["status"] != "completed":
        raise RuntimeError(run["error"])
    sim = run["summaries"]["sim_hw"]
    recorder = run["summaries"].get("recorder", {})
    return {"rate": sim["steps_per_s"], "wall_s": sim["wall_s"],
            "recorded": sum(recorder.get("recorded", {}).values()),
            "lost": sum(max(v, 0) for v in run["lost"].values())}


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
        with BagWriter(Path(tmp) / "bag") as writer:
            channel = writer.add_topic("/pkm/drives/state", "sensor_msgs/msg/JointState")
            start = time.perf_counter()
            for i in range(messages):
                writer.write(channel, i, data)
                if i % 500 == 0:
                    writer.flush()
            elapsed = time.perf_counter() - start
    return messages / elapsed, len(data)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="archi_demo")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--duration-s", type=float, default=0.0, help="override (0: the scenario's)")
    args = parser.parse_args(argv)

    rate, size = writer_throughput()
    print(f"BagWriter.write: {rate:,.0f} messages/s ({size}-byte JointState, zstd chunks, flush every 500)")
    print()
    print(f"{args.scenario}: lockstep rate (steps/s), {args.repeats} alternated runs per row")
    print("| mode | recording | steps/s (runs) | median | loop period | recorded msgs/s | lost |")
    print("|---|---|---|---|---|---|---|")
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
            print(f"| {mode} | {'on' if record else 'off'} | {', '.join(f'{x:.0f}' for x in rates)} | {median:.0f} | "
                  f"{1e6 / median:.0f} us | {thru:,.0f} | {lost if record else '-'} |")
    print()
    for in_process in (False, True):
        off, on = results[(in_process, False)], results[(in_process, True)]
        cost = (1.0 / on - 1.0 / off) * off
        print(f"recording cost ({'in-process' if in_process else 'processes'}): {cost * 100:+.1f} % of the loop "
              f"period (target <= 5 %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
