"""Kinematics core benchmark: median time per call and batched throughput.

    .venv/bin/python benchmarks/kinematics.py [--repeat N]

Prints one table with the targets of the foundation issue. Speed targets live here,
not in tests. Single-call rows time a warm-started, realistic per-cycle call (the
control loop runs them at 1-2 kHz); batched rows time vectorised calls over 100,000
poses.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numpy as np

from pkm_kinematics import GoughDKMSolver, load_machine
from pkm_kinematics import distribution as fd
from pkm_kinematics.rotations import exp_so3, rotation_from_rpy


def per_call_us(fn, args_list, repeat: int) -> float:
    """Median over ``repeat`` rounds of the mean time per call over ``args_list``."""
    rounds = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for args in args_list:
            fn(*args)
        rounds.append((time.perf_counter() - t0) / len(args_list) * 1e6)
    return statistics.median(rounds)


def per_second(fn, n: int, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return n / statistics.median(times)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    archi = load_machine("archi").model
    star = load_machine("sliding_star").model
    delta = load_machine("mom3")
    gough = delta.metrology.platform
    rows = []   # (name, value, unit, target, ok)

    # --- planar IK / FK / Jacobian, one pose per control cycle along the ARCHI motion
    k = 500
    t = np.linspace(0.0, 1.0, k)
    path = np.column_stack([1.0 + 0.1 * t, -0.4 + 0.05 * t, math.pi / 4 + math.pi / 4 * t])
    q_path = [archi.inverse_kinematics(p) for p in path]
    us = per_call_us(archi.inverse_kinematics, [(p,) for p in path], args.repeat)
    rows.append(("planar IK (archi, 4 legs)", us, "us/call", "<= 10", us <= 10))
    us = per_call_us(archi.forward_kinematics, [(q, p) for q, p in zip(q_path, path)], args.repeat)
    rows.append(("planar FK (archi, closed form + Gauss-Newton)", us, "us/call", "<= 30", us <= 30))
    star_path = np.column_stack([0.2 * t - 0.1, 0.1 * t - 0.05, 0.2 * t])
    star_q = [star.inverse_kinematics(p) for p in star_path]
    us = per_call_us(star.forward_kinematics, [(q, p) for q, p in zip(star_q, np.vstack([star_path[:1], star_path[:-1]]))],
                     args.repeat)
    rows.append(("planar FK (sliding_star, Newton warm)", us, "us/call", "<= 30", us <= 30))
    us = per_call_us(archi.jacobian, [(p, q) for p, q in zip(path, q_path)], args.repeat)
    rows.append(("planar J_m (archi, q known)", us, "us/call", "-", True))
    cube = delta.model.workspace["center"] + rng.uniform(-0.15, 0.15, (k, 3))
    us = per_call_us(delta.model.inverse_kinematics, [(p,) for p in cube], args.repeat)
    rows.append(("translational IK (mom3 delta)", us, "us/call", "<= 10", us <= 10))
    rho = [delta.model.inverse_kinematics(p) for p in cube]
    us = per_call_us(delta.model.forward_kinematics, [(r,) for r in rho], args.repeat)
    rows.append(("translational FK (mom3 delta, closed form)", us, "us/call", "<= 30", us <= 30))

    # --- Gough DKM warm-started along a 2 kHz stream (0.2 m/s, small rotations)
    stream = []
    for i in range(k):
        ti = i / 2000.0
        p = gough.home_position + [0.1 * math.sin(2 * ti), 0.1 * math.cos(2 * ti) - 0.1, 0.02 * ti]
        stream.append((gough.strut_lengths(p, rotation_from_rpy(1e-4 * math.sin(ti), 2e-4 * ti, 1e-4)),))
    rounds = []
    for _ in range(args.repeat):
        solver = GoughDKMSolver(gough)
        solver.solve(*stream[0])
        rounds.append(per_call_us(solver.solve, stream[1:], 1))
    us = statistics.median(rounds)
    rows.append(("Gough DKM warm start (stream, 100 um/cycle)", us, "us/call", "<= 40", us <= 40))
    cold = [(gough.strut_lengths(gough.home_position + rng.uniform(-0.1, 0.1, 3),
                                 rotation_from_rpy(*rng.uniform(-0.05, 0.05, 3))),) for _ in range(100)]
    us = per_call_us(gough.direct_kinematics, cold, args.repeat)
    rows.append(("Gough DKM cold start from home", us, "us/call", "-", True))

    # --- force distribution along the ARCHI motion
    jacs = [archi.jacobian(p, q) for p, q in zip(path, q_path)]
    wrench = np.array([100.0, -300.0, 20.0])
    us = per_call_us(fd.min_inf_norm, [(j, wrench) for j in jacs], args.repeat)
    rows.append(("inf-norm distribution (4 drives, exact)", us, "us/call", "<= 20", us <= 20))
    us = per_call_us(fd.min_two_norm, [(j, wrench) for j in jacs], args.repeat)
    rows.append(("pseudo-inverse distribution (4 drives)", us, "us/call", "-", True))
    us = per_call_us(fd.min_p_norm, [(j, wrench, 4.0) for j in jacs], args.repeat)
    rows.append(("p-norm distribution (p = 4)", us, "us/call", "-", True))

    # --- batched
    n = 100_000
    poses = np.column_stack([rng.uniform(0.6, 1.4, n), rng.uniform(-0.6, -0.25, n), rng.uniform(-7, 7, n)])
    rate = per_second(lambda: archi.inverse_kinematics_batch(poses), n, args.repeat)
    rows.append(("batched planar IK (archi)", rate, "poses/s", "-", True))
    q_b, _ = archi.inverse_kinematics_batch(poses)
    rate = per_second(lambda: archi.forward_kinematics_batch(q_b, guesses=poses), n, args.repeat)
    rows.append(("batched planar FK (archi)", rate, "poses/s", "-", True))
    p_b = gough.home_position + rng.uniform(-0.15, 0.15, (n, 3))
    r_b = np.array([rotation_from_rpy(*r) for r in rng.uniform(-0.01, 0.01, (n, 3))])
    l_b = gough.strut_lengths_batch(p_b, r_b)
    gp = p_b + rng.normal(0.0, 1e-4, (n, 3))
    gr = np.einsum("nij,njk->nik", np.array([exp_so3(w) for w in rng.normal(0.0, 1e-4, (n, 3))]), r_b)
    rate = per_second(lambda: gough.direct_kinematics_batch(l_b, gp, gr), n, args.repeat)
    rows.append(("batched Gough DKM (warm, 100 um guess)", rate, "poses/s", ">= 400,000", rate >= 400_000))
    home_p = np.tile(gough.home_position, (n, 1))
    home_r = np.tile(np.eye(3), (n, 1, 1))
    rate = per_second(lambda: gough.direct_kinematics_batch(l_b, home_p, home_r), n, args.repeat)
    rows.append(("batched Gough DKM (cold, from home)", rate, "poses/s", "-", True))

    width = max(len(r[0]) for r in rows)
    print(f"{'benchmark'.ljust(width)}  {'median':>12}  {'unit':<8}  {'target':<11}  met")
    print("-" * (width + 44))
    for name, value, unit, target, ok in rows:
        shown = f"{value:,.0f}" if unit == "poses/s" else f"{value:.1f}"
        print(f"{name.ljust(width)}  {shown:>12}  {unit:<8}  {target:<11}  {'yes' if ok else 'NO'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
