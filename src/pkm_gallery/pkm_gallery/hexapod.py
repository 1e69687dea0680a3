"""The hexapods: LinuxCNC's genhexkins geometry under a 6-DOF program, and the Sliding Star's
and MoM3's methods on six degrees of freedom (drive fighting on an 8-strut hexapod, strut
errors removed by control on a Gough metrology).
"""

from __future__ import annotations

import numpy as np

from pkm_bringup.scenario import load_scenario
from pkm_gallery.framework import Bench, Experiment, Outcome, internal_force, plot
from pkm_gallery.sliding_star import FORCE_LIMIT_N, fighting_table_and_plot
from pkm_runs.report_data import rpy_of

# ------------------------------------------------------------------ the hexapods
HEXAPOD_STRATEGIES = ("joint_pid", "decentralized_projected", "cartesian_pid")


def hexapod_redundant_fighting(bench: Bench) -> Outcome:
    """Sliding Star §3 on a 6-DOF machine: hexapod8 (8 struts) with strut s1 1 % longer
    than its encoder reads; independent joint PIDs fight up to saturation; the eq. 8
    projection and centralized Cartesian control (eq. 9) hold without fighting."""
    shipped = load_scenario("hexapod_redundant_fighting").controller      # its integral time (a stable one)
    runs = {st: bench.run("hexapod_redundant_fighting", label=st, controller={**shipped, "strategy": st})
            for st in HEXAPOD_STRATEGIES}
    internal = {st: internal_force(r, "hexapod8") for st, r in runs.items()}
    peak_force = {st: float(np.nanmax(np.abs(r.steps["applied"]))) for st, r in runs.items()}
    o = Outcome()
    pid, pid_peak = runs["joint_pid"], float(np.nanmax(internal["joint_pid"]))
    o.check("independent joint PIDs on the 8 struts: the drives fight over the inconsistent lengths, their "
            "forces grow up to saturation and the machine is stopped",
            f"{pid.status} ({pid.cause}); peak strut force {peak_force['joint_pid']:.0f} N, internal force up "
            f"to {pid_peak:.0f} N", pid.status == "tripped" and peak_force["joint_pid"] >= FORCE_LIMIT_N - 1e-6)
    for st, what in (("decentralized_projected", "the eq. 8 projection of the joint controllers' forces on the "
                      "range of the 8 x 6 J_m"), ("cartesian_pid", "centralized Cartesian control on the six task "
                                                  "coordinates (eq. 9)")):
        r, fi = runs[st], internal[st]
        o.check(f"{what}: no fighting (completed; internal force below 1 % of the joint PIDs' peak)",
                f"{r.status}; internal force up to {np.nanmax(fi):.1f} N", r.status == "completed" and
                np.nanmax(fi) < 0.01 * pid_peak)
    fighting_table_and_plot(bench, o, runs, internal, peak_force, "strut",
                             "hexapod8 (8 struts, 6 DOF), 1 % error on strut s1", "hexapod_redundant_fighting.png")
    o.notes = ("The internal force is the part of the eight applied strut forces in ker(J_m^T), two-dimensional "
               "here, at the true pose. The joint PIDs' gains are scaled by the apparent mass of each strut, "
               "1 / (J A^-1 J^T)_ii (pkm_controller.laws.apparent_drive_mass).")
    return o


HEXAPOD_METROLOGY = {"encoders (computed torque)": "computed_torque", "Gough struts (sensor_space)": "sensor_space",
                     "Gough DKM pose (measured_space)": "measured_space"}


def hexapod_metrology(bench: Bench) -> Outcome:
    """MoM3 §6.3-6.4 on 6 DOF: hexapod8 with pitch errors on three strut screws, a
    cutting load on a compliant tool and a load on the machine's frame (MoM3 §7.1.2);
    the encoders' pose is off by ~1 mm; control on the Gough struts or its DKM pose
    puts the tool where the program says."""
    errors = {}
    for label, strategy in HEXAPOD_METROLOGY.items():
        out = bench.run("hexapod_metrology", label=strategy, controller={"strategy": strategy})
        s = out.steps
        end = s["t_s"] >= s["t_s"][-1] - 0.2                   # the held pose, after the move
        e = np.linalg.norm(s["position"][end] - s["ref_position"][end], axis=1)
        r = _rotation_error(s["orientation"][end], s["ref_orientation"][end])
        errors[label] = (out.status, float(np.nanmax(e)), float(np.nanmax(r)))
    o = Outcome()
    encoders, struts, pose = (errors[k] for k in HEXAPOD_METROLOGY)
    o.check("all three runs complete", ", ".join(sorted({v[0] for v in errors.values()})),
            all(v[0] == "completed" for v in errors.values()))
    o.check("the encoders see neither the struts' pitch errors nor the load's deflection of the tool nor the "
            "frame's: the tool is off (over 100 um at the held pose)",
            f"{1e6 * encoders[1]:.0f} um, {1e6 * encoders[2]:.0f} urad", encoders[1] > 100e-6)
    for label, (_, e, r) in ((k, errors[k]) for k in list(HEXAPOD_METROLOGY)[1:]):
        o.check(f"{label}: the tool held within 5 um and 50 urad of the program (the Gough's resolution, "
                f"not the actuation chain's errors)", f"{1e6 * e:.2f} um, {1e6 * r:.1f} urad",
                e < 5e-6 and r < 50e-6)
    o.table = [["feedback", "status", "held pose: position error max (um)", "rotation error max (urad)"]]
    o.table += [[k, v[0], f"{1e6 * v[1]:.2f}", f"{1e6 * v[2]:.1f}"] for k, v in errors.items()]
    o.notes = ("The paper separates actuation and measurement on a 3-DOF Delta; here the same Gough platform "
               "measures a 6-DOF hexapod, and the sensor-space law (J_t at the estimated real pose) runs on all "
               "six task coordinates: the error fed back is the translation and the rotation vector.")
    return o


