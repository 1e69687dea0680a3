"""The ARCHI paper's experiments (Marquet et al., ICAR 2001): the conditioning of the redundant
machine and of its sub-machines, unlimited rotation, drive fighting and its cures, the force
distributions, a singularity crossed and a drive lost.
"""

from __future__ import annotations

import math

import numpy as np

from pkm_gallery.framework import (Bench, Experiment, Outcome, RunOutput, internal_force, plot,
                                   tracking_error_m)
from pkm_kinematics import load_machine
from pkm_kinematics.analysis import condition_numbers, condition_sweep

# the controller's singularity supervision (config/controller/archi.yaml max_condition):
# a redundant machine whose J_m stays below it never comes near a singularity
ARCHI_MAX_CONDITION = 100.0


# ------------------------------------------------------------------ ARCHI §3.3
def _path_conditioning(out: RunOutput, from_lowest: bool = False) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """Along the measured (true) path of an ARCHI run (``from_lowest``: from where the
    yaw is lowest on): the unwrapped yaw (deg), the condition number of J_m, and per
    3-leg sub-machine its condition numbers and the yaws (deg) where its Jacobian
    determinant changes sign (a singularity crossed)."""
    model = load_machine("archi").model
    s = out.steps
    ok = np.isfinite(s["yaw"])
    yaw = np.unwrap(s["yaw"][ok])
    position = s["position"][ok]
    if from_lowest:
        start = int(np.argmin(yaw))
        yaw, position = yaw[start:], position[start:]
    poses = np.column_stack([position[:, 0], position[:, 1], yaw])
    jac = model.jacobian_batch(poses)
    subs, crossings = {}, {}
    for legs in model.sub_machines():
        name = model.sub_machine_name(legs)
        sub = jac[:, list(legs), :]
        subs[name] = condition_numbers(sub)
        det = np.linalg.det(sub)
        k = np.nonzero(np.sign(det[:-1]) * np.sign(det[1:]) < 0)[0]
        crossings[name] = np.degrees(yaw[k]).tolist()
    return np.degrees(yaw), condition_numbers(jac), subs, crossings


def _draw_conditioning(bench: Bench, name: str, title: str, yaw_deg, full, subs) -> str:
    def draw(fig):
        ax = fig.add_subplot(1, 1, 1)
        for sub_name, cond in subs.items():
            ax.semilogy(yaw_deg, cond, lw=0.8, label=sub_name)
        ax.semilogy(yaw_deg, full, "k", lw=2.0, label="J_m (4 drives)")
        ax.set_ylim(1.0, 1e4)
        ax.set_xlabel("nacelle angle theta (deg), measured")
        ax.set_ylabel("condition number")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    return plot(bench, name, draw)


def archi_fig10(bench: Bench) -> Outcome:
    """ARCHI Figure 10: at x = 1 m, y = -0.4 m the nacelle turns from -200 to 200 deg
    under control (encoders only: the Gough cannot follow a full turn); the condition
    numbers of J_m and of the four 3-leg sub-machines along the measured sweep, and
    where each sub-machine's determinant changed sign against the singular angles of
    the nominal pose (analysis.condition_sweep: Brent's method on det, independent of
    the run)."""
    out = bench.run("archi_fig10")
    yaw, full, subs, crossings = _path_conditioning(out, from_lowest=True)
    model = load_machine("archi").model
    nominal = condition_sweep(model, 1.0, -0.4, -200.0, 200.0)
    expected = {model.sub_machine_name(legs): angles for legs, angles in nominal.singular_angles_deg.items()}
    o = Outcome()
    o.check("the nacelle turns over theta in [-200, 200] deg under control (completed, not tripped)",
            f"{out.status}; measured theta {yaw.min():.1f} to {yaw.max():.1f} deg",
            out.status == "completed" and yaw.min() <= -199.0 and yaw.max() >= 199.0)
    o.check(f"the redundant machine: good conditioning, no singularity (cond(J_m) below the supervisor's "
            f"{ARCHI_MAX_CONDITION:g} everywhere)", f"max cond(J_m) {np.nanmax(full):.2f}, min {np.nanmin(full):.2f}",
            np.nanmax(full) < ARCHI_MAX_CONDITION)
    misses = [max((min(abs(a - b) for b in crossings[n]) if crossings[n] else math.inf) for a in angles)
              for n, angles in expected.items() if angles]
    worst = max(misses) if misses else math.inf
    o.check("each 3-leg sub-machine: singularities occur where its Jacobian determinant vanishes (every "
            "singular angle of the nominal pose crossed on the measured path, within 0.5 deg; none elsewhere)",
            f"{sum(len(c) for c in crossings.values())} crossings, {sum(len(a) for a in expected.values())} "
            f"expected; farthest {worst:.3f} deg from its nominal angle",
            all(len(crossings[n]) == len(a) for n, a in expected.items()) and worst <= 0.5)
    o.table = [["matrix", "max cond on the path", "singular at theta (deg), measured", "nominal pose (deg)"],
               ["J_m (4 drives)", f"{np.nanmax(full):.2f}", "never", "never"]]
    o.table += [[n, f"{np.nanmax(c[np.isfinite(c)]):.3g}" if np.isfinite(c).any() else "inf",
                 ", ".join(f"{a:.2f}" for a in crossings[n]) or "-", ", ".join(f"{a:.2f}" for a in expected[n])]
                for n, c in subs.items()]
    o.figures.append(_draw_conditioning(bench, "archi_fig10.png", "ARCHI Figure 10, redrawn from the run "
                                        "(x = 1 m, y = -0.4 m)", yaw, full, subs))
    return o


