"""The papers' experiments of ``pkm-gallery`` (the registry ``EXPERIMENTS``; framework:
:mod:`pkm_gallery.gallery`). Each runs its scenario files in one process and judges
the measured figures against the paper's claim; the thresholds are argued in the
claim's text (docs/results.md shows them).
"""

from __future__ import annotations

import math

import numpy as np

from pkm_gallery.gallery import Bench, Experiment, Outcome, RunOutput

# the controller's singularity supervision (config/controller/archi.yaml max_condition):
# a redundant machine whose J_m stays below it never comes near a singularity
ARCHI_MAX_CONDITION = 100.0


def _plot(bench: Bench, name: str, draw, size=(8, 4.5)) -> str:
    """Draw a figure with ``draw(fig)`` (matplotlib's Agg canvas) into the bench's
    figure directory; returns its file name."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    draw(fig)
    fig.tight_layout()
    fig.savefig(bench.figure(name))
    return name


# ------------------------------------------------------------------ ARCHI §3.3
def _path_conditioning(out: RunOutput, from_lowest: bool = False) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """Along the measured (true) path of an ARCHI run (``from_lowest``: from where the
    yaw is lowest on): the unwrapped yaw (deg), the condition number of J_m, and per
    3-leg sub-machine its condition numbers and the yaws (deg) where its Jacobian
    determinant changes sign (a singularity crossed)."""
    from pkm_kinematics import load_machine
    from pkm_kinematics.analysis import condition_numbers
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
    return _plot(bench, name, draw)


def archi_fig10(bench: Bench) -> Outcome:
    """ARCHI Figure 10: at x = 1 m, y = -0.4 m the nacelle turns from -200 to 200 deg
    under control (encoders only: the Gough cannot follow a full turn); the condition
    numbers of J_m and of the four 3-leg sub-machines along the measured sweep, and
    where each sub-machine's determinant changed sign against the singular angles of
    the nominal pose (analysis.condition_sweep: Brent's method on det, independent of
    the run)."""
    from pkm_kinematics import load_machine
    from pkm_kinematics.analysis import condition_sweep
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


# ------------------------------------------------------------------ ARCHI §4.1
def _internal_force(out: RunOutput, machine: str = "archi") -> np.ndarray:
    """||f_int|| per step of the applied forces, f_int = f - J (J^T J)^-1 J^T f at the
    true pose of a planar machine (x, y, yaw) or a spatial one (x, y, z, a, b, c) (the
    report's definition, pkm_runs.report_metrics)."""
    from pkm_runs.report_data import rpy_of
    from pkm_runs.report_metrics import internal_force_rows
    from pkm_kinematics import load_machine
    s, cfg = out.steps, load_machine(machine)
    if cfg.model.task_space.dof == 6:
        poses = np.column_stack([s["position"], rpy_of(s["orientation"])])
    else:
        poses = np.column_stack([s["position"][:, 0], s["position"][:, 1], s["yaw"]])
    return internal_force_rows(cfg, s["applied"], poses)


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
    internal = {s: _internal_force(r) for s, r in runs.items()}
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
    o.figures.append(_plot(bench, "archi_fig12.png", draw))
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
        t, fi = r.steps["t_s"], _internal_force(r)
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
            ax.plot(r.steps["t_s"], _internal_force(r), lw=0.8, label=d)
        ax.set_title("internal force ||f_int||", fontsize=9)
        ax.set_xlabel("t (s)", fontsize=8)
        ax.legend(fontsize=6)
        ax.grid(True, alpha=0.3)
    o.figures.append(_plot(bench, "archi_distributions.png", draw, size=(11, 6)))
    return o


# ------------------------------------------------------------------ ARCHI §4
CROSSING = "archi_singularity_crossing"
# the chain that crosses its singularity on that motion (its leg in line with the
# nacelle) leaves J_234 singular; drive q1 lost -> the machine is J_234
SINGULAR_SUB = "J_234"


def _tracking_error_m(out: RunOutput) -> np.ndarray:
    """|p_true - p_ref| (x, y) per step."""
    s = out.steps
    return np.hypot(*(s["position"][:, :2] - s["ref_position"][:, :2]).T)


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
    err = _tracking_error_m(full_run)
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
                f"{1e6 * np.nanmax(_tracking_error_m(sub_run)[:k + 1]):.1f} (to the stop)"]]

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
    o.figures.append(_plot(bench, "archi_singularity_crossing.png", draw))
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
    err = _tracking_error_m(good)
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
                f"{1e6 * np.nanmax(_tracking_error_m(bad)[:k + 1]):.1f} (to the stop)"]]
    return o


