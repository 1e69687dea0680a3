"""The MoM3 paper's experiments (Corbel et al., ASME JMR 2010): loads seen by the Gough
metrology and not by the encoders (Tables 2, 3), the degree of sensor redundancy, the
Gough's resolution (Table 1), the imperfect Delta and sensor-space control (Figure 19).
"""

from __future__ import annotations

import numpy as np

from pkm_bringup.scenario import load_scenario
from pkm_gallery.framework import Bench, Experiment, Outcome, RunOutput
from pkm_kinematics import load_machine, machine_names
from pkm_kinematics.analysis import degree_of_sensor_redundancy, gough_resolution, sensor_redundancy
from pkm_kinematics.parallelogram import ParallelogramMachine
from pkm_kinematics.rotations import log_so3, rotation_from_quaternion

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


EXPERIMENTS = (
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
)