def archi_unlimited_rotation(bench: Bench) -> Outcome:
    """ARCHI's unlimited rotation (§1, §3.3): two full turns of the nacelle under
    control, every 3-leg sub-machine passing its singularities on the way."""
    out = bench.run("archi_unlimited_rotation")
    yaw, full, subs, crossings = _path_conditioning(out)
    turned = yaw.max() - yaw.min()
    o = Outcome()
    o.check("unlimited rotation: two full turns under control (completed, not tripped; 720 deg commanded, "
            "measured within 1 deg)", f"{out.status}; turned {turned:.1f} deg ({turned / 360:.2f} turns)",
            out.status == "completed" and turned >= 719.0)
    o.check("every 3-leg sub-machine passes its singularities (at least 2 sign changes of its determinant "
            "per turn made)", "; ".join(f"{n}: {len(c)}" for n, c in crossings.items()),
            all(len(c) >= 2 * math.floor(turned / 360) for c in crossings.values()))
    o.check(f"the 4-drive machine stays well conditioned (cond(J_m) < {ARCHI_MAX_CONDITION:g})",
            f"max cond(J_m) {np.nanmax(full):.2f}", np.nanmax(full) < ARCHI_MAX_CONDITION)
    err = np.hypot(*(out.steps["position"][:, :2] - out.steps["position"][0, :2]).T)
    o.table = [["figure", "value"], ["turned (deg)", f"{turned:.1f}"],
               ["max cond(J_m)", f"{np.nanmax(full):.2f}"],
               ["tool position error while turning, max (um)", f"{1e6 * np.nanmax(err):.1f}"]]
    o.figures.append(_draw_conditioning(bench, "archi_unlimited_rotation.png", "ARCHI: two full turns, "
                                        "condition numbers along the measured path", yaw, full, subs))
    return o



FIG12_STRATEGIES = ("joint_pid", "decentralized_projected", "cartesian_pid")


