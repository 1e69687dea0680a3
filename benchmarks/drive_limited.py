"""Motion within every drive's limits: the Cartesian-only plan against the drive-limited
one on the same paths, and the planning time of a CAM-style program.

    .venv/bin/python benchmarks/drive_limited.py [--segments 10000]

Rows per path: its duration planned in Cartesian space only (with the peak drive
velocity, acceleration and force as fractions of their limits: over 1 is what today's
validation refuses), and drive-limited (planner.plan_validated: slowed down where a
drive needs it); the planning time. Then a CAM-style program (lines, arcs in three
planes, drilling cycles) of ``--segments`` segments on the Orthoglide: parsing, and
timing and sampling with the drive check.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from pkm_kinematics import load_machine
from pkm_kinematics.dynamics import dynamic_model
from pkm_trajectory.gcode import parse_gcode
from pkm_trajectory.planner import Limits, Line, plan, plan_validated
from pkm_trajectory.program import gcode_segments, program_segments
from pkm_trajectory.time_optimal import DriveLimits, DriveModel, drive_forces, drive_rates


def peaks(model: DriveModel, samples) -> tuple:
    """Peak |qdot|, |qddot|, |f| over the samples as fractions of the drives' limits."""
    machine = model.machine
    _, qdot, qddot = drive_rates(machine, samples.position, samples.velocity, samples.acceleration)
    step = max(1, len(samples.time_s) // 400)
    forces = np.array([drive_forces(model, x, v, a) for x, v, a in
                       zip(samples.position[::step], samples.velocity[::step], samples.acceleration[::step])])
    lim = model.limits
    return (np.abs(qdot).max() / lim.velocity, np.abs(qddot).max() / lim.acceleration,
            np.abs(forces).max() / lim.force)


def paths():
    hexapod = load_machine("genhexkins")
    home = np.array(hexapod.model.home, dtype=float)
    tilt = Line(tuple(home), tuple(home + [0.03, 0.0, 0.0, math.radians(8.0), math.radians(-6.0), 0.0]))
    archi = load_machine("archi")
    crossing = gcode_segments("G21 G90\nG1 F30000 Y-600\nG1 X1100 Y-500 C90\nM2\n", archi.model.task_space,
                              archi.model.home)
    yield ("genhexkins tilt 8/-6 deg + 30 mm", hexapod, [tilt],
           Limits((0.1,) * 3 + (0.5,) * 3, (1.0,) * 3 + (5.0,) * 3, (40.0,) * 3 + (200.0,) * 3), (0.02, 0.2, 60.0))
    ortho = load_machine("orthoglide")
    corner = gcode_segments("G21 G90\nG1 F72000 X126 Y126 Z126\nG1 X-73 Y-73 Z-73\nM2\n", ortho.model.task_space,
                            ortho.model.home)
    yield ("Orthoglide home -> Q2 -> Q1 (psi 0.5-2)", ortho, corner,
           Limits((1.2,) * 3, (14.0,) * 3, (1400.0,) * 3), (1.2, 14.0, 150.0))
    yield ("ARCHI through J_234's singularity", archi, crossing,
           Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0)), (0.06, 1.0, 300.0))


def cam_program(segments: int) -> str:
    """Lines, arcs in G17/G18/G19 and G81 holes about the Orthoglide's home, in mm."""
    out = ["G21 G90 G94 G17", "G0 X0 Y0 Z0", "G1 F1200"]
    k = 0
    while len(out) < segments:
        x, y = 10 * math.sin(0.01 * k), 10 * math.cos(0.013 * k)
        out.append(f"G1 X{x:.4f} Y{y:.4f} Z{0.5 * math.sin(0.02 * k):.4f}")
        if k % 50 == 10:
            out += ["G18 G2 X{:.4f} I1 K0".format(x + 2), "G19 G3 Y{:.4f} J1 K0".format(y + 2), "G17"]
        if k % 200 == 100:
            out += [f"G98 G81 X{x:.3f} Y{y:.3f} Z-2 R1 F300", "G80", "G1 F1200"]
        k += 1
    return "\n".join(out + ["M2"])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--segments", type=int, default=10000)
    args = parser.parse_args(argv)
    print("| path | Cartesian-only s | peak v, a, f / limit | drive-limited s | peak v, a, f / limit | planning s |")
    print("|---|---|---|---|---|---|")
    for name, config, segments, limits, (v_q, a_q, f_q) in paths():
        machine = config.model
        model = DriveModel(machine, DriveLimits(v_q, a_q, f_q), dynamic_model(config))
        cartesian = plan(segments, limits)
        t0 = time.perf_counter()
        limited = plan_validated(segments, machine, limits, 1000.0, 0.0, v_q, a_q, None, None, f_q, model.dynamics)
        planning = time.perf_counter() - t0
        fmt = ", ".join
        print(f"| {name} | {cartesian.duration_s:.3f} | {fmt(f'{p:.2f}' for p in peaks(model, cartesian))} | "
              f"{limited.duration_s:.3f} | {fmt(f'{p:.3f}' for p in peaks(model, limited))} | {planning:.3f} |")
    ortho = load_machine("orthoglide")
    machine = ortho.model
    text = cam_program(args.segments)
    t0 = time.perf_counter()
    moves = parse_gcode(text, start=tuple(machine.home))
    parse_s = time.perf_counter() - t0
    segments = program_segments(moves, machine.task_space, machine.home)
    limits = Limits((0.2,) * 3, (2.0,) * 3, (50.0,) * 3)
    model = DriveModel(machine, DriveLimits(0.5, 5.0))
    t0 = time.perf_counter()
    samples = plan(segments, limits, 1000.0, 3, model)
    plan_s = time.perf_counter() - t0
    print(f"\nCAM-style program on the Orthoglide: {len(text.splitlines())} lines, {len(segments)} segments, "
          f"{samples.duration_s:.1f} s of motion")
    print("| step | s | per segment, ms |\n|---|---|---|")
    print(f"| parse | {parse_s:.3f} | {1e3 * parse_s / len(segments):.3f} |")
    print(f"| time laws + drive check + sampling | {plan_s:.3f} | {1e3 * plan_s / len(segments):.3f} |")


if __name__ == "__main__":
    main()