def _rotation_error(orientation: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The angle (rad) of the rotation between two quaternion rows (x, y, z, w)."""
    dot = np.abs(np.sum(orientation * reference, axis=1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def hexapod_demo(bench: Bench) -> Outcome:
    """LinuxCNC's genhexkins hexapod through the graph: a 6-DOF G-code program (X Y Z
    A B C) planned, tracked under computed torque in SE(3) on the strut encoders."""
    out = bench.run("hexapod_demo")
    s = out.steps
    both = np.isfinite(s["ref_position"]).all(axis=1) & np.isfinite(s["position"]).all(axis=1)
    e = np.linalg.norm(s["position"][both] - s["ref_position"][both], axis=1)
    r = _rotation_error(s["orientation"][both], s["ref_orientation"][both])
    angles = np.degrees(rpy_of(s["ref_orientation"][both]))
    span = [(float(np.nanmin(angles[:, k])), float(np.nanmax(angles[:, k]))) for k in range(3)]
    o = Outcome()
    o.check("the program's six coordinates are followed (the reference turns about all three axes: A, B and C "
            "each span at least 3 deg)", ", ".join(f"{w} {lo:+.1f} to {hi:+.1f} deg"
                                                    for w, (lo, hi) in zip("ABC", span)),
            all(hi - lo >= 3.0 - 1e-9 for lo, hi in span))
    o.check("the run completes, nothing tripped", f"{out.status} ({out.cause})", out.status == "completed")
    o.check("computed torque in SE(3): the tool within 20 um and 50 urad of the reference throughout",
            f"position max {1e6 * e.max():.1f} um (RMS {1e6 * np.sqrt(np.mean(e * e)):.1f} um); rotation max "
            f"{1e6 * r.max():.1f} urad", e.max() < 20e-6 and r.max() < 50e-6)
    o.table = [["tool error", "RMS", "max"],
               ["position (um)", f"{1e6 * np.sqrt(np.mean(e * e)):.2f}", f"{1e6 * e.max():.2f}"],
               ["rotation (urad)", f"{1e6 * np.sqrt(np.mean(r * r)):.2f}", f"{1e6 * r.max():.2f}"]]

    def draw(fig):
        t = s["t_s"][both]
        ax = fig.add_subplot(1, 2, 1)
        ax.plot(t, 1e6 * e, lw=1.0)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("position error (um)")
        ax.grid(True, alpha=0.3)
        ax = fig.add_subplot(1, 2, 2)
        for k, w in enumerate("ABC"):
            ax.plot(t, angles[:, k], lw=1.0, label=w)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("reference rotation (deg)")
        ax.legend(fontsize=8)
        ax.grid(True, alpha=0.3)
    o.figures.append(plot(bench, "hexapod_demo.png", draw, size=(11, 4.0)))
    return o



EXPERIMENTS = (
    Experiment("hexapod_demo", "The Gough-Stewart hexapod follows a 6-DOF program (X Y Z A B C) under computed "
               "torque in SE(3)", "LinuxCNC", "genhexkins", ("hexapod_demo",), hexapod_demo),
    Experiment("hexapod_redundant_fighting", "Drive fighting on an 8-strut hexapod under a 1 % strut error, and "
               "its cures", "Sliding Star", "§3, eq. 6-9 (on 6 DOF)", ("hexapod_redundant_fighting",),
               hexapod_redundant_fighting),
    Experiment("hexapod_metrology", "A hexapod's strut errors, unseen by its encoders, removed by control on a "
               "Gough metrology", "MoM3", "§6.3-6.4 (on 6 DOF)", ("hexapod_metrology",), hexapod_metrology),
)
