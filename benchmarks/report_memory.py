"""Report benchmark: peak memory and wall time of the run report against the run's length.

A synthetic ARCHI run is recorded with the project's own writer (``pkm_recording.bag.BagWriter``,
the per-step messages encoded with ``pkm_common.cdr`` as the nodes encode them): at
``--rate-hz`` the seven per-step streams of the graph (``/clock``, ``drives/state``,
``platform/true_pose``, ``metrology/struts``, ``metrology/pose``, ``drives/command``,
``controller/reference``), plus ``controller/status`` at 10 Hz and sim_hw's
``diagnostics`` at 1 Hz, with a ``run.json`` naming the machine and the published
counts. The report (``write_report``: metrics.json and the four figures) then runs in a
fresh Python process, which prints its own peak resident set size (``getrusage``
ru_maxrss) and wall time.

Printed: one row per simulated length: messages in the bag, bag size, seconds to write
it, the report's peak RSS (MiB) and seconds. Most of a short run's RSS is the report's
imports (scipy through pkm_kinematics, matplotlib, rosbags); what grows with the run's
length is what the report keeps of it.

``--report-module PATH`` reports with another copy of the report module (e.g. an older
one: ``git show <rev>:src/pkm_runs/pkm_runs/report.py > /tmp/report_old.py``),
loaded by path; it must provide ``write_report(run_dir)``.

Usage: python benchmarks/report_memory.py [--seconds 60 600] [--rate-hz 1000] [--report-module PATH]
       [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

NS = "/pkm"
WALL0_NS = 1_700_000_000 * 10**9     # log times: the recorder's clock
WALL_PER_STEP = 1.25                  # wall ns per simulated ns (a loop at 0.8 x real time)
STATUS_HZ, DIAGNOSTICS_HZ = 10.0, 1.0
STRUTS = 6                            # Gough metrology struts
FLUSH_STEPS = 500                     # the recorder flushes every ~0.5 s

STEP_TOPICS = {  # suffix -> message type, in the order one step publishes them
    "/clock": "rosgraph_msgs/msg/Clock",
    f"{NS}/drives/state": "sensor_msgs/msg/JointState",
    f"{NS}/platform/true_pose": "geometry_msgs/msg/PoseStamped",
    f"{NS}/metrology/struts": "sensor_msgs/msg/JointState",
    f"{NS}/metrology/pose": "geometry_msgs/msg/PoseStamped",
    f"{NS}/drives/command": "sensor_msgs/msg/JointState",
    f"{NS}/controller/reference": "geometry_msgs/msg/PoseStamped",
}
DIAGNOSTIC_TOPICS = {f"{NS}/controller/status": "diagnostic_msgs/msg/DiagnosticArray",
                     f"{NS}/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}

# the child: reports a run directory and prints {"peak_rss_mb", "seconds"} as its last line
_CHILD = """\
import importlib.util, json, resource, sys, time
run_dir, module = sys.argv[1], sys.argv[2]
start = time.perf_counter()
if module:
    spec = importlib.util.spec_from_file_location("report_under_test", module)
    report = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = report            # dataclasses look their module up
    spec.loader.exec_module(report)
else:
    from pkm_runs import report
