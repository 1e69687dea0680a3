"""The Sliding Star paper's experiments (Valasek et al.): drive fighting under a link error and
its cures (eq. 6-9), and on-line forward kinematics by integrating the differential
kinematics (§3.1).
"""

from __future__ import annotations

import numpy as np

from pkm_gallery.framework import Bench, Experiment, Outcome, RunOutput, internal_force, plot, tracking_error_m
from pkm_kinematics import load_machine
from pkm_kinematics.online_fk import integrate_forward_kinematics

# ------------------------------------------------------------------ Sliding Star §3
STAR_STRATEGIES = ("joint_pid", "decentralized_projected", "decentralized_integral_projected", "cartesian_pid")
FORCE_LIMIT_N = 2000.0                   # config/controller defaults and the plant's


def sliding_star_fighting(bench: Bench) -> Outcome:
    """Sliding Star §3: a 2 % link error; cascade joint PIDs fight up to saturation; the
    eq. 8 projection (Fig. 8), its lab variant on the integral only (Fig. 9) and the
    centralized Cartesian control (eq. 9) against the same error."""
    runs = {st: bench.run("sliding_star_fighting", label=st, controller={"strategy": st}) for st in STAR_STRATEGIES}
    internal = {st: internal_force(r, "sliding_star") for st, r in runs.items()}
    peak_force = {st: float(np.nanmax(np.abs(r.steps["applied"]))) for st, r in runs.items()}
    o = Outcome()
    pid_peak = float(np.nanmax(internal["joint_pid"]))
    pid = runs["joint_pid"]
    o.check("cascade joint PIDs: the drives fight, their forces grow up to saturation (the force limit) and "
            "the machine is stopped", f"{pid.status} ({pid.cause}); peak drive force {peak_force['joint_pid']:.0f} N, "
            f"internal force up to {pid_peak:.0f} N",
            pid.status == "tripped" and peak_force["joint_pid"] >= FORCE_LIMIT_N - 1e-6)
    for st, what in (("decentralized_projected", "the eq. 8 projection of the joint controllers' forces (Fig. 8)"),
                     ("cartesian_pid", "centralized Cartesian control (eq. 9)")):
        r, fi = runs[st], internal[st]
        o.check(f"{what}: no fighting (completed; internal force below 1 % of the joint PIDs' peak)",
                f"{r.status}; internal force up to {np.nanmax(fi):.1f} N", r.status == "completed" and
                np.nanmax(fi) < 0.01 * pid_peak)
    fig9, fi9 = runs["decentralized_integral_projected"], internal["decentralized_integral_projected"]
    tail = fi9[fig9.steps["t_s"] >= fig9.steps["t_s"][-1] - 0.5]
    o.check("the lab model's variant, the projection on the integral component only (Fig. 9): the fight "
            "no longer grows (completed, below the force limit, the internal force over the last 0.5 s within "
            "5 % of its mean)", f"{fig9.status}; peak drive force {peak_force['decentralized_integral_projected']:.0f} N; "
            f"internal force {tail.min():.0f} to {tail.max():.0f} N",
            fig9.status == "completed" and peak_force["decentralized_integral_projected"] < FORCE_LIMIT_N
            and tail.max() - tail.min() < 0.05 * tail.mean())
    fighting_table_and_plot(bench, o, runs, internal, peak_force, "drive", "Sliding Star, 2 % error on link s3",
                             "sliding_star_fighting.png")
    o.notes = ("The Fig. 9 variant stops the growth but keeps the static fight of the proportional terms: "
               f"{tail.mean():.0f} N of internal force here, against {np.nanmax(internal['decentralized_projected']):.0f} N "
               "with the full projection (Fig. 8). The paper reports the variant applicable on its lab model, "
               "without a figure of its internal force; with this project's gains and a 2 % error it holds the "
               "machine at over 1.5 kN of drive force.")
    return o


