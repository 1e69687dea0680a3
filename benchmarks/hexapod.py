"""Strut machines' forward kinematics against a compiled C Newton solve of the same
stream (issue 23's target: every warm FK within 5x of C).

    .venv/bin/python benchmarks/hexapod.py [--repeat N] [--readings N]

The stream: a 2 kHz motion (100 um and a few hundred microradians per reading) of
LinuxCNC's genhexkins hexapod and of MoM3's Gough metrology platform, each solve
warm-started from the previous pose. The C reference (benchmarks/c/strut_newton.c:
genhexkins' Newton iteration, the rotation updated on SO(3)) is built here with
``cc -O2`` and called once per stream through ctypes, so its per-reading time is the
solve's own. Ours (each reading from the pose extrapolated from the last two: one
Newton step where C, from the last pose, takes two): the same stream in one compiled
loop (``StrutFK.solve_stream``,
the batched form; ``GoughDKMSolver.solve_stream``, the metrology's chord solver), and
one Python call per reading (``StrutFK.solve``, ``GoughDKMSolver.solve``: what a
node pays per cycle), and for the Gough a batch of independent readings each from
the pose before it (``GoughPlatform.direct_kinematics_batch``: no state between
rows, one core). Printed: microseconds per
reading, the ratio to C, iterations per reading. Without a C compiler the C rows say
so and the others still print.
"""

from __future__ import annotations

import argparse
import ctypes
import math
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pkm_kinematics import GoughDKMSolver, load_machine
from pkm_kinematics.struts import StrutFK, StrutMachine
from pkm_kinematics.rotations import rotation_from_rpy

HERE = Path(__file__).resolve().parent


def build_c() -> ctypes.CDLL | None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    out = Path(tempfile.mkdtemp(prefix="pkm-bench-")) / "strut_newton.so"
    subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(out), str(HERE / "c" / "strut_newton.c"), "-lm"],
                   check=True)
    lib = ctypes.CDLL(str(out))
    dbl = ctypes.POINTER(ctypes.c_double)
    lib.solve_stream.argtypes = [dbl, dbl, ctypes.c_int, dbl, dbl, ctypes.c_double, ctypes.c_int, dbl]
    lib.solve_stream.restype = ctypes.c_int
    return lib


def c_stream(lib, legs, lengths, p0, r0, tol):
    """(seconds per reading, iterations per reading, poses) of the C solve."""
    ptr = lambda a: a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))   # noqa: E731
    legs, lengths = np.ascontiguousarray(legs), np.ascontiguousarray(lengths)
    p, r, poses = p0.copy(), r0.reshape(9).copy(), np.empty((len(lengths), 12))
    t0 = time.perf_counter()
    total = lib.solve_stream(ptr(legs), ptr(lengths), len(lengths), ptr(p), ptr(r), tol, 30, ptr(poses))
    elapsed = time.perf_counter() - t0
    if total < 0:
        raise RuntimeError(f"C solve: reading {-1 - total} did not converge")
    return elapsed / len(lengths), total / len(lengths), poses


def stream(positions_and_rotations, lengths_of) -> np.ndarray:
    return np.array([lengths_of(p, r) for p, r in positions_and_rotations])


def motion(home, n: int, scale_m: float):
    """n poses of a 2 kHz motion about ``home``: ~100 um per reading at scale 0.1 m."""
    out = []
    for k in range(n):
        t = k / 2000.0
        p = home + [scale_m * math.sin(2 * t), scale_m * math.cos(2 * t) - scale_m, 0.02 * t]
        out.append((p, rotation_from_rpy(0.05 * math.sin(3 * t), 0.002 * k / 20, 0.04 * t)))
    return out


def timed(run_once, n: int):
    """(seconds per reading, iterations per reading or NaN) of one run."""
    t0 = time.perf_counter()
    its = run_once()
    return (time.perf_counter() - t0) / n, its