# ------------------------------------------------------------------ MoM3 §7.1
TABLE2_LOAD_ON_S = (0.5, 3.1, 7.0)          # mom3_table2.yaml: 110 N on at these times...
WINDOW_S = 0.2                              # ...compared over the 0.2 s before and 0.35 s after
TABLE2_PAPER_UM = {"the Delta robot (encoders)": (0.3, 1.0, 0.6), "the Gough platform": (73.7, 73.1, 70.9),
                   "the laser distancemeter (true)": (80.4, 74.4, 76.1)}


def _window_mean(t, values, start, stop):
    rows = (t >= start) & (t <= stop)
    return np.nanmean(values[rows], axis=0), int(rows.sum())


TABLE3_PAPER_UM = {"the Delta robot (encoders)": (1.0, 0.35, 1.0), "the Gough platform": (70.1, 69.2, 64.8),
                   "the laser distancemeter (true)": (65.7, 54.8, 54.9)}


def _displacements(bench: Bench, scenario: str) -> tuple[RunOutput, dict, bool]:
    """The y displacement (um) at each point between the unloaded and the loaded
    machine (the 0.2 s before the load against 0.35-0.55 s after), seen by the Delta's
    encoders (their forward kinematics), the Gough (its DKM pose) and in truth (the
    plant's tool pose: the paper's laser); and whether the reference stood still."""
    from pkm_kinematics import load_machine
    out = bench.run(scenario)
    s, t = out.steps, out.steps["t_s"]
    encoder_position, _ = load_machine("mom3").model.forward_kinematics_batch(s["q"])
    views = {"the Delta robot (encoders)": encoder_position, "the Gough platform": s["gough_position"],
             "the laser distancemeter (true)": s["position"]}
    seen = {k: [] for k in views}
    still = out.status == "completed"
    for on in TABLE2_LOAD_ON_S:
        before, after = (on - WINDOW_S - 0.01, on - 0.01), (on + 0.35, on + 0.35 + WINDOW_S)
        ref_moved = np.nanmax(np.abs(np.diff(s["ref_position"][(t >= before[0]) & (t <= after[1])], axis=0)))
        still = still and ref_moved < 1e-12
        for name, values in views.items():
            a, _ = _window_mean(t, values, *before)
            b, _ = _window_mean(t, values, *after)
            seen[name].append(1e6 * float(b[1] - a[1]))
    return out, seen, still


def _table_outcome(seen: dict, still: bool, paper: dict, load: str, expected_um: float, paper_range: str,
                   encoders_by_construction: bool) -> Outcome:
    enc, gough, true = seen.values()
    o = Outcome()
    held = ("here by construction: the frame load moves the actuation chain rigidly, its dynamics unchanged"
            if encoders_by_construction else "the controller holds them under the load")
    o.check(f"the {load} falls inside the dwells (completed; the reference stands still around each)",
            "still" if still else "the reference moved", still)
    o.check("the Delta robot's control cannot see the deformation (encoders: |dy| <= 1 um, the paper's "
            f"{min(paper['the Delta robot (encoders)']):g}-{max(paper['the Delta robot (encoders)']):g} um; {held})",
            ", ".join(f"{v:.2f}" for v in enc) + " um", max(abs(v) for v in enc) <= 1.0)
    o.check("the Gough platform detects the displacement, confirmed by the laser, the differences within "
            "its resolution (paper: ~6 um; here |Gough - true| <= 6 um)",
            ", ".join(f"{g - tr:+.2f}" for g, tr in zip(gough, true)) + " um",
            max(abs(g - tr) for g, tr in zip(gough, true)) <= 6.0)
    o.table = [["displacement along y (um) seen by", "P1", "P2", "P3", "paper P1", "paper P2", "paper P3"]]
    o.table += [[name, *(f"{v:.2f}" for v in seen[name]), *(f"{v:g}" for v in paper[name])] for name in seen]
    o.notes = ("P1 = (0, 0, 882) mm, P2 = (60, 0, 882) mm, P3 = (-40, 50, 842) mm (the paper does not give "
               f"its points). The true displacement, {', '.join(f'{v:.1f}' for v in true)} um, is the plant's "
               f"compliance times the load by construction ({expected_um:g} um, chosen from the paper's laser: "
               f"{paper_range}); what the experiment shows is that the encoders cannot see it and the Gough can.")
    return o