def archi_fig12(bench: Bench) -> Outcome:
    """ARCHI Figure 12 and its two cures: 2 % error on leg 3; independent joint PIDs
    fight: the integral makes the internal force grow until the drives saturate and
    the supervisor stops the machine (without the integral it stays where the
    proportional term puts it: the paper's "as soon as an integral effect is
    included"); the projection of the joint errors (Sliding Star eq. 8) and the
    Cartesian PID do not fight."""
    runs = {s: bench.run("archi_fig12", label=s, controller={"strategy": s}) for s in FIG12_STRATEGIES}
    runs["joint_pid, no integral"] = bench.run("archi_fig12", label="joint_pid_no_integral",
                                               controller={"strategy": "joint_pid", "integral_time_s": 0.0})
    internal = {s: internal_force(r) for s, r in runs.items()}
    o = Outcome()
    pid, fi = runs["joint_pid"], internal["joint_pid"]
    t = pid.steps["t_s"]
    p_level = float(fi[np.searchsorted(t, 0.01)])          # the proportional term's, before the integral acts
    o.check("joint PIDs with a 2 % leg error: the motor forces do not converge; the integral makes the "
            "internal force grow (peak over 1.5x its level at 10 ms) until the drives saturate and the "
            "supervisor stops the machine (cause saturation)",
            f"{pid.status}, cause {pid.cause}; internal force {p_level:.0f} N at 10 ms, {np.nanmax(fi):.0f} N "
            f"at most", pid.status == "tripped" and pid.cause == "saturation" and np.nanmax(fi) > 1.5 * p_level)
    nop, fn = runs["joint_pid, no integral"], internal["joint_pid, no integral"]
    tail = fn[nop.steps["t_s"] >= nop.steps["t_s"][-1] - 0.5]
    o.check("the same joint PIDs without the integral: no growth (completed; the internal force over the "
            "last 0.5 s within 5 % of its mean, below the fighting peak)",
            f"{nop.status}; {tail.min():.0f} to {tail.max():.0f} N",
            nop.status == "completed" and tail.max() - tail.min() < 0.05 * tail.mean() and tail.max() < np.nanmax(fi))
    for s in FIG12_STRATEGIES[1:]:
        r, f = runs[s], internal[s]
        last = f[r.steps["t_s"] >= r.steps["t_s"][-1] - 0.5]
        o.check(f"{s}: the forces converge (completed; the internal force over the last 0.5 s below 5 % "
                f"of the joint PIDs' peak; inf-norm distribution: some internal force by design)",
                f"{r.status}; {last.min():.1f} to {last.max():.1f} N (joint PIDs' peak {np.nanmax(fi):.0f} N)",
                r.status == "completed" and np.nanmax(last) < 0.05 * np.nanmax(fi))
    o.table = [["strategy", "status", "cause", "peak internal force (N)", "internal force at the end (N)",
                "peak drive force (N)"]]
    for s, r in runs.items():
        o.table.append([s, r.status, r.cause, f"{np.nanmax(internal[s]):.1f}", f"{internal[s][-1]:.1f}",
                        f"{np.nanmax(np.abs(r.steps['applied'])):.1f}"])

    def draw(fig):
        ax1, ax2 = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
        for i in range(pid.steps["applied"].shape[1]):
            ax1.plot(t, pid.steps["applied"][:, i], lw=1.0, label=f"q{i + 1}")
        ax1.set_title("joint PIDs: motor forces (Figure 12)")
        ax1.set_xlabel("t (s)")
        ax1.set_ylabel("force (N)")
        ax1.legend(fontsize=8)
        for s, r in runs.items():
            ax2.plot(r.steps["t_s"], internal[s], lw=1.0, label=s)
        ax2.set_title("internal force ||f_int||")
        ax2.set_xlabel("t (s)")
        ax2.set_ylabel("N")
        ax2.legend(fontsize=8)
        for ax in (ax1, ax2):
            ax.grid(True, alpha=0.3)
    o.figures.append(plot(bench, "archi_fig12.png", draw))
    return o


# ------------------------------------------------------------------ ARCHI §4.3-4.5
DISTRIBUTIONS = ("two_arm", "two_arm_gravity", "pseudo_inverse", "inf_norm", "p_norm")
REST_S = (0.05, 0.25)                    # the settle phase before the motion: statics only
MOTION_FROM_S = 0.35


