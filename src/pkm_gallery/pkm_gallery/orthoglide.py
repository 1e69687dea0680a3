"""The Orthoglide paper's experiment (Wenger and Chablat, 2002): the prescribed cube at the
prototype's speed, its transmission factors (eq. 17) and parallel singularities.
"""

from __future__ import annotations

import numpy as np

from pkm_gallery.framework import Bench, Experiment, Outcome, plot
from pkm_kinematics import load_machine
from pkm_kinematics.analysis import cube_points
from pkm_kinematics.errors import SingularityError

# ------------------------------------------------------------------ Orthoglide
OG_SPEED_M_S, OG_ACCEL_M_S2 = 1.2, 14.0      # the prototype's targets
OG_PSI = (0.5, 2.0)                          # eq. 17
OG_GRID = 21                                 # points per axis of the cube map


def orthoglide_cube(bench: Bench) -> Outcome:
    """The Orthoglide's prescribed cube at the prototype's speed and acceleration: the
    velocity transmission factors along the measured path and over the whole cube
    (eq. 17: 1/2 <= psi <= 2), the parallel-singularity measure over the cube, and the
    refusal of a pose near a parallel singularity."""
    out = bench.run("orthoglide_cube")
    model = load_machine("orthoglide").model
    s, t = out.steps, out.steps["t_s"]
    dt = float(np.median(np.diff(t)))
    speed = np.linalg.norm(np.diff(s["position"], axis=0), axis=1) / dt
    ref_v = np.diff(s["ref_position"], axis=0) / dt
    accel = np.abs(np.diff(ref_v, axis=0) / dt).max(axis=1)           # per axis, as the planner limits it
    psi_path = model.transmission_factors_batch(s["position"])
    w = model.workspace
    grid = cube_points(w["center"], float(w["size"]), OG_GRID)
    psi_cube = model.transmission_factors_batch(grid)
    det_cube = model.parallel_singularity_measure_batch(grid)
    err = np.linalg.norm(s["position"] - s["ref_position"], axis=1)
    o = Outcome()
    o.check(f"the path runs at the prototype's targets ({OG_SPEED_M_S} m/s, {OG_ACCEL_M_S2} m/s^2 per axis) "
            "under control (completed; the reference's acceleration reaches its limit within 1 % and no more, "
            "the tool's speed within 1 % below and 5 % above, with its tracking error)",
            f"{out.status}; tool speed up to {speed.max():.3f} m/s, reference acceleration up to {accel.max():.2f} m/s^2",
            out.status == "completed" and 0.99 * OG_SPEED_M_S <= speed.max() <= 1.05 * OG_SPEED_M_S
            and 0.99 * OG_ACCEL_M_S2 <= accel.max() <= 1.01 * OG_ACCEL_M_S2)
    o.check("the transmission factors along the measured path stay within [1/2, 2] (eq. 17)",
            f"psi in [{np.nanmin(psi_path):.4f}, {np.nanmax(psi_path):.4f}]",
            OG_PSI[0] <= np.nanmin(psi_path) and np.nanmax(psi_path) <= OG_PSI[1])
    o.check(f"over the whole prescribed cube ({OG_GRID}^3 points) psi stays within [1/2, 2] (to 1e-6: the sizing "
            "puts the corners Q1, Q2 on the bounds)", f"psi in [{np.nanmin(psi_cube):.7f}, {np.nanmax(psi_cube):.7f}]",
            np.nanmin(psi_cube) >= OG_PSI[0] - 1e-6 and np.nanmax(psi_cube) <= OG_PSI[1] + 1e-6)
    near = np.array(w["center"]) + 0.15         # 50 mm beyond the corner Q2 on the diagonal: |det| ~ 0.001
    try:
        model.check_parallel_singularity(near)
        refusal = ""
    except SingularityError as exc:
        refusal = str(exc)
    o.check(f"no parallel singularity in the cube (|det| of the unit leg directions above the margin "
            f"{model.parallel_margin:g} everywhere), and a pose near one is refused with a clear error",
            f"|det| >= {np.nanmin(det_cube):.3f} on the cube; refused: {refusal or 'no'}",
            np.nanmin(det_cube) > model.parallel_margin and "parallel singularity" in refusal)
    o.table = [["figure", "value"],
               ["tool speed, max (m/s)", f"{speed.max():.3f}"],
               ["reference acceleration per axis, max (m/s^2)", f"{accel.max():.2f}"],
               ["tool error, RMS / max (um)", f"{1e6 * np.sqrt(np.nanmean(err * err)):.1f} / {1e6 * np.nanmax(err):.1f}"],
               ["psi on the path, min / max", f"{np.nanmin(psi_path):.4f} / {np.nanmax(psi_path):.4f}"],
               ["psi on the cube, min / max", f"{np.nanmin(psi_cube):.4f} / {np.nanmax(psi_cube):.4f}"],
               ["parallel-singularity measure on the cube, min", f"{np.nanmin(det_cube):.3f}"]]
    o.notes = ("The controller has no paper figure to meet here (the paper designs the machine, it does not "
               "control it): the tool error is reported, not judged.")

    def draw(fig):
        ax = fig.add_subplot(1, 2, 1)
        ax.plot(t, psi_path, lw=0.8)
        for bound in OG_PSI:
            ax.axhline(bound, color="grey", ls=":")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("transmission factors psi")
        ax.set_title("along the measured path")
        ax.grid(True, alpha=0.3)
        ax = fig.add_subplot(1, 2, 2)
        mid = grid[:, 2] == np.unique(grid[:, 2])[OG_GRID // 2]
        xs, ys = grid[mid, 0], grid[mid, 1]
        sc = ax.scatter(1e3 * xs, 1e3 * ys, c=np.nanmax(psi_cube[mid], axis=1), s=18, cmap="viridis")
        fig.colorbar(sc, ax=ax, label="largest psi")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_title("largest psi, mid-height slice of the cube")
    o.figures.append(plot(bench, "orthoglide_cube.png", draw, size=(11, 4.5)))
    return o


EXPERIMENTS = (
    Experiment("orthoglide_cube", "The prescribed cube at 1.2 m/s and 14 m/s^2: transmission factors and "
               "parallel singularities", "Orthoglide", "§3.3, §4.3-4.4, eq. 17", ("orthoglide_cube",), orthoglide_cube),
)