def mom3_table2(bench: Bench) -> Outcome:
    """MoM3 Table 2: 110 N on the tool at P1-P3 under classical Cartesian control."""
    _, seen, still = _displacements(bench, "mom3_table2")
    return _table_outcome(seen, still, TABLE2_PAPER_UM, "110 N load on the tool", 77.0, "74.4-80.4 um", False)


def mom3_table3(bench: Bench) -> Outcome:
    """MoM3 Table 3: 850 N on the Delta's frame at P1-P3 under classical Cartesian
    control (the plant's frame compliance moves the actuation chain, the tool with it)."""
    _, seen, still = _displacements(bench, "mom3_table3")
    return _table_outcome(seen, still, TABLE3_PAPER_UM, "850 N load on the frame", 59.5, "54.8-65.7 um", True)


def _tilt_mrad(orientation: np.ndarray) -> np.ndarray:
    """The rotation angle (mrad) of quaternions (N, 4: x, y, z, w)."""
    return 2e3 * np.arctan2(np.linalg.norm(orientation[:, :3], axis=1), np.abs(orientation[:, 3]))


def mom3_imperfect(bench: Bench) -> Outcome:
    """MoM3 §4.1 and §6.4: the Delta's parallelograms with unequal bars (the plant's
    ``parallelogram_bar_errors_m``) tilt the platform; the controller knows the perfect
    Delta. Sensor-space control with J_t at the estimated real pose of the Gough
    platform, then at the desired pose: the static tool error at rest after the move."""
    from pkm_kinematics import load_machine
    from pkm_kinematics.parallelogram import ParallelogramMachine
    from pkm_kinematics.rotations import log_so3, rotation_from_quaternion
    from pkm_bringup.scenario import load_scenario
    shipped = load_scenario("mom3_imperfect")
    runs, static = {}, {}
    for variant in ("estimated", "desired"):
        out = bench.run("mom3_imperfect", variant, controller={**shipped.controller, "sensor_jacobian": variant})
        s, t = out.steps, out.steps["t_s"]
        rest = t > t[-1] - 0.1                                    # the end of the dwell at the corner
        runs[variant] = out
        static[variant] = 1e6 * (s["position"] - s["ref_position"])[rest].mean(axis=0)
    s, t = runs["estimated"].steps, runs["estimated"].steps["t_s"]
    rest = t > t[-1] - 0.1
    plant = shipped.plant
    delta = load_machine("mom3").model
    bars = ParallelogramMachine("bars", delta.legs, plant["parallelogram_half_width_m"],
                                plant["parallelogram_bar_errors_m"], delta.home, delta.workspace)
    corner = s["ref_position"][-1]
    expected = 1e3 * float(np.linalg.norm(bars.parasitic_rotation(corner)))
    true_tilt, gough_tilt = _tilt_mrad(s["orientation"][rest]).mean(), _tilt_mrad(s["gough_orientation"][rest]).mean()
    gough_rot = rotation_from_quaternion(np.nanmean(s["gough_orientation"][rest], axis=0))
    true_rot = rotation_from_quaternion(np.nanmean(s["orientation"][rest], axis=0))
    gough_off = 1e3 * float(np.linalg.norm(log_so3(gough_rot @ true_rot.T)))
    est, des = (float(np.linalg.norm(static[v])) for v in ("estimated", "desired"))
    completed = all(r.status == "completed" for r in runs.values())
    o = Outcome()
    o.check("§4.1: unequal parallelogram bars tilt the platform (the plant's tilt is the imperfect Delta "
            "model's at the corner, within 0.01 mrad)", f"{true_tilt:.3f} mrad (model {expected:.3f})",
            completed and abs(true_tilt - expected) <= 0.01)
    o.check("§4: the Gough platform measures the parasitic tilt that the encoders, read through the perfect "
            "Delta, cannot (its DKM rotation within 0.05 mrad of the true one)",
            f"{gough_tilt:.3f} mrad, {gough_off:.4f} mrad off", gough_off <= 0.05)
    o.check("§6.4: J_t at the estimated real pose: no static error beyond the Gough's 1 um resolution",
            f"{est:.2f} um", est <= 1.0)
    o.check("§6.4: J_t at the desired pose leaves a static error (the paper: some microns), larger than at "
            "the estimated pose (here at least twice)", f"{des:.2f} um, {des / est:.1f} x", des >= 2.0 * est)
    o.table = [["J_t evaluated at", "static error x, y, z (um)", "|error| (um)"]]
    o.table += [[f"the {v} pose", ", ".join(f"{c:+.2f}" for c in static[v]), f"{np.linalg.norm(static[v]):.2f}"]
                for v in ("estimated", "desired")]
    o.notes = (f"The tool moves from home to (100, -80, 800) mm and holds; the static error is the mean of "
               f"true tool position minus reference over the last 0.1 s of the hold. Bar errors "
               f"{', '.join(f'{1e6 * e:g}' for e in plant['parallelogram_bar_errors_m'])} um (twice those of "
               f"config/machines/mom3_imperfect.yaml; the paper gives none): with half of them (1.8 mrad) both "
               f"variants stay within the resolution, 0.49 and 0.53 um here; with 4x (7 mrad), 1.6 and 3.1 um. "
               f"The estimate of the real pose is first order (x_h,des - J_h e_l), so the estimated variant "
               f"keeps a second-order error that grows with the tilt.")
    return o