def archi_distributions(bench: Bench) -> Outcome:
    """ARCHI Figures 15-18: the test motion under computed torque with each force
    distribution; peak drive force, internal force at rest and in motion, and the
    largest change of the internal force per cycle (the "discontinuities" of §4.5)."""
    runs = {d: bench.run("archi_distributions", label=d, controller={"strategy": "computed_torque",
                                                                     "distribution": d}) for d in DISTRIBUTIONS}
    fig = {}
    for d, r in runs.items():
        t, fi = r.steps["t_s"], internal_force(r)
        motion = t >= MOTION_FROM_S
        fig[d] = {"peak": float(np.nanmax(np.abs(r.steps["applied"]))),
                  "rest": float(np.nanmean(fi[(t >= REST_S[0]) & (t <= REST_S[1])])),
                  "internal_max": float(np.nanmax(fi)),
                  "jump": float(np.nanmax(np.abs(np.diff(fi[motion]))))}
    o = Outcome()
    o.check("every distribution runs the test motion (completed)", ", ".join(f"{d} {r.status}" for d, r in runs.items()),
            all(r.status == "completed" for r in runs.values()))
    two, grav = fig["two_arm"], fig["two_arm_gravity"]
    o.check("two-arm control: neglecting gravity, the static internal force is quite important; with gravity "
            "(§4.3.2) it is very small (at rest: at least 3x smaller)", f"{two['rest']:.0f} N without gravity, "
            f"{grav['rest']:.0f} N with", two["rest"] >= 3.0 * grav["rest"])
    pinv = fig["pseudo_inverse"]
    o.check("pseudo-inverse: no drive force in the null space (internal force < 1 N), better than two-arm "
            "(lower peak drive force than two-arm without gravity)", f"internal force <= {pinv['internal_max']:.2g} N; "
            f"peak {pinv['peak']:.0f} N against {two['peak']:.0f} N",
            pinv["internal_max"] < 1.0 and pinv["peak"] < two["peak"])
    inf, pn = fig["inf_norm"], fig["p_norm"]
    lowest = min(fig, key=lambda d: fig[d]["peak"])
    o.check("infinity-norm: more efficient than the pseudo-inverse (the lowest peak drive force of all five)",
            f"inf_norm {inf['peak']:.1f} N; lowest: {lowest}", lowest == "inf_norm")
    o.check("p-norm (p = 4) as the compromise suggested in §4.5: peak between inf-norm's and the "
            "pseudo-inverse's, and smaller jumps of the internal force per cycle than inf-norm's",
            f"peak {pn['peak']:.1f} N in [{inf['peak']:.1f}, {pinv['peak']:.1f}]; largest jump {pn['jump']:.2f} N "
            f"against {inf['jump']:.2f} N", inf["peak"] <= pn["peak"] <= pinv["peak"] and pn["jump"] < inf["jump"])
    o.table = [["distribution", "peak drive force (N)", "internal force at rest (N)", "internal force, max (N)",
                "largest change of the internal force per cycle in motion (N)"]]
    o.table += [[d, f"{v['peak']:.1f}", f"{v['rest']:.1f}", f"{v['internal_max']:.1f}", f"{v['jump']:.2f}"]
                for d, v in fig.items()]

    def draw(figure):
        for k, (d, r) in enumerate(runs.items()):
            ax = figure.add_subplot(2, 3, k + 1)
            ax.plot(r.steps["t_s"], r.steps["applied"], lw=0.8)
            ax.set_title(d, fontsize=9)
            ax.set_xlabel("t (s)", fontsize=8)
            ax.set_ylabel("drive forces (N)", fontsize=8)
            ax.grid(True, alpha=0.3)
        ax = figure.add_subplot(2, 3, 6)
        for d, r in runs.items():
            ax.plot(r.steps["t_s"], internal_force(r), lw=0.8, label=d)
        ax.set_title("internal force ||f_int||", fontsize=9)
        ax.set_xlabel("t (s)", fontsize=8)
        ax.legend(fontsize=6)
        ax.grid(True, alpha=0.3)
    o.figures.append(plot(bench, "archi_distributions.png", draw, size=(11, 6)))
    return o


# ------------------------------------------------------------------ ARCHI §4
CROSSING = "archi_singularity_crossing"
# the chain that crosses its singularity on that motion (its leg in line with the
# nacelle) leaves J_234 singular; drive q1 lost -> the machine is J_234
SINGULAR_SUB = "J_234"



def _stop_index(out: RunOutput) -> int:
    """The step of the stop (the first all-zero command after motion), else the last."""
    zero = np.all(out.steps["command"] == 0.0, axis=1)
    moving = np.nonzero(~zero)[0]
    after = np.nonzero(zero[moving[0]:])[0] if len(moving) else []
    return int(moving[0] + after[0]) if len(after) else len(zero) - 1