def fighting_table_and_plot(bench: Bench, o: Outcome, runs: dict, internal: dict, peak_force: dict, drive: str,
                             title: str, figure: str) -> None:
    """The drive-fighting experiments' table (status, cause, peak force, internal force
    max and at the end, per strategy) and their internal-force plot."""
    o.table = [["strategy", "status", "cause", f"peak {drive} force (N)", "internal force, max (N)",
                "internal force at the end (N)"]]
    o.table += [[st, r.status, r.cause, f"{peak_force[st]:.0f}", f"{np.nanmax(internal[st]):.1f}",
                 f"{internal[st][-1]:.1f}"] for st, r in runs.items()]

    def draw(fig):
        ax = fig.add_subplot(1, 1, 1)
        for st, r in runs.items():
            ax.plot(r.steps["t_s"], internal[st], lw=1.0, label=st)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("internal force ||f_int|| (N)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    o.figures.append(plot(bench, figure, draw))


ONLINE_FK_RUNS = {"newton": "newton", "integrated_euler": "integrated_euler", "integrated (midpoint)": "integrated"}
RESYNC_CYCLES = 50


def _integrated_drift(out: RunOutput, order: int, resync: int) -> tuple[np.ndarray, np.ndarray]:
    """The controller's integrated encoder pose, recomputed from the recorded readings
    with the same function and schedule (pkm_kinematics.online_fk; Newton at the first
    cycle and every ``resync``), against the Newton solution of the same readings: the
    translation (m) and yaw (rad) drift per step."""
    model = load_machine("sliding_star").model
    s = out.steps
    q = s["q"]
    # Newton's solution of every reading at once, started at the true pose of its step
    newton, converged = model.forward_kinematics_batch(q, np.column_stack([s["position"][:, :2], s["yaw"]]))
    if not converged.all():
        raise RuntimeError(f"sliding_star_online_fk: Newton did not converge at {int((~converged).sum())} steps")
    x = newton[0]
    trans, yaw = np.zeros(len(q)), np.zeros(len(q))
    for k in range(1, len(q)):
        x = newton[k] if resync and k % resync == 0 else integrate_forward_kinematics(model, x, q[k] - q[k - 1], order)
        trans[k], yaw[k] = np.hypot(*(x[:2] - newton[k, :2])), abs(x[2] - newton[k, 2])
    return trans, yaw


def sliding_star_online_fk(bench: Bench) -> Outcome:
    """Sliding Star §3.1: the on-line forward kinematics by integrating the differential
    kinematics, in the loop, against the Newton solution: two rectangles at 0.5 m/s;
    its drift (recomputed from the recorded readings), and what bounds it (the
    integration order, a Newton resynchronisation)."""
    runs, drift = {}, {}
    for label, fk in ONLINE_FK_RUNS.items():
        runs[label] = bench.run("sliding_star_online_fk", label=fk,
                                controller={"strategy": "computed_torque", "forward_kinematics": fk})
        if fk != "newton":
            drift[label] = _integrated_drift(runs[label], 2 if fk == "integrated" else 1, 0)
    # the resynchronised form on the same readings (the drift is a function of them)
    resynced = f"integrated_euler, Newton every {RESYNC_CYCLES}"
    drift[resynced] = _integrated_drift(runs["integrated_euler"], 1, RESYNC_CYCLES)
    rms = {label: float(np.sqrt(np.nanmean(tracking_error_m(r) ** 2))) for label, r in runs.items()}
    o = Outcome()
    o.check("the machine runs on the integrated forward kinematics (all three runs complete)",
            ", ".join(f"{k}: {r.status}" for k, r in runs.items()), all(r.status == "completed" for r in runs.values()))
    euler_t, euler_y = drift["integrated_euler"]
    t = runs["integrated_euler"].steps["t_s"]
    halves = [t <= t[-1] / 2, t > t[-1] / 2]
    first, last = (float(euler_t[m].max()) for m in halves)
    o.check("explicit Euler integration drifts, but the drift does not grow with the run (the second loop's "
            "largest within 20 % of the first's: an error of the step, not accumulated)",
            f"{1e6 * first:.1f} um in the first loop, {1e6 * last:.1f} um in the second; yaw up to "
            f"{1e6 * euler_y.max():.1f} urad", last <= 1.2 * first)
    mid_t, mid_y = drift["integrated (midpoint)"]
    o.check("the midpoint rule bounds the drift to below the encoders' resolution (1 um, 2 urad) and 100x "
            "below Euler's", f"{1e6 * mid_t.max():.3f} um, {1e6 * mid_y.max():.3f} urad",
            mid_t.max() < 1e-6 and mid_y.max() < 2e-6 and 100 * mid_t.max() < euler_t.max())
    res_t, _ = drift[resynced]
    o.check(f"a Newton solution every {RESYNC_CYCLES} cycles (fk_resync_cycles) bounds Euler's drift (below half "
            "of it without; recomputed on the Euler run's readings)",
            f"{1e6 * res_t.max():.1f} um against {1e6 * euler_t.max():.1f} um", res_t.max() < 0.5 * euler_t.max())
    o.check("with the midpoint rule the tool is as accurate as with the Newton solution (RMS tool error "
            "within 1 um)", f"{1e6 * rms['integrated (midpoint)']:.2f} um against {1e6 * rms['newton']:.2f} um",
            abs(rms["integrated (midpoint)"] - rms["newton"]) < 1e-6)
    o.table = [["forward kinematics", "drift, max (um)", "yaw drift, max (urad)", "RMS tool error (um)",
                "controller compute p50 (us)"]]
    for label in [*runs, resynced]:
        dt, dy = drift.get(label, (np.zeros(1), np.zeros(1)))
        r = runs.get(label)
        p50 = r.run.get("summaries", {}).get("controller", {}).get("compute_us_p50") if r else None
        o.table.append([label, f"{1e6 * dt.max():.3f}", f"{1e6 * dy.max():.3f}",
                        f"{1e6 * rms[label]:.2f}" if label in rms else "-",
                        f"{p50:.0f}" if isinstance(p50, (int, float)) else "-"])
    o.notes = ("The drift is recomputed from the recorded encoder readings with the controller's own function "
               "(pkm_kinematics.online_fk) and compared with the Newton solution of the same readings. Euler's "
               "error is first order in the step (about proportional to the speed: on a 400 x 200 mm rectangle "
               "19 um at 0.1 m/s, 105 um at 0.5 m/s) and returns with the pose: on closed loops it does not "
               "accumulate. The "
               "compute times are one run each on a shared machine: indicative only.")

    def draw(fig):
        ax = fig.add_subplot(1, 1, 1)
        for label, (dt, _) in drift.items():
            ax.semilogy(t[1:] if len(t) == len(dt) else runs[label].steps["t_s"][1:], np.maximum(1e6 * dt[1:], 1e-4),
                    lw=0.8, label=label)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("drift of the integrated pose (um)")
        ax.set_title("Sliding Star: on-line forward kinematics against Newton's")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    o.figures.append(plot(bench, "sliding_star_online_fk.png", draw))
    return o


EXPERIMENTS = (
    Experiment("sliding_star_fighting", "Drive fighting under a 2 % link error, and its cures",
               "Sliding Star", "§3, eq. 6-9, Fig. 7-9", ("sliding_star_fighting",), sliding_star_fighting),
    Experiment("sliding_star_online_fk", "On-line forward kinematics by integrating the differential kinematics",
               "Sliding Star", "§3.1", ("sliding_star_online_fk",), sliding_star_online_fk),
)