def mom3_dosr(bench: Bench) -> Outcome:
    """MoM3 §3: the degree of sensor redundancy, dosr = C - (M - O + D), of the paper's
    examples and of every machine here with and without its metrology, in the perfect
    (M = O) and imperfect (M = 6) cases (analysis.sensor_redundancy; ``pkm-analyze
    dosr`` prints the same table). No run: a count of measures."""
    from pkm_kinematics import load_machine, machine_names
    from pkm_kinematics.analysis import degree_of_sensor_redundancy, sensor_redundancy
    rows = {}
    for name in machine_names():
        cfg = load_machine(name)
        for r in sensor_redundancy(cfg.model.n_legs, cfg.metrology is not None, cfg.model.task_dof,
                                    cfg.model.spatiality):
            rows[(name, r.sensors)] = r
    o = Outcome()
    o.check("Fig. 5: one measure of a prismatic joint is iso-measured (dosr 0) in the perfect case, "
            "under-measured (-1) with parasitic motion along a second axis (M = 2)",
            f"{degree_of_sensor_redundancy(1, 1, 1, 1)}, {degree_of_sensor_redundancy(1, 2, 1, 1)}",
            (degree_of_sensor_redundancy(1, 1, 1, 1), degree_of_sensor_redundancy(1, 2, 1, 1)) == (0, -1))
    archi = rows[("archi", "encoders")]
    o.check("Fig. 7: a 3-DOF machine with actuation redundancy measured at its 4 drives is over-measured "
            "(dosr 1, perfect case): ARCHI's encoders", f"dosr {archi.dosr_perfect}", archi.dosr_perfect == 1)
    delta, gough = rows[("mom3", "encoders")], rows[("mom3", "gough struts")]
    o.check("§4: the Gough platform's 6 measures make MoM3 iso-measured even with parasitic motions "
            "(imperfect case, M = 6: dosr 0), where its 3 drive encoders are under-measured",
            f"Gough struts {gough.dosr_imperfect}, encoders {delta.dosr_imperfect}",
            gough.dosr_imperfect == 0 and delta.dosr_imperfect < 0)
    o.table = [["machine", "sensors", "C", "dosr, perfect (M = O)", "dosr, imperfect (M = 6)"]]
    o.table += [[m, r.sensors, str(r.c), str(r.dosr_perfect), str(r.dosr_imperfect)] for (m, _), r in rows.items()]
    return o