def _controller_faults(out: RunOutput) -> str:
    return str(out.run.get("summaries", {}).get("controller", {}).get("faults", ""))


def archi_singularity_crossing(bench: Bench) -> Outcome:
    """ARCHI §4's test motion, a translation while the nacelle turns pi/4 -> pi/2,
    placed where a chain crosses its singularity; the 4-drive machine goes through
    with a bounded condition number; with drive q1 failed from the start the machine
    is the sub-machine J_234, which that crossing makes singular: it must stop before."""
    full_run = bench.run(CROSSING, label="four_drives")
    sub_run = bench.run(CROSSING, label="q1_failed", plant={"faults": "0:no_force:0.05"})
    yaw, full, subs, crossings = _path_conditioning(full_run)
    o = Outcome()
    on_motion = [a for a in crossings[SINGULAR_SUB] if 45.5 < a < 89.5]
    o.check(f"during the motion (theta 45 -> 90 deg) a chain crosses a singularity: {SINGULAR_SUB}'s "
            "determinant changes sign on the measured path", f"{SINGULAR_SUB} crossed at "
            + ", ".join(f"{a:.1f}" for a in crossings[SINGULAR_SUB]) + " deg", bool(on_motion))
    err = tracking_error_m(full_run)
    o.check(f"the 4-drive machine tracks it with a bounded condition number (completed; cond(J_m) < "
            f"{ARCHI_MAX_CONDITION:g}; tool error < 0.1 mm)",
            f"{full_run.status}; max cond(J_m) {np.nanmax(full):.2f}; max tool error {1e6 * np.nanmax(err):.1f} um",
            full_run.status == "completed" and np.nanmax(full) < ARCHI_MAX_CONDITION and np.nanmax(err) < 1e-4)
    k = _stop_index(sub_run)
    sub_yaw, _, sub_subs, sub_crossings = _path_conditioning(sub_run)
    km = int(np.isfinite(sub_run.steps["yaw"][:k + 1]).sum()) - 1     # k among the steps with a true pose
    stop_cond = float(sub_subs[SINGULAR_SUB][km])
    o.check(f"the same motion on the 3-drive sub-machine {SINGULAR_SUB} (drive q1 failed at 0.05 s) is stopped "
            "safely before the singularity (cause singularity; its determinant never changes sign)",
            f"{sub_run.status}, cause {sub_run.cause} at {sub_run.steps['t_s'][k]:.3f} s, cond({SINGULAR_SUB}) "
            f"{stop_cond:.0f} there; crossings {len(sub_crossings[SINGULAR_SUB])}; controller: "
            f"{_controller_faults(sub_run)}",
            sub_run.status == "tripped" and sub_run.cause == "singularity" and not sub_crossings[SINGULAR_SUB]
            and "continuing on J_234" in _controller_faults(sub_run))
    o.table = [["run", "status", "cause", "max cond(J_m)", f"{SINGULAR_SUB} crossed at (deg)", "max tool error (um)"],
               ["four drives", full_run.status, full_run.cause, f"{np.nanmax(full):.2f}",
                ", ".join(f"{a:.1f}" for a in crossings[SINGULAR_SUB]), f"{1e6 * np.nanmax(err):.1f}"],
               ["q1 failed (J_234)", sub_run.status, sub_run.cause, "-", "none",
                f"{1e6 * np.nanmax(tracking_error_m(sub_run)[:k + 1]):.1f} (to the stop)"]]

    def draw(fig):
        ax = fig.add_subplot(1, 1, 1)
        t = full_run.steps["t_s"][np.isfinite(full_run.steps["yaw"])]
        for name, cond in subs.items():
            ax.semilogy(t, cond, lw=0.8, label=f"{name} (four drives' path)")
        ax.semilogy(t, full, "k", lw=2.0, label="J_m (4 drives)")
        ts = sub_run.steps["t_s"][np.isfinite(sub_run.steps["yaw"])][:km + 1]
        ax.semilogy(ts, sub_subs[SINGULAR_SUB][:km + 1], "r--", lw=1.5, label="J_234, q1 failed: stopped")
        ax.axhline(ARCHI_MAX_CONDITION, color="grey", ls=":", label="max_condition")
        ax.set_ylim(1.0, 1e4)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("condition number")
        ax.set_title("ARCHI §4-style motion through a chain singularity")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    o.figures.append(plot(bench, "archi_singularity_crossing.png", draw))
    return o


