"""Bringup benchmark: what recording costs the closed loop, and recorder throughput.

1. The default scenario (archi_demo: ARCHI test motion, Gough in the loop, sensor
   space + inf-norm) as five processes, with and without the recorder, alternated
   ``--repeats`` times: lockstep rate (sim_hw steps per wall second) and the recording
   cost as a fraction of the loop period, and the same in one process.
2. Recorder throughput: BagWriter.write alone (JointState-sized CDR, lz4 chunks, as the recorder writes), and
   the recorder node end to end in the runs above (messages recorded per wall second).
3. The recorder process's CPU per tapped message (fed archi_demo-like tap batches of
   25 steps, the taps' former 50 ms, and of 200, their 0.2 s).
4. The recording cost inside one run, as processes and in one process: the taps
   record in one window of 1000 loop steps in three (``alternating_windows``).
   Alternated runs of one configuration differ by up to 20 % on this VM, so rates (1.)
   cannot show a few per cent; neighbouring windows share the VM's slow phases.
   Printed: per run the median cost of its cycles; over all cycles of
   ``--window-runs`` runs the median and the ratio of the sums, each with the 90 %
   interval of a two-stage bootstrap (runs, then cycles). Then the same cycles in CPU
   time, per process (``cpu_costs``): the extra CPU per recorded step, and their sum
   as a share of the loop period.

Usage: python benchmarks/bringup.py [--scenario archi_demo] [--repeats 2] [--duration-s 0] [--window-runs 2]
       [--windows-only] [--window-modes both|processes|in-process] [--window-length-s 0]
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
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


GATE_DIR = Path(__file__).resolve().parent / "window_gate"


def alternating_windows(scenario: str, duration_s: float, in_process: bool, window_steps: int = 1000) -> dict:
    """The recording cost measured inside one run, so that this VM's slow phases (the
    same code runs up to 1.5-2x slower for seconds to minutes, with or without steal)
    fall on both sides alike: the taps record in one window of ``window_steps`` loop
    steps of simulated time in three and are silent in the others
    (``window_gate/sitecustomize.py``: in the node processes through their PYTHONPATH,
    or installed in this one); the recorder runs throughout. Returns the per-cycle
    costs of :func:`window_costs`, the median clean step period and the run's CPU steal."""
    from pkm_bringup.scenario import load_scenario
    spec = importlib.util.spec_from_file_location("window_gate", GATE_DIR / "sitecustomize.py")
    gate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gate)
    window_ns = int(round(window_steps * load_scenario(scenario).dt_s * 1e9))
    with tempfile.TemporaryDirectory() as logs:
        saved = {k: os.environ.pop(k, None) for k in ("PYTHONPATH", "PKM_TAP_WINDOW_NS", "PKM_TAP_WINDOW_LOG")}
        publish = None
        try:
            if in_process:
                from pkm_recording import tap
                publish = tap.TappedPublisher.publish
                steps, marks = gate.install(window_ns, None)
                cpu_marks = {"in-process": marks}
            else:
                os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(GATE_DIR), saved["PYTHONPATH"]]))
                os.environ["PKM_TAP_WINDOW_NS"], os.environ["PKM_TAP_WINDOW_LOG"] = str(window_ns), logs
            run = run_once(scenario, True, in_process, duration_s)
        finally:
            if publish is not None:
                tap.TappedPublisher.publish = publish
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        if not in_process:
            files = list(Path(logs).glob("*.txt"))
            if len(files) != 1:
                raise RuntimeError(f"alternating_windows: {len(files)} step logs from the node processes, expected 1")
            steps = _pairs(files[0].read_text().splitlines())
            cpu_marks = {}
            for path in sorted(Path(logs).glob("*.cpu")):
                module, *lines = path.read_text().splitlines()
                cpu_marks[module.rpartition(".")[2]] = _pairs(lines)
            for path in Path(logs).glob("*.rec"):
                cpu_marks["recorder_node"] = marks_from_samples(_pairs(path.read_text().splitlines()), steps,
                                                                window_ns)
    if run["lost"] < run["recorded"]:      # 2 in 3 of the tapped messages are never recorded
        raise RuntimeError(f"alternating_windows: the gate did not act ({run['recorded']} messages recorded, "
                           f"{run['lost']} not)")
    extra, clean, period_s, cycles = window_costs(steps, window_ns, window_steps // 2, gate.CYCLE)
    cpu = {name: cpu_costs(window_cpu(marks), window_steps, cycles) for name, marks in cpu_marks.items()}
    return {"extra": extra, "clean": clean, "period_us": period_s * 1e6, "steal": run["steal"], "cpu": cpu}


def _pairs(lines) -> list[tuple[int, int]]:
    return [tuple(map(int, line.split())) for line in lines if line.strip()]


def window_costs(steps, window_ns: int, min_steps: int, cycle: int = 3):
    """(extra, clean, clean period s, cycles) per cycle of windows of ``window_ns`` simulated
    time: recording (w % cycle == 0), draining (w + 1: the recording's deferred work
    lands there), clean. ``extra``: the recording and draining windows' mean step
    periods minus two clean ones'; ``clean``: the mean of the clean windows before and
    after (w - 1 and w + 2, centred on the other two: a linear drift of the VM's
    speed cancels). A cycle's cost, as a share of the loop period per recorded step,
    is extra / clean. From the (stamp ns, perf_counter ns) of every step; each period
    belongs to the step it starts from (the period after the state of step k holds
    that step's sensor and controller work). Windows with fewer than ``min_steps``
    steps (the ends of the run) are left out. Also the median clean window's period,
    and the cycles by their recording window."""
    import numpy as np
    stamps, times = np.array(sorted(steps), dtype=np.int64).T
    periods, window = np.diff(times) * 1e-9, stamps[:-1] // window_ns
    means = {int(w): periods[window == w].mean() for w in np.unique(window)
             if np.count_nonzero(window == w) >= min_steps}
    extra, clean, cycles = [], [], []
    for w in sorted(means):
        if w % cycle == 0 and all(v in means for v in (w - 1, w + 1, w + 2)):
            reference = 0.5 * (means[w - 1] + means[w + 2])
            extra.append(means[w] + means[w + 1] - 2.0 * reference)
            clean.append(reference)
            cycles.append(w)
    return (np.array(extra), np.array(clean), float(np.median([means[w] for w in means if w % cycle == cycle - 1])),
            cycles)


def window_cpu(marks) -> dict[int, float]:
    """CPU seconds of a process in each window, from its (window, process CPU ns)
    marks at its first tapped message of each window: the mark of w + 1 minus w's."""
    at = dict(marks)
    return {w: (at[w + 1] - at[w]) * 1e-9 for w in at if w + 1 in at}


def cpu_costs(cpu: dict[int, float], window_steps: int, cycles):
    """Per cycle (its recording window w), a process's extra CPU seconds per recorded
    step: the recording and draining windows' CPU minus the clean ones' before and
    after (w - 1, w + 2), over ``window_steps``; NaN where a window is missing. The
    CPU-time view of :func:`window_costs`: it holds no preemption or waiting, but the
    VM's slow phases change it too, so it is hardly less noisy (session 11)."""
    import numpy as np
    return np.array([(cpu[w] + cpu[w + 1] - cpu[w - 1] - cpu[w + 2]) / window_steps
                     if all(v in cpu for v in (w - 1, w, w + 1, w + 2)) else np.nan for w in cycles])


def marks_from_samples(samples, steps, window_ns: int) -> list[tuple[int, float]]:
    """(window, CPU ns) marks of a process sampled as (perf_counter ns, CPU ns), at
    the wall time of each window's first loop step (sim_hw's (stamp ns,
    perf_counter ns)): the recorder publishes nothing tapped to mark its windows."""
    import numpy as np
    t, cpu = np.array(sorted(samples), dtype=np.float64).T
    stamps, times = np.array(sorted(steps), dtype=np.int64).T
    windows, first = np.unique(stamps // window_ns, return_index=True)
    inside = (times[first] >= t[0]) & (times[first] <= t[-1])
    return [(int(w), float(c)) for w, c in zip(windows[inside], np.interp(times[first][inside], t, cpu))]


def two_stage_bootstrap_90(runs, statistic, draws: int = 5000) -> tuple[float, float]:
    """The 5th and 95th percentiles of ``statistic(extra, clean)`` over two-stage
    resamples: the runs with replacement, then the cycles within each drawn run. The
    runs differ by more than their cycles do (the VM's phases last minutes), so
    resampling cycles alone gives too narrow an interval; and adjacent cycles share a
    clean window, which the runs as units also cover."""
    import numpy as np
    rng = np.random.default_rng(0)
    samples = np.empty(draws)
    for d in range(draws):
        extra, clean = [], []
        for k in rng.integers(0, len(runs), len(runs)):
            e, c = runs[k]
            i = rng.integers(0, len(e), len(e))
            extra.append(e[i])
            clean.append(c[i])
        samples[d] = statistic(np.concatenate(extra), np.concatenate(clean))
    return tuple(float(x) for x in np.percentile(samples, [5, 95]))


def writer_throughput(messages: int = 200_000) -> tuple[float, int]:
    from pkm_recording.bag import BagWriter
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

    from pkm_bringup.graph import init_context
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

    from pkm_recording.bag import read_counts
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


def recorder_cpu_per_tapped_message(batches: int = 50, steps: int = 200, depth: int = 50) -> tuple[float, int, int]:
    """recorder_node in its own process, fed tap batches like archi_demo's (7 topics
    of 96-200 bytes, ``steps`` steps a batch: 200 at 1 kHz and the taps' 0.2 s; one
    batch every 0.4 ms x ``steps``) from this process: the recorder's
    CPU time (user + system, all its threads, from /proc) per message recorded. Unlike
    a rate it hardly depends on what else the VM runs. Returns (us per message,
    recorded, sent). ``depth``: the tap publisher's history (TAP_QOS keeps 50 batches,
    10 s at 0.2 s; it kept 200 when the taps batched every 50 ms)."""
    import copy
    import json

    from sensor_msgs.msg import JointState
    from std_msgs.msg import UInt8MultiArray

    from pkm_common.qos import STREAM_PUBLISHER_QOS, TAP_QOS
    from pkm_recording.tap import TAP_TOPIC, StreamTap

    def cpu_s(pid: int) -> float:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    qos = copy.copy(TAP_QOS)
    qos.depth = depth

    def publishers(node):   # the tap, and the streams it stands for (the recorder discovers their types)
        return ([node.create_publisher(UInt8MultiArray, TAP_TOPIC, qos)]
                + [node.create_publisher(JointState, t, STREAM_PUBLISHER_QOS) for t in topics])

    topics, sizes = [f"/bench/stream{i}" for i in range(7)], (120, 200, 96, 150, 180, 110, 90)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with recorder_beside(tmp, "bench_tap", {"tapped_topics": ",".join(topics)}, publishers) as (pubs, recorder):
            time.sleep(1.0)
            tap, step, start = StreamTap(), 0, cpu_s(recorder.popen.pid)
            for _ in range(batches):
                for _ in range(steps):
                    step += 1
                    for topic, size in zip(topics, sizes):       # a header stamp at bytes 4-12
                        data = b"\x00\x01\x00\x00" + step.to_bytes(4, "little") + bytes(size - 8)
                        tap.add(topic, "sensor_msgs/msg/JointState", data, time.time_ns())
                pubs[0].publish(tap.take_batch())
                time.sleep(0.0004 * steps)
            time.sleep(1.5)
            used = cpu_s(recorder.popen.pid) - start
        recorded = sum(json.loads((tmp / "rec.json").read_text())["recorded"].get(t, 0) for t in topics)
        return used * 1e6 / max(recorded, 1), recorded, batches * steps * len(topics)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="archi_demo")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--duration-s", type=float, default=0.0, help="override (0: the scenario's)")
    parser.add_argument("--window-runs", type=int, default=2, help="runs per mode of the alternating windows")
    parser.add_argument("--windows-only", action="store_true", help="only the in-run measurement (4.)")
    parser.add_argument("--window-modes", choices=("both", "processes", "in-process"), default="both",
                        help="the modes of the in-run measurement")
    parser.add_argument("--window-length-s", type=float, default=0.0,
                        help="simulated length of each in-run measurement (0: 90 s as processes, 60 s in one "
                             "process; at least 3 windows of 1000 steps)")
    args = parser.parse_args(argv)
    if not args.windows_only:
        throughput_and_rates(args)
    windows(args)
    return 0


def throughput_and_rates(args) -> None:
    rate, size = writer_throughput()
    print(f"BagWriter.write: {rate:,.0f} messages/s ({size}-byte JointState, lz4 chunks, flush every 500)")
    pub_rate, rec_rate, lost = recorder_throughput()
    print(f"recorder_node (own process), 20,000 JointState published at {pub_rate:,.0f}/s: recorded at "
          f"{rec_rate:,.0f} messages/s, lost {lost}")
    for batches, steps, depth in ((400, 25, 200), (50, 200, 50)):
        us, recorded, sent = recorder_cpu_per_tapped_message(batches, steps, depth)
        print(f"recorder_node (own process) fed tap batches of {steps} steps: {us:.2f} us of its CPU per message "
              f"({recorded:,} of {sent:,} recorded)")
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


def windows(args) -> None:
    import numpy as np
    modes = {"both": (False, True), "processes": (False,), "in-process": (True,)}[args.window_modes]
    results = [(in_process, length_s, [alternating_windows(args.scenario, length_s, in_process)
                                       for _ in range(args.window_runs)])
               for in_process, length_s in ((False, args.window_length_s or 90.0), (True, args.window_length_s or 60.0))
               if in_process in modes]
    print()
    print(f"{args.scenario}: recording cost inside one run, the taps recording in one window of 1000 steps in "
          f"three ({args.window_runs} runs per mode; per cycle, the extra time of the recording and draining "
          f"windows over two clean ones, per recorded step; 90 % intervals of a two-stage bootstrap: runs, "
          f"then cycles)")
    print("| mode | run length | cycles | clean step period (runs) | CPU steal % (runs) | median per run | "
          "median | ratio of sums |")
    print("|---|---|---|---|---|---|---|---|")
    for in_process, length_s, runs in results:
        extra, clean = np.concatenate([r["extra"] for r in runs]), np.concatenate([r["clean"] for r in runs])
        costs = extra / clean
        pairs = [(r["extra"], r["clean"]) for r in runs]
        mlo, mhi = two_stage_bootstrap_90(pairs, lambda e, c: np.median(e / c))
        sums = two_stage_bootstrap_90(pairs, lambda e, c: e.sum() / c.sum())
        per_run = ", ".join(f"{np.median(r['extra'] / r['clean']) * 100:+.1f}" for r in runs)
        periods = ", ".join(f"{r['period_us']:.0f}" for r in runs)
        steals = ", ".join("n/a" if r["steal"] is None else f"{r['steal']:.1f}" for r in runs)
        print(f"| {'in-process' if in_process else 'processes'} | {length_s:.0f} s | {len(costs)} | {periods} us | "
              f"{steals} | {per_run} % | {np.median(costs) * 100:+.1f} % [{mlo * 100:+.1f}, {mhi * 100:+.1f}] | "
              f"{extra.sum() / clean.sum() * 100:+.1f} % [{sums[0] * 100:+.1f}, {sums[1] * 100:+.1f}] |")
    print()
    print("The same cycles in CPU time (cpu_costs): each process's extra CPU per recorded step, and as a share of "
          "the clean step period (ratio of sums; 90 % two-stage bootstrap intervals). 'all' adds them up: the cost "
          "if every microsecond of it delayed the loop")
    print("| mode | process | extra CPU per recorded step: median | share of the clean period |")
    print("|---|---|---|---|")
    for in_process, _, runs in results:
        names = sorted(set().union(*(r["cpu"] for r in runs)))
        for name in names + (["all"] if len(names) > 1 else []):       # one process: 'all' is that row
            pairs = []
            for r in runs:
                if name == "all":
                    if not all(n in r["cpu"] for n in names):
                        continue
                    extra = np.sum([r["cpu"][n] for n in names], axis=0)
                else:
                    extra = r["cpu"].get(name, np.full(len(r["clean"]), np.nan))
                keep = np.isfinite(extra)
                if keep.any():
                    pairs.append((extra[keep], r["clean"][keep]))
            if not pairs:
                continue
            e, c = np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])
            mlo, mhi = two_stage_bootstrap_90(pairs, lambda e, c: np.median(e))
            lo, hi = two_stage_bootstrap_90(pairs, lambda e, c: e.sum() / c.sum())
            print(f"| {'in-process' if in_process else 'processes'} | {name} | {np.median(e) * 1e6:.1f} us "
                  f"[{mlo * 1e6:.1f}, {mhi * 1e6:.1f}] | {e.sum() / c.sum() * 100:+.2f} % "
                  f"[{lo * 100:+.2f}, {hi * 100:+.2f}] |")


if __name__ == "__main__":
    sys.exit(main())