def mom3_gough_table1(bench: Bench) -> Outcome:
    """MoM3 §5.5-5.6, Table 1: the Gough metrology's worst-case resolution over the
    300 mm cube (eq. 20-21: 1 um scales, the 2^6 strut-error vertices and the 8 tool-box
    corners) at the paper's geometry, against the figures the paper gives for it. No
    run: the criterion of the geometry optimisation, evaluated (analysis.gough_resolution,
    ``pkm-analyze resolution --machine mom3``)."""
    from pkm_kinematics import load_machine
    from pkm_kinematics.analysis import gough_resolution
    met = load_machine("mom3").metrology
    res = gough_resolution(met.platform, met.encoder_resolution_m, met.tool_box, met.workspace_center,
                           met.workspace_size_m, 7)
    o = Outcome()
    o.check("Table 1's geometry gives about 12 um at tool level (within 10 %)", f"{1e6 * res.tool_m:.2f} um",
            abs(res.tool_m - 12e-6) <= 1.2e-6)
    o.check("and about 6 um in position, about 30 urad of tilt (within 15 %)",
            f"{1e6 * res.position_m:.2f} um, {1e6 * res.tilt_rad:.1f} urad",
            abs(res.position_m - 6e-6) <= 0.9e-6 and abs(res.tilt_rad - 30e-6) <= 4.5e-6)
    o.check("its struts stay within [634, 1080] mm over the cube (§5.6)",
            f"{1e3 * res.strut_range[0]:.1f} to {1e3 * res.strut_range[1]:.1f} mm", res.struts_within_limits)
    o.table = [["figure", "ours", "paper"], ["tool-level resolution (um)", f"{1e6 * res.tool_m:.2f}", "12"],
               ["position resolution (um)", f"{1e6 * res.position_m:.2f}", "about 6"],
               ["tilt resolution (urad)", f"{1e6 * res.tilt_rad:.1f}", "about 30"],
               ["strut lengths (mm)", f"{1e3 * res.strut_range[0]:.1f} .. {1e3 * res.strut_range[1]:.1f}",
                "634 .. 1080"]]
    o.notes = ("`pkm-analyze gough-optimize` does not return Table 1: under the constraints the paper states, "
               "Table 1 is not optimal (closing the joint pairs up to our 2 deg bound, 2.6 mm apart, gives "
               "7.2 um); the paper must have bounded the joint spacing without saying so. "
               "docs/investigations/gough_optimisation.md has the analysis and the proposed joint-spacing "
               "constraint.")
    return o


FIG19_LOADS_N = (0.0, 110.0, 140.0)
FIG19_CONTROLS = {"classical Cartesian (encoders)": "computed_torque", "sensor space (Gough struts)": "sensor_space"}
FIG19_FROM_S = 0.6       # the square starts (settle_s): the load, on at 0.05-0.15 s, has settled


def mom3_fig19(bench: Bench) -> Outcome:
    """MoM3 Figure 19: the square under 0, 110 and 140 N on the tool, classical
    Cartesian control (encoders) against sensor-space control (Gough struts): the tool
    error (true tool against the reference) over the square, the load on and settled."""
    errors: dict = {}
    for label, strategy in FIG19_CONTROLS.items():
        for load in FIG19_LOADS_N:
            out = bench.run("mom3_fig19", label=f"{strategy}_{load:.0f}N",
                            controller={"strategy": strategy, "distribution": "pseudo_inverse"},
                            load=[{"t_s": 0.05, "wrench": [load, 0.0, 0.0], "ramp_s": 0.1}] if load else [])
            s = out.steps
            rows = s["t_s"] >= FIG19_FROM_S
            e = np.linalg.norm(s["position"][rows] - s["ref_position"][rows], axis=1)
            errors[(label, load)] = (out.status, float(np.sqrt(np.nanmean(e * e))), float(np.nanmax(e)))
    o = Outcome()
    classical, sensor = FIG19_CONTROLS
    o.check("all six runs complete", ", ".join(sorted({v[0] for v in errors.values()})),
            all(v[0] == "completed" for v in errors.values()))
    c0, c140 = errors[(classical, 0.0)][1], errors[(classical, 140.0)][1]
    o.check("classical Cartesian control: a 140 N load (at least) doubles the tool position error",
            f"RMS {1e6 * c0:.1f} um at 0 N, {1e6 * c140:.1f} um at 140 N", c140 >= 2.0 * c0)
    s0, s140 = errors[(sensor, 0.0)][1], errors[(sensor, 140.0)][1]
    o.check("sensor-space control: the load does not change the accuracy (RMS error at 140 N within 2 um of "
            "the one at 0 N; the Gough's tool-level resolution is ~11 um worst case)",
            f"RMS {1e6 * s0:.1f} um at 0 N, {1e6 * s140:.1f} um at 140 N", abs(s140 - s0) <= 2e-6)
    o.check("sensor-space control gives better results than classical Cartesian control under load "
            "(lower RMS error at 110 and 140 N)", "; ".join(
                f"{load:.0f} N: {1e6 * errors[(sensor, load)][1]:.1f} against {1e6 * errors[(classical, load)][1]:.1f} um"
                for load in FIG19_LOADS_N[1:]),
            all(errors[(sensor, load)][1] < errors[(classical, load)][1] for load in FIG19_LOADS_N[1:]))
    o.table = [["control", *(f"{load:.0f} N: RMS / max tool error (um)" for load in FIG19_LOADS_N)]]
    o.table += [[label, *(f"{1e6 * errors[(label, load)][1]:.1f} / {1e6 * errors[(label, load)][2]:.1f}"
                          for load in FIG19_LOADS_N)] for label in FIG19_CONTROLS]
    o.notes = ("The nominal Delta stands for the paper's calibrated one: without a load, its classical "
               "control is as accurate as the encoders; the paper's calibrated robot kept residual errors, "
               "so its 'doubling' starts from a larger error than ours.")
    return o