FAIL_AT_S = 2.2          # just after the motion starts from (1, -0.6) m at 45 deg


def archi_drive_failure(bench: Bench) -> Outcome:
    """A drive loses its force mid-motion (plant fault no_force at 2.2 s, the motion of
    archi_singularity_crossing): the controller continues on the three others where
    that sub-machine is well conditioned (q3 lost: J_124) and stops safely where it is
    not (q1 lost: J_234, close to its singularity there)."""
    runs = {d: bench.run(CROSSING, label=f"{d}_fails", plant={"faults": f"{i}:no_force:{FAIL_AT_S}"})
            for d, i in (("q3", 2), ("q1", 0))}
    o = Outcome()
    good = runs["q3"]
    err = tracking_error_m(good)
    o.check("q3 fails: the controller continues on J_124 (well conditioned there) to the end (completed; tool "
            "error < 0.5 mm)", f"{good.status}; {_controller_faults(good)}; max tool error {1e6 * np.nanmax(err):.1f} um",
            good.status == "completed" and "continuing on J_124" in _controller_faults(good) and np.nanmax(err) < 5e-4)
    bad = runs["q1"]
    k = _stop_index(bad)
    t_stop = float(bad.steps["t_s"][k])
    after = bad.steps["position"][k:, :2]
    drift = float(np.nanmax(np.hypot(*(after - after[0]).T))) if len(after) else math.nan
    o.check("q1 fails: J_234 is close to its singularity there: the machine stops safely (tripped, cause "
            "drive_failure naming the ill-conditioned sub-machine, within 10 ms of the failure; the tool moves "
            "< 1 mm after the stop)", f"{bad.status}, cause {bad.cause}: {bad.run.get('trip_reason', '')}; stopped "
            f"{1e3 * (t_stop - FAIL_AT_S):.0f} ms after the failure; {1e6 * drift:.0f} um after the stop",
            bad.status == "tripped" and bad.cause == "drive_failure" and "too close to singular" in
            bad.run.get("trip_reason", "") and t_stop - FAIL_AT_S <= 0.010 and drift < 1e-3)
    o.table = [[f"drive failed at {FAIL_AT_S} s", "status", "cause", "controller", "max tool error (um)"],
               ["q3", good.status, good.cause, _controller_faults(good), f"{1e6 * np.nanmax(err):.1f}"],
               ["q1", bad.status, bad.cause, bad.run.get("trip_reason", ""),
                f"{1e6 * np.nanmax(tracking_error_m(bad)[:k + 1]):.1f} (to the stop)"]]
    return o


EXPERIMENTS = (
    Experiment("archi_fig10", "Conditioning of the redundant machine and of its 3-leg sub-machines",
               "ARCHI", "§3.3, Figure 10", ("archi_fig10",), archi_fig10),
    Experiment("archi_unlimited_rotation", "Two full turns of the nacelle through the sub-machines' "
               "singularities", "ARCHI", "§1, §3.3", ("archi_unlimited_rotation",), archi_unlimited_rotation),
    Experiment("archi_fig12", "Joint PIDs fight under a 2 % leg error; projection and Cartesian control do not",
               "ARCHI", "§4.1, Figure 12", ("archi_fig12",), archi_fig12),
    Experiment("archi_distributions", "Force distributions on the test motion: two-arm with and without "
               "gravity, pseudo-inverse, infinity-norm, p-norm", "ARCHI", "§4.3-4.5, Figures 15-18",
               ("archi_distributions",), archi_distributions),
    Experiment(CROSSING, "A translation while the nacelle turns pi/4 -> pi/2 through a chain singularity",
               "ARCHI", "§4, Figure 11", (CROSSING,), archi_singularity_crossing),
    Experiment("archi_drive_failure", "A drive fails mid-motion: continue on three drives, or stop where that "
               "sub-machine is ill-conditioned", "ARCHI", "§2 (redundancy), §3.3", (CROSSING,), archi_drive_failure),
)
