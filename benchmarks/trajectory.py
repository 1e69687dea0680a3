"""Trajectory planning time: a 1,000-line G-code program and the ARCHI test motion.

    .venv/bin/python benchmarks/trajectory.py [--lines 1000] [--repeat 3]

Rows: parse only; parse + time law + sampling at 1 kHz; the same plus validation of
every sample against the machine model (IK, joint limits, joint velocity and
acceleration, conditioning); the ARCHI test motion (a translation while the nacelle
turns from pi/4 to pi/2, ARCHI §4) planned and validated; corner blending of the
program's line moves at 0.1 mm.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

from pkm_kinematics import load_machine
from pkm_kinematics.task_space import PLANAR
from pkm_trajectory.gcode import parse_gcode
from pkm_trajectory.planner import Limits, Line, plan, plan_blended, validate
from pkm_trajectory.program import gcode_segments

LIMITS = Limits(velocity=(0.5, 0.5, 2.0), acceleration=(5.0, 5.0, 20.0), jerk=(200.0, 200.0, 800.0))


def program(lines: int = 1000) -> str:
    """A square spiral of G1 moves with some arcs, around the ARCHI home, in mm."""
    out = ["G21 G90 G17", "G1 F3000 X1000 Y-400"]
    x, y = 1000.0, -400.0
    for k in range(lines - 3):
        if k % 10 == 9:
            out.append(f"G2 X{x:.3f} Y{y:.3f} I2 J0")          # a full circle of 2 mm radius
            continue
        step = 1.0 + (k % 7)
        dx, dy = [(step, 0), (0, step), (-step, 0), (0, -step)][k % 4]
        x, y = x + dx, y + dy
        out.append(f"G1 X{x:.3f} Y{y:.3f}")
    out.append("M2")
    return "\n".join(out)


def timed(fn, repeat=3):
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs), result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--lines", type=int, default=1000, help="lines of the G-code program (>= 20)")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    archi = load_machine("archi").model
    text = program(max(20, args.lines))
    start = archi.home.tolist()
    rows = []
    t, moves = timed(lambda: parse_gcode(text, start=(start[0], start[1], 0.0), start_angles=(0.0, 0.0, start[2])),
                     args.repeat)
    rows.append((f"parse {args.lines:,}-line G-code ({len(moves)} moves)", t * 1e3, "ms"))
    t, samples = timed(lambda: plan(gcode_segments(text, PLANAR, start), LIMITS, 1000.0, translation_axes=2),
                       args.repeat)
    rows.append((f"  + time law + 1 kHz sampling ({len(samples.time_s):,} samples, "
                 f"{samples.duration_s:.1f} s)", t * 1e3, "ms"))
    t, _ = timed(lambda: validate(samples, archi, 2.0, 50.0, 50.0), repeat=1)
    rows.append(("  validation of every sample (ARCHI model)", t * 1e3, "ms"))
    lines = [s for s in gcode_segments(text, PLANAR, start) if isinstance(s, Line)][:200]
    t, blended = timed(lambda: plan_blended(lines, LIMITS, 1e-4, 1000.0, translation_axes=2), repeat=1)
    rows.append(("blend 200 line moves at 0.1 mm", t * 1e3, "ms"))
    motion = [Line((1.0, -0.4, math.pi / 4), (1.1, -0.35, math.pi / 2))]
    t, s = timed(lambda: plan(motion, LIMITS, 1000.0, translation_axes=2), args.repeat)
    rows.append((f"ARCHI test motion: plan + sample ({len(s.time_s)} samples)", t * 1e3, "ms"))
    t, _ = timed(lambda: validate(s, archi, 2.0, 50.0, 50.0), args.repeat)
    rows.append(("ARCHI test motion: validation", t * 1e3, "ms"))
    width = max(len(r[0]) for r in rows)
    print(f"{'benchmark'.ljust(width)}  {'median':>10}  unit")
    print("-" * (width + 20))
    for name, value, unit in rows:
        print(f"{name.ljust(width)}  {value:>10.1f}  {unit}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