# ------------------------------------------------------------------ Sliding Star §3
STAR_STRATEGIES = ("joint_pid", "decentralized_projected", "decentralized_integral_projected", "cartesian_pid")
FORCE_LIMIT_N = 2000.0                   # config/controller defaults and the plant's


def sliding_star_fighting(bench: Bench) -> Outcome:
    """Sliding Star §3: a 2 % link error; cascade joint PIDs fight up to saturation; the
    eq. 8 projection (Fig. 8), its lab variant on the integral only (Fig. 9) and the
    centralized Cartesian control (eq. 9) against the same error."""
    runs = {st: bench.run("sliding_star_fighting", label=st, controller={"strategy": st}) for st in STAR_STRATEGIES}
    internal = {st: _internal_force(r, "sliding_star") for st, r in runs.items()}
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
    _fighting_table_and_plot(bench, o, runs, internal, peak_force, "drive", "Sliding Star, 2 % error on link s3",
                             "sliding_star_fighting.png")
    o.notes = ("The Fig. 9 variant stops the growth but keeps the static fight of the proportional terms: "
               f"{tail.mean():.0f} N of internal force here, against {np.nanmax(internal['decentralized_projected']):.0f} N "
               "with the full projection (Fig. 8). The paper reports the variant applicable on its lab model, "
               "without a figure of its internal force; with this project's gains and a 2 % error it holds the "
               "machine at over 1.5 kN of drive force.")
    return o