report.write_report(run_dir)
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "seconds": time.perf_counter() - start}))
"""


def _diagnostic_array(typestore, stamp_ns: int, name: str, level: int, message: str, values: dict) -> bytes:
    t = typestore.types
    status = t["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level, name=name, message=message, hardware_id="",
        values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=str(v)) for k, v in values.items()])
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9,
                                                                              nanosec=stamp_ns % 10**9), frame_id="")
    msg = t["diagnostic_msgs/msg/DiagnosticArray"](header=header, status=[status])
    return typestore.serialize_cdr(msg, "diagnostic_msgs/msg/DiagnosticArray")


def write_synthetic_run(run_dir, duration_s: float, rate_hz: float = 1000.0) -> dict:
    """Record a synthetic ARCHI run of ``duration_s`` simulated seconds at ``rate_hz`` into
    ``run_dir`` (``bag/`` and ``run.json``; the directory must not hold a bag). The tool
    follows a circle of 20 mm radius, one turn every 4 s, with a 5 um error; the drive forces
    are smooth with one spike. Returns {"messages", "bag_bytes", "seconds"}."""
    from rosbags.typesys import Stores, get_typestore

    from pkm_recording.bag import BagWriter, qos_profile
    from pkm_common.cdr import JointStateEncoder, PoseStampedEncoder, encode_clock

    start = time.perf_counter()
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    steps = int(round(duration_s * rate_hz))
    dt_ns = int(round(1e9 / rate_hz))
    drives = ["q1", "q2", "q3", "q4"]
    state_enc = JointStateEncoder(drives)
    command_enc = JointStateEncoder(drives, fields=("effort",))
    struts_enc = JointStateEncoder([f"s{k + 1}" for k in range(STRUTS)], fields=("position",))
    pose_enc = PoseStampedEncoder("world")
    published = dict.fromkeys(list(STEP_TOPICS) + list(DIAGNOSTIC_TOPICS), 0)
    status_every = max(1, int(round(rate_hz / STATUS_HZ)))
    diagnostics_every = max(1, int(round(rate_hz / DIAGNOSTICS_HZ)))
    with BagWriter(run_dir / "bag", compression="zstd") as writer:
        reliable = [qos_profile("reliable", "volatile", 10)]
        ids = {topic: writer.add_topic(topic, msgtype, reliable)
               for topic, msgtype in {**STEP_TOPICS, **DIAGNOSTIC_TOPICS}.items()}
        block = 2000
        for first in range(0, steps, block):
            k = np.arange(first, min(first + block, steps))
            t = k / rate_hz
            phase = 2.0 * math.pi * t / 4.0
            ref = np.column_stack([1.0 + 0.02 * np.cos(phase), -0.4 + 0.02 * np.sin(phase),
                                   0.785 + 0.1 * np.sin(phase)])
            true = ref + [5e-6, -3e-6, 2e-6]
            q = np.column_stack([np.sin(phase + j) * 0.1 + 0.5 for j in range(4)])
            forces = np.column_stack([200.0 * np.sin(phase + j) + 40.0 * (-1) ** j for j in range(4)])
            forces[k == steps // 3, 2] = 1234.0                          # one spike the plots must keep
            struts = np.column_stack([0.8 + 0.01 * np.sin(phase + j) for j in range(STRUTS)])
            half = true[:, 2] / 2.0
            quat_true = np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)])
            half = ref[:, 2] / 2.0
            quat_ref = np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)])
            rows = zip(k.tolist(), q.tolist(), forces.tolist(), struts.tolist(), true.tolist(), quat_true.tolist(),
                       ref.tolist(), quat_ref.tolist())
            for step, q_k, f_k, s_k, x_k, o_k, r_k, p_k in rows:
                stamp = step * dt_ns
                wall = WALL0_NS + int(stamp * WALL_PER_STEP)
                writer.write(ids["/clock"], wall, encode_clock(stamp))
                writer.write(ids[f"{NS}/drives/state"], wall + 1000, state_enc.encode(stamp, q_k, [0.0] * 4, f_k))
                writer.write(ids[f"{NS}/platform/true_pose"], wall + 2000,
                             pose_enc.encode(stamp, (x_k[0], x_k[1], 0.0), o_k))
                writer.write(ids[f"{NS}/metrology/struts"], wall + 3000, struts_enc.encode(stamp, s_k))
                writer.write(ids[f"{NS}/metrology/pose"], wall + 4000,
                             pose_enc.encode(stamp, (x_k[0], x_k[1], 0.0), o_k))
                writer.write(ids[f"{NS}/drives/command"], wall + 50_000, command_enc.encode(stamp, effort=f_k))
                writer.write(ids[f"{NS}/controller/reference"], wall + 51_000,
                             pose_enc.encode(stamp, (r_k[0], r_k[1], 0.0), p_k))
                if step % status_every == 0:
                    writer.write(ids[f"{NS}/controller/status"], wall + 52_000, _diagnostic_array(
                        typestore, stamp, "controller", 0, "tracking",
                        {"mode": "tracking", "cycles": step + 1, "cause": "none"}))
                    published[f"{NS}/controller/status"] += 1
                if step % diagnostics_every == 0:
                    writer.write(ids[f"{NS}/diagnostics"], wall + 53_000, _diagnostic_array(
                        typestore, stamp, "sim_hw", 0, "running",
                        {"step": step, "deadline_misses": 0, "cause": "none"}))
                    published[f"{NS}/diagnostics"] += 1
                if step % FLUSH_STEPS == FLUSH_STEPS - 1:
                    writer.flush()
        for topic in STEP_TOPICS:
            published[topic] = steps
        messages = writer.message_count
    (run_dir / "run.json").write_text(json.dumps({"scenario": "synthetic", "machine": "archi", "namespace": NS,
                                                  "published": published}), encoding="utf-8")
    size = sum(f.stat().st_size for f in (run_dir / "bag").iterdir())
    return {"messages": messages, "bag_bytes": size, "seconds": time.perf_counter() - start}


def report_in_subprocess(run_dir, report_module=None, timeout_s: float = 3600.0) -> dict:
    """Report ``run_dir`` in a fresh Python process: {"peak_rss_mb", "seconds"} (its own
    peak RSS in MiB and the wall time of write_report, imports included)."""
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(run_dir), str(report_module or "")],
                          capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0:
        raise RuntimeError(f"report of {run_dir} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, nargs="+", default=[60.0, 600.0],
                        help="simulated lengths of the synthetic runs (default: 60 600)")
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--report-module", help="path of another report module to measure (default: the installed one)")
    parser.add_argument("--keep", help="write the runs here (kept) instead of a temporary directory")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        print(f"report: {args.report_module or 'pkm_runs.report'}; {args.rate_hz:g} Hz, "
              f"{len(STEP_TOPICS)} per-step streams")
        print(f"{'sim s':>7} {'steps':>8} {'messages':>9} {'bag MB':>7} {'write s':>8} {'peak RSS MiB':>12} "
              f"{'report s':>9}")
        for seconds in args.seconds:
            run_dir = root / f"synthetic_{seconds:g}s"
            written = write_synthetic_run(run_dir, seconds, args.rate_hz)
            measured = report_in_subprocess(run_dir, args.report_module)
            print(f"{seconds:7g} {int(round(seconds * args.rate_hz)):8d} {written['messages']:9d} "
                  f"{written['bag_bytes'] / 1e6:7.1f} {written['seconds']:8.1f} {measured['peak_rss_mb']:12.0f} "
                  f"{measured['seconds']:9.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