def ours(machine: StrutMachine, gough, lengths, poses, tol: float) -> dict:
    """label -> a function timing one run of that solver over the stream."""
    n = len(lengths)
    p0, r0 = poses[0]

    def strut_stream():
        fk = StrutFK(machine, tol_m=tol)
        fk.reset(machine.task_coordinates(p0, r0))
        def once():
            _, codes, iterations, _ = fk.solve_stream(lengths)
            assert (codes == 0).all(), "a reading of the stream did not converge"
            return iterations.mean()
        return timed(once, n)

    def strut_calls():
        fk = StrutFK(machine, tol_m=tol)
        fk.reset(machine.task_coordinates(p0, r0))
        def once():
            for q in lengths:
                fk.solve(q)
            return math.nan
        return timed(once, n)

    variants = {"ours, compiled stream (StrutFK.solve_stream)": strut_stream,
                "ours, a Python call per reading (StrutFK.solve)": strut_calls}
    if gough is None:
        return variants

    def gough_calls():
        solver = GoughDKMSolver(gough, tol_m=tol)
        solver.reset(p0, r0)
        def once():
            for q in lengths:
                solver.solve(q)
            return math.nan
        return timed(once, n)

    def gough_stream():
        solver = GoughDKMSolver(gough, tol_m=tol)
        solver.reset(p0, r0)
        def once():
            _, _, converged, iterations = solver.solve_stream(lengths)
            assert converged.all(), "a reading of the stream did not converge"
            return iterations.mean()
        return timed(once, n)

    # a batch of independent readings (a study's, a log's), each from the pose before
    # it as C's stream starts each: rows with no state between them
    guess_p = np.array([poses[max(k - 1, 0)][0] for k in range(n)])
    guess_r = np.array([poses[max(k - 1, 0)][1] for k in range(n)])

    def gough_batch():
        def once():
            _, _, converged, iterations = gough.direct_kinematics_batch(lengths, guess_p, guess_r, tol_m=tol)
            assert converged.all(), "a reading of the batch did not converge"
            return iterations.mean()
        return timed(once, n)

    return {**variants,
            "ours, the metrology's GoughDKMSolver.solve per reading": gough_calls,
            "ours, the metrology's solver as a compiled stream (GoughDKMSolver.solve_stream)": gough_stream,
            "ours, a batch of independent readings, one core (GoughPlatform.direct_kinematics_batch)": gough_batch}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--readings", type=int, default=4000)
    args = parser.parse_args(argv)
    tol = 1e-10
    lib = build_c()

    hexapod: StrutMachine = load_machine("genhexkins").model
    gough = load_machine("mom3").metrology.platform
    cases = [("genhexkins hexapod", hexapod.base_joints, hexapod.platform_joints, hexapod.home[:3],
              lambda p, r: hexapod.strut_lengths(p, r)),
             ("MoM3 Gough metrology", gough.base_points, gough.plate_points, gough.home_position,
              lambda p, r: gough.strut_lengths(p, r))]
    rows = []
    for name, base, plate, home, lengths_of in cases:
        poses = motion(np.asarray(home, dtype=float), args.readings, 0.1)
        lengths = stream(poses, lengths_of)
        legs = np.hstack((base, plate))
        p0, r0 = poses[0][0].copy(), poses[0][1].copy()
        machine = StrutMachine(name, [f"s{k}" for k in range(6)], base, plate, [(1e-3, 10.0)] * 6,
                               hexapod.task_coordinates(p0, r0), {})
        variants = ours(machine, gough if name.startswith("MoM3") else None, lengths, poses, tol)
        if lib is None:
            rows.append((name, "C Newton: no C compiler (cc) here", math.nan, math.nan, math.nan))
        # each repeat times C and then every one of ours, so that a ratio compares
        # runs of the same seconds (this VM's speed drifts by tens of per cent)
        c_times, times, ratios, its = [], {v: [] for v in variants}, {v: [] for v in variants}, {}
        for _ in range(args.repeat):
            c_s = math.nan
            if lib is not None:
                c_s, c_its, _ = c_stream(lib, legs, lengths, p0, r0, tol)
                c_times.append(c_s)
            for label, run in variants.items():
                seconds, its[label] = run()
                times[label].append(seconds)
                ratios[label].append(seconds / c_s)
        if lib is not None:
            rows.append((name, "C Newton (cc -O2), stream", 1e6 * statistics.median(c_times), c_its, 1.0))
        for label in variants:
            rows.append((name, label, 1e6 * statistics.median(times[label]), its[label],
                         statistics.median(ratios[label])))

    print(f"hexapod benchmark: warm-started FK over a {args.readings}-reading 2 kHz stream, "
          f"tol {tol:g} m, median of {args.repeat} (x C: the median of the ratios to the C run of the same repeat)")
    print(f"| machine | solver | us/reading | iterations/reading | x C |")
    print("|---|---|---|---|---|")
    for name, solver, us, its, ratio in rows:
        its_text = "-" if math.isnan(its) else f"{its:.2f}"
        ratio_text = "-" if math.isnan(ratio) else f"{ratio:.1f}"
        print(f"| {name} | {solver} | {us:.2f} | {its_text} | {ratio_text} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