def _fighting_table_and_plot(bench: Bench, o: Outcome, runs: dict, internal: dict, peak_force: dict, drive: str,
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
    o.figures.append(_plot(bench, figure, draw))


# ------------------------------------------------------------------ the hexapods
HEXAPOD_STRATEGIES = ("joint_pid", "decentralized_projected", "cartesian_pid")


def hexapod_redundant_fighting(bench: Bench) -> Outcome:
    """Sliding Star §3 on a 6-DOF machine: hexapod8 (8 struts) with strut s1 1 % longer
    than its encoder reads; independent joint PIDs fight up to saturation; the eq. 8
    projection and centralized Cartesian control (eq. 9) hold without fighting."""
    from pkm_bringup.scenario import load_scenario
    shipped = load_scenario("hexapod_redundant_fighting").controller      # its integral time (a stable one)
    runs = {st: bench.run("hexapod_redundant_fighting", label=st, controller={**shipped, "strategy": st})
            for st in HEXAPOD_STRATEGIES}
    internal = {st: _internal_force(r, "hexapod8") for st, r in runs.items()}
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
    _fighting_table_and_plot(bench, o, runs, internal, peak_force, "strut",
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
    from pkm_runs.report_data import rpy_of
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
    o.figures.append(_plot(bench, "hexapod_demo.png", draw, size=(11, 4.0)))
    return o


ONLINE_FK_RUNS = {"newton": "newton", "integrated_euler": "integrated_euler", "integrated (midpoint)": "integrated"}
RESYNC_CYCLES = 50


def _integrated_drift(out: RunOutput, order: int, resync: int) -> tuple[np.ndarray, np.ndarray]:
    """The controller's integrated encoder pose, recomputed from the recorded readings
    with the same function and schedule (pkm_kinematics.online_fk; Newton at the first
    cycle and every ``resync``), against the Newton solution of the same readings: the
    translation (m) and yaw (rad) drift per step."""
    from pkm_kinematics import load_machine
    from pkm_kinematics.online_fk import integrate_forward_kinematics
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
    rms = {label: float(np.sqrt(np.nanmean(_tracking_error_m(r) ** 2))) for label, r in runs.items()}
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
    o.figures.append(_plot(bench, "sliding_star_online_fk.png", draw))
    return o


# ------------------------------------------------------------------ Orthoglide
OG_SPEED_M_S, OG_ACCEL_M_S2 = 1.2, 14.0      # the prototype's targets
OG_PSI = (0.5, 2.0)                          # eq. 17
OG_GRID = 21                                 # points per axis of the cube map


def orthoglide_cube(bench: Bench) -> Outcome:
    """The Orthoglide's prescribed cube at the prototype's speed and acceleration: the
    velocity transmission factors along the measured path and over the whole cube
    (eq. 17: 1/2 <= psi <= 2), the parallel-singularity measure over the cube, and the
    refusal of a pose near a parallel singularity."""
    from pkm_kinematics import load_machine
    from pkm_kinematics.analysis import cube_points
    from pkm_kinematics.errors import SingularityError
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
    o.figures.append(_plot(bench, "orthoglide_cube.png", draw, size=(11, 4.5)))
    return o


EXPERIMENTS: dict[str, Experiment] = {e.name: e for e in (
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
    Experiment("mom3_table2", "A 110 N load on the tool: seen by the Gough and the laser, not by the encoders",
               "MoM3", "§7.1.1, Table 2", ("mom3_table2",), mom3_table2),
    Experiment("mom3_table3", "An 850 N load on the Delta's frame: seen by the Gough and the laser, not by the "
               "encoders", "MoM3", "§7.1.2, Table 3", ("mom3_table3",), mom3_table3),
    Experiment("mom3_dosr", "The degree of sensor redundancy of every machine, with and without its metrology",
               "MoM3", "§3, Fig. 5-7", (), mom3_dosr),
    Experiment("mom3_gough_table1", "The Gough metrology's resolution at the paper's geometry",
               "MoM3", "§5.5-5.6, Table 1", (), mom3_gough_table1),
    Experiment("mom3_imperfect", "The imperfect Delta: the Gough sees the parasitic tilt; J_t at the estimated "
               "against the desired pose", "MoM3", "§4.1, §6.4", ("mom3_imperfect",), mom3_imperfect),
    Experiment("mom3_fig19", "Classical Cartesian against sensor-space control under 0, 110 and 140 N",
               "MoM3", "§7.2, Figure 19", ("mom3_fig19",), mom3_fig19),
    Experiment("sliding_star_fighting", "Drive fighting under a 2 % link error, and its cures",
               "Sliding Star", "§3, eq. 6-9, Fig. 7-9", ("sliding_star_fighting",), sliding_star_fighting),
    Experiment("sliding_star_online_fk", "On-line forward kinematics by integrating the differential kinematics",
               "Sliding Star", "§3.1", ("sliding_star_online_fk",), sliding_star_online_fk),
    Experiment("hexapod_demo", "The Gough-Stewart hexapod follows a 6-DOF program (X Y Z A B C) under computed "
               "torque in SE(3)", "LinuxCNC", "genhexkins", ("hexapod_demo",), hexapod_demo),
    Experiment("hexapod_redundant_fighting", "Drive fighting on an 8-strut hexapod under a 1 % strut error, and "
               "its cures", "Sliding Star", "§3, eq. 6-9 (on 6 DOF)", ("hexapod_redundant_fighting",),
               hexapod_redundant_fighting),
    Experiment("hexapod_metrology", "A hexapod's strut errors, unseen by its encoders, removed by control on a "
               "Gough metrology", "MoM3", "§6.3-6.4 (on 6 DOF)", ("hexapod_metrology",), hexapod_metrology),
    Experiment("orthoglide_cube", "The prescribed cube at 1.2 m/s and 14 m/s^2: transmission factors and "
               "parallel singularities", "Orthoglide", "§3.3, §4.3-4.4, eq. 17", ("orthoglide_cube",), orthoglide_cube),
)}

# the papers' experiments not run here yet, and why: (name, where in the paper, why),
# listed in results.md (none left: the last ones, MoM3 Table 3 and Sliding Star's
# on-line forward kinematics, are experiments above)
PENDING: tuple[tuple[str, str, str], ...] = ()
