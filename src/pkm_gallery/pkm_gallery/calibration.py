"""Calibration (issue 44): the papers' errors made to vanish by identifying the machine's
real geometry from its own measurements (pkm_calibration).

- ``archi_calibration``: ARCHI with archi_fig12's 2 % error on leg 3 runs its
  calibration program (pkm-calibrate plan: 30 poses by the observability index O1),
  identifies its geometry from its four encoders' inconsistency alone (self-calibration,
  no instrument: MoM3 §3's dosr = 1), and runs archi_fig12's joint PIDs again on the
  calibrated model: the internal force at rest and the saturation trip of ARCHI §4.1
  against the nominal model's, and against a machine without the error. The same
  machine calibrated with a laser tracker instead (archi_laser_calibration): every
  parameter identified, the frames included.
- ``genhexkins_calibration``: LinuxCNC's hexapod as built (pkm-calibrate as-built:
  every joint and every encoder's scale off) calibrated with a laser tracker on its
  tool point: the identified parameters against the plant's true ones within their
  predicted standard deviations (chi-square of this run; over 200 seeds of the same
  poses and noise, the statistic's mean and its 95 % band), and the tool error on the
  poses kept out of the identification (every fourth), before and after.
- ``mom3_calibration``: MoM3's Delta as built (its parallelograms' lengths and its
  encoders' zeros off) calibrated with its own Gough metrology; then MoM3 §7's square
  (mom3_fig19) under classical Cartesian control on the encoders, on the nominal and
  on the calibrated model, against sensor-space control on the Gough, without and with
  Table 2's 110 N: how much of the gap calibration closes, and what it cannot (the load
  deflection stays invisible to the encoders).
- ``mom3_compensation``: the same Delta whose ball screws are also off along their
  travel (a repeatable error no geometric parameter explains): each drive's
  compensation table (LinuxCNC's COMP_FILE) identified with the geometry from the same
  kind of run, and the square under classical control on the calibrated model without
  and with the tables.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from pkm_calibration.as_built import as_built_struts, strut_gauge
from pkm_calibration.identify import identify
from pkm_calibration.machine_files import write_machine_file
from pkm_calibration.poses import candidate_poses
from pkm_calibration.procedure import calibrated_machine_data, identify_run
from pkm_calibration.strut_errors import StrutErrorModel
from pkm_bringup.scenario import load_scenario
from pkm_gallery.framework import Bench, Experiment, Outcome, internal_force
from pkm_gallery.mom3 import FIG19_FROM_S
from pkm_kinematics import load_machine

LEG_ERROR = 0.02                 # archi_fig12: leg 3 2 % long (config/scenarios/archi_fig12.yaml)
ARCHI_REFLECTOR = (0.1, 0.05, 0.0)   # archi_laser_calibration's laser tracker, nacelle frame (m)


def _rest(force: np.ndarray, t_s: np.ndarray) -> float:
    """The internal force at rest: its mean over the run's last 0.5 s."""
    return float(np.mean(force[t_s >= t_s[-1] - 0.5]))


def archi_calibration(bench: Bench) -> Outcome:
    config = load_machine("archi")
    bench.run("archi_calibration")
    result = identify_run(config, bench.work / "archi_calibration")
    names = list(result.names)
    truth = np.zeros(len(names))
    truth[names.index("length.q3")] = LEG_ERROR * float(config.data["legs"][2]["link_length"])
    free = list(result.identifiable.identified)
    statistic, bound = result.chi_square(truth), float(chi2.ppf(0.999, len(free)))
    path = write_machine_file(bench.work / "archi.calibrated.yaml",
                              calibrated_machine_data(config, result, "archi_calibration (gallery)",
                                                      str(bench.work / "archi_calibration")))
    q3 = names.index("length.q3")
    bench.run("archi_laser_calibration")
    laser = identify_run(config, bench.work / "archi_laser_calibration", "laser", tool=ARCHI_REFLECTOR,
                         validate_every=4)
    laser_path = write_machine_file(bench.work / "archi.laser.calibrated.yaml",
                                    calibrated_machine_data(config, laser, "archi_laser_calibration (gallery)",
                                                            str(bench.work / "archi_laser_calibration")))
    laser_free = list(laser.identifiable.identified)
    laser_statistic, laser_bound = laser.chi_square(truth), float(chi2.ppf(0.999, len(laser_free)))

    runs = {}
    for label, model, plant, controller in (
            ("nominal model, no integral", None, None, {"strategy": "joint_pid", "integral_time_s": 0.0}),
            ("calibrated model, no integral", path, None, {"strategy": "joint_pid", "integral_time_s": 0.0}),
            ("laser-calibrated model, no integral", laser_path, None,
             {"strategy": "joint_pid", "integral_time_s": 0.0}),
            ("no leg error, no integral", None, {"link_length_errors": [0.0] * 4},
             {"strategy": "joint_pid", "integral_time_s": 0.0}),
            ("nominal model, with integral", None, None, {"strategy": "joint_pid"}),
            ("calibrated model, with integral", path, None, {"strategy": "joint_pid"})):
        overrides = {"controller": controller, **({"model": str(model)} if model else {}),
                     **({"plant": plant} if plant else {})}
        runs[label] = bench.run("archi_fig12", label=label.replace(", ", "_").replace(" ", "_"), **overrides)
    rest = {k: _rest(internal_force(r), r.steps["t_s"]) for k, r in runs.items()}

    o = Outcome()
    o.check("self-calibration, no instrument: archi_fig12's 2 % leg error (20 mm on leg 3) identified from the "
            "four encoders at the calibration program's dwells, within 3 standard deviations (1 um encoder counts: "
            "tens of um)", f"{1e3 * result.theta[q3]:.4f} mm, std {1e3 * result.std[q3]:.4f} mm, {result.dwells} "
                           f"dwells", abs(result.theta[q3] - truth[q3]) < 3.0 * result.std[q3] < 1e-4)
    o.check("every identified parameter within its predicted uncertainty: the chi-square of the errors with "
            f"their predicted covariance below its 99.9 % quantile ({len(free)} degrees of freedom)",
            f"{statistic:.2f} < {bound:.2f}", statistic < bound)
    o.check("what the redundancy cannot identify is named and held at nominal, not fitted (the base's and the "
            "platform's frames: 5 of 20)", result.identifiable.describe(), len(result.identifiable.held) == 5)
    o.check("the encoders' inconsistency explained: closure residual RMS from millimetres (the nominal model) to "
            "below 1 um (the encoders' 1 um count)",
            f"{1e6 * result.misfit_before_m:.1f} um -> {1e6 * result.misfit_after_m:.3f} um",
            result.misfit_before_m > 1e-3 and result.misfit_after_m < 1e-6)
    v = laser.extra["validation"]
    o.check("laser calibration: with a tracker on a reflector off the nacelle's centre every parameter of the "
            "machine is identified but the nacelle's angle datum (the tracker's frame is the base's; self-calibration: "
            "5 held), 20 mm on leg 3 within 3 standard deviations, "
            "chi-square below its 99.9 % quantile, the tool point on dwells kept out from the nominal model's "
            "millimetres to micrometres",
            f"{laser.identifiable.describe()}; length.q3 {1e3 * laser.theta[q3]:.4f} mm, std "
            f"{1e3 * laser.std[q3]:.4f} mm; chi-square {laser_statistic:.1f} < {laser_bound:.1f}; validation RMS "
            f"{1e6 * v['rms_before_m']:.1f} -> {1e6 * v['rms_after_m']:.2f} um",
            abs(laser.theta[q3] - truth[q3]) < 3.0 * laser.std[q3] and laser_statistic < laser_bound
            and len(laser.identifiable.held) == 4
            and v["rms_after_m"] < 1e-5 < 1e-3 < v["rms_before_m"])
    nominal, calibrated, floor = (rest["nominal model, no integral"], rest["calibrated model, no integral"],
                                  rest["no leg error, no integral"])
    o.check("ARCHI §4.1 on the calibrated model: joint PIDs without the integral hold the machine with an "
            "internal force at rest below 5 % of the nominal model's, within 5 N of a machine without the error "
            "(whose proportional-only loops leave some: gravity)",
            f"{calibrated:.1f} N against {nominal:.1f} N (a machine without the error: {floor:.1f} N)",
            calibrated < 0.05 * nominal and abs(calibrated - floor) < 5.0)
    with_i, cal_i = runs["nominal model, with integral"], runs["calibrated model, with integral"]
    o.check("and with the integral: no fight, no saturation trip (the nominal model: tripped, saturation)",
            f"nominal: {with_i.status} ({with_i.cause}); calibrated: {cal_i.status} ({cal_i.cause}), "
            f"{rest['calibrated model, with integral']:.1f} N at rest",
            with_i.status == "tripped" and cal_i.status == "completed"
            and rest["calibrated model, with integral"] < 0.05 * nominal)
    o.table = [["joint PIDs (archi_fig12)", "status", "cause", "internal force at rest (N)",
                "peak drive force (N)"]]
    o.table += [[k, r.status, r.cause, f"{rest[k]:.1f}", f"{np.nanmax(np.abs(r.steps['applied'])):.1f}"]
                for k, r in runs.items()]
    o.notes = ("Identified (um, with standard deviations from the encoders' 1 um count):\n\n"
               + "\n".join(f"- {n}: {v} +- {s}" for n, v, s in result.table()[1:]))
    return o


AS_BUILT_SEED = 44              # config/scenarios/genhexkins_calibration.yaml's machine
TOOL = (0.0, 0.0, -0.05)        # its laser tracker's reflector, platform frame (m)
SEEDS = 200                     # the chi-square's distribution over noise draws


def genhexkins_calibration(bench: Bench) -> Outcome:
    config = load_machine("genhexkins")
    model = StrutErrorModel(config.model, TOOL)
    pool = candidate_poses(config.model, 200, AS_BUILT_SEED)          # as pkm-calibrate as-built drew them
    held = strut_gauge(model, config.model.inverse_kinematics_batch(pool)[0])
    _, truth, _ = as_built_struts(config, model, held, AS_BUILT_SEED)
    run = bench.run("genhexkins_calibration")
    result = identify_run(config, bench.work / "genhexkins_calibration", "laser", tool=TOOL, validate_every=4)
    free = list(result.identifiable.identified)
    z = (result.theta[free] - truth[free]) / result.std[free]
    statistic, bound = result.chi_square(truth), float(chi2.ppf(0.999, len(free)))
    # the same identification over noise draws at the run's readings (what the encoders
    # read there, the tracker's points from the truth plus the run's sigma)
    from pkm_calibration.recorded import read_calibration_run
    readings = read_calibration_run(bench.work / "genhexkins_calibration", config, instrument="laser")
    q = readings.readings[np.arange(len(readings.readings)) % 4 != 3]
    exact = model.predict(truth, q).y
    rng = np.random.default_rng(0)
    draws = []
    for _ in range(SEEDS):
        y = exact + result.extra["sigma_m"] * rng.standard_normal(exact.shape)
        r = identify(model, q, y, result.extra["sigma_m"], held=held)
        d = r.theta[free] - truth[free]
        draws.append(float(d @ np.linalg.solve(r.covariance, d)))
    draws = np.array(draws)
    lo, hi = chi2.ppf([0.025, 0.975], len(free))
    inside = float(np.mean((draws > lo) & (draws < hi)))
    v = result.extra["validation"]
    path = write_machine_file(bench.work / "genhexkins.calibrated.yaml", calibrated_machine_data(
        config, result, "genhexkins_calibration (gallery)", str(bench.work / "genhexkins_calibration")))
    scenario = load_scenario("genhexkins_calibration")
    demo = {}           # hexapod_demo's 6-axis program on the machine as built, the controller on each model
    for label, model in (("nominal", "genhexkins"), ("calibrated", str(path))):
        out = bench.run("hexapod_demo", label=f"hexapod_demo_{label}", machine=scenario.machine, model=model,
                        plant={"link_length_errors": scenario.plant["link_length_errors"]})
        st = out.steps
        e = np.linalg.norm(st["position"] - st["ref_position"], axis=1)
        demo[label] = (out.status, float(np.sqrt(np.nanmean(e * e))), float(np.nanmax(e)))
    o = Outcome()
    o.check("a laser tracker on the tool point identifies what one point can (45 of 54: the tracker's frame and "
            "the platform's turn about the point named and held), the residuals from the nominal model's to the "
            "readings' noise",
            f"{result.identifiable.describe()}; {1e6 * result.misfit_before_m:.1f} um -> "
            f"{1e6 * result.misfit_after_m:.3f} um RMS (sigma {1e6 * result.extra['sigma_m']:.2f} um)",
            len(free) == 45 and result.misfit_after_m < 3.0 * result.extra["sigma_m"])
    o.check("the identified parameters are the plant's true ones within their predicted standard deviations: "
            "chi-square of this run below its 99.9 % quantile, and over 200 noise draws its mean within 10 % of "
            "the degrees of freedom and 90-99 % of the draws in the 95 % band",
            f"this run {statistic:.1f} < {bound:.1f}; draws: mean {draws.mean():.1f} ({len(free)} dof), "
            f"{100 * inside:.1f} % in [{lo:.1f}, {hi:.1f}]",
            statistic < bound and abs(draws.mean() / len(free) - 1.0) < 0.1 and 0.9 <= inside <= 0.99)
    o.check(f"validation on the {v['dwells']} poses kept out: the tool error of the nominal model (the as-built "
            "machine's hundreds of micrometres) brought to the tracker's noise (below 1 um)",
            f"RMS {1e6 * v['rms_before_m']:.1f} um -> {1e6 * v['rms_after_m']:.2f} um, max "
            f"{1e6 * v['max_before_m']:.1f} um -> {1e6 * v['max_after_m']:.2f} um",
            v["rms_before_m"] > 1e-4 and v["rms_after_m"] < 1e-6)
    o.check("the calibration run itself: completed on the nominal model (its tracking error is the model's)",
            f"{run.status}", run.status == "completed")
    o.check("the calibrated file (its joints, and its encoders' zeros and scales as compensation tables) as the "
            "controller's model: hexapod_demo's 6-axis program on the machine as built, the platform's error "
            "from the nominal model's hundreds of micrometres to below 10 um RMS",
            f"nominal {1e6 * demo['nominal'][1]:.1f} um RMS ({1e6 * demo['nominal'][2]:.1f} max), calibrated "
            f"{1e6 * demo['calibrated'][1]:.2f} um RMS ({1e6 * demo['calibrated'][2]:.2f} max)",
            demo["nominal"][0] == demo["calibrated"][0] == "completed" and demo["nominal"][1] > 1e-4
            and demo["calibrated"][1] < 1e-5)
    o.table = [["figure", "value"], ["poses identified / validated", f"{result.dwells} / {v['dwells']}"],
               ["tool error before (nominal model), RMS / max um", f"{1e6 * v['rms_before_m']:.1f} / "
                                                                  f"{1e6 * v['max_before_m']:.1f}"],
               ["tool error after (identified), RMS / max um", f"{1e6 * v['rms_after_m']:.2f} / "
                                                              f"{1e6 * v['max_after_m']:.2f}"],
               ["chi-square of this run (dof)", f"{statistic:.1f} ({len(free)})"],
               ["largest |error| / std", f"{np.abs(z).max():.2f}"],
               ["hexapod_demo, platform error RMS / max um: nominal model", f"{1e6 * demo['nominal'][1]:.1f} / "
                                                                          f"{1e6 * demo['nominal'][2]:.1f}"],
               ["hexapod_demo, calibrated model", f"{1e6 * demo['calibrated'][1]:.2f} / "
                                                  f"{1e6 * demo['calibrated'][2]:.2f}"]]
    return o


MOM3_PLANT = {"link_length_errors": [0.002, -0.0015, 0.001],       # config/scenarios/mom3_calibration.yaml
              "rail_offset_errors_m": [0.0005, -0.0008, 0.0003]}
MOM3_COMPLIANCE = [7.0e-7, 7.0e-7, 7.0e-7]                          # mom3_fig19's (Table 2: 77 um under 110 N)


def _square_error(bench: Bench, label: str, strategy: str, plant: dict, model=None, load_n: float = 0.0) -> tuple:
    """(status, RMS, max) of the tool error over mom3_fig19's square, under ``load_n`` on
    the tool (x), the controller on ``model`` (default: the machine's)."""
    out = bench.run("mom3_fig19", label=label, controller={"strategy": strategy, "distribution": "pseudo_inverse"},
                    plant=plant, load=[{"t_s": 0.05, "wrench": [load_n, 0.0, 0.0], "ramp_s": 0.1}] if load_n else [],
                    **({"model": str(model)} if model else {}))
    st = out.steps
    rows = st["t_s"] >= FIG19_FROM_S
    e = np.linalg.norm(st["position"][rows] - st["ref_position"][rows], axis=1)
    return out.status, float(np.sqrt(np.nanmean(e * e))), float(np.nanmax(e))


def mom3_calibration(bench: Bench) -> Outcome:
    config = load_machine("mom3")
    run = bench.run("mom3_calibration")
    result = identify_run(config, bench.work / "mom3_calibration", "gough", validate_every=4)
    names = list(result.names)
    truth = np.zeros(len(names))
    for k, leg in enumerate(config.model.leg_names):
        length = config.data["legs"][k]["link_length"]
        truth[names.index(f"length.{leg}")] = MOM3_PLANT["link_length_errors"][k] * length
        truth[names.index(f"zero.{leg}")] = MOM3_PLANT["rail_offset_errors_m"][k]
    free = list(result.identifiable.identified)
    statistic, bound = result.chi_square(truth), float(chi2.ppf(0.999, len(free)))
    worst = float(np.max(np.abs(result.theta[free] - truth[free]) / result.std[free]))
    path = write_machine_file(bench.work / "mom3.calibrated.yaml",
                              calibrated_machine_data(config, result, "mom3_calibration (gallery)",
                                                      str(bench.work / "mom3_calibration")))
    errors = {}
    for label, strategy, model in (("classical (encoders), nominal model", "computed_torque", None),
                                   ("classical (encoders), calibrated model", "computed_torque", path),
                                   ("sensor space (Gough struts), nominal model", "sensor_space", None)):
        for load in (0.0, 110.0):
            errors[(label, load)] = _square_error(bench, f"{strategy}_{'calibrated' if model else 'nominal'}_"
                                                         f"{load:.0f}N", strategy,
                                                  {**MOM3_PLANT, "compliance": MOM3_COMPLIANCE}, model, load)
    nominal, calibrated, sensor = (k for k, _ in list(errors)[::2])
    v = result.extra["validation"]
    o = Outcome()
    o.check("the Gough as the instrument: the Delta's lengths and encoder zeros identified, each within 3 standard "
            "deviations of the plant's, chi-square below its 99.9 % quantile; the Gough's frame (the base) and the "
            "joints' heights along the rails (their zeros') named and held",
            f"largest |error| {worst:.2f} std; chi-square {statistic:.1f} < {bound:.1f} ({len(free)} parameters); "
            f"held: {', '.join(names[k] for k in result.identifiable.held)}",
            run.status == "completed" and worst < 3.0 and statistic < bound)
    o.check("validation on the dwells kept out: the Gough's tool position predicted from the encoders, from the "
            "nominal model's error to the Gough's resolution (below 2 um)",
            f"RMS {1e6 * v['rms_before_m']:.1f} um -> {1e6 * v['rms_after_m']:.2f} um ({v['dwells']} dwells)",
            v["rms_after_m"] < 2e-6 and v["rms_before_m"] > 1e-4)
    n0, c0, s0 = errors[(nominal, 0.0)][1], errors[(calibrated, 0.0)][1], errors[(sensor, 0.0)][1]
    closed = (n0 - c0) / (n0 - s0)
    o.check("MoM3 §7 after calibration, no load: classical control on the encoders closes at least 95 % of its gap "
            "to sensor-space control (tool error RMS over the square)",
            f"nominal {1e6 * n0:.1f} um, calibrated {1e6 * c0:.1f} um, sensor space {1e6 * s0:.1f} um: "
            f"{100 * closed:.1f} % closed", all(st == "completed" for st, _, _ in errors.values()) and closed > 0.95)
    c110, s110 = errors[(calibrated, 110.0)][1], errors[(sensor, 110.0)][1]
    o.check("what calibration cannot do (MoM3 Table 2): under 110 N the calibrated encoders' error grows by the "
            "deflection they cannot see (at least 50 um more), sensor-space control's stays within 2 um",
            f"calibrated {1e6 * c0:.1f} -> {1e6 * c110:.1f} um; sensor space {1e6 * s0:.1f} -> {1e6 * s110:.1f} um",
            c110 - c0 > 50e-6 and abs(s110 - s0) <= 2e-6)
    _check_gough_off(bench, o, config, truth)
    o.table = [["control (the Delta as built)", "0 N: RMS / max tool error (um)", "110 N: RMS / max (um)"]]
    o.table += [[label, *(f"{1e6 * errors[(label, load)][1]:.1f} / {1e6 * errors[(label, load)][2]:.1f}"
                          for load in (0.0, 110.0))] for label in (nominal, calibrated, sensor)]
    o.notes = ("Identified (um, with standard deviations):\n\n"
               + "\n".join(f"- {n}: {val} +- {sd}" for n, val, sd in result.table()[1:]))
    return o


GOUGH_JOINT_ERROR_M = 2e-4      # the Gough's own joints off (per axis, std): its sensor's calibration_error_m


def _check_gough_off(bench: Bench, o: Outcome, config, truth) -> None:
    """The same calibration with the Gough's own joints off: by its pose (its forward
    kinematics on its nominal joints) and strut by strut with its joints identified too
    (gough_errors)."""
    label = "mom3_calibration_gough_off"
    run = bench.run("mom3_calibration", label=label, sensor={"calibration_error_m": GOUGH_JOINT_ERROR_M, "seed": 3})
    by_pose, by_struts = (identify_run(config, bench.work / label, instrument)
                          for instrument in ("gough", "gough-struts"))
    legs = config.model.leg_names
    lengths = [by_struts.names.index(f"length.{leg}") for leg in legs]
    zeros = [by_struts.names.index(f"zero.{leg}") for leg in legs]
    length_std = np.abs(by_struts.theta[lengths] - truth[lengths]) / by_struts.std[lengths]
    pose_mm = np.abs(by_pose.theta[lengths] - truth[lengths]).max() * 1e3
    offsets = by_struts.theta[zeros] - truth[zeros]
    datum = float(offsets.mean())
    spread = np.abs(offsets - datum) / by_struts.std[zeros]
    o.check(f"the Gough's own joints off ({1e3 * GOUGH_JOINT_ERROR_M:g} mm per axis, std): its pose carries them into "
            "the Delta's model (more than 10 um of the readings unexplained); read strut by strut with its joints "
            "identified too, the readings are explained (below 1 um) and the lengths are the plant's within 3 std; "
            "the zeros share one offset, the datum the Gough's held joints give, within 3 std of it",
            f"residual RMS by the pose {1e6 * by_pose.misfit_after_m:.1f} um (lengths up to {pose_mm:.2f} mm off), "
            f"strut by strut {1e6 * by_struts.misfit_after_m:.3f} um (lengths within {length_std.max():.2f} std; "
            f"zeros {1e6 * datum:.1f} um off together, within {spread.max():.2f} std of it); "
            f"{len(by_struts.identifiable.identified)} of {len(by_struts.names)} parameters identified",
            run.status == "completed" and by_pose.misfit_after_m > 10e-6 and by_struts.misfit_after_m < 1e-6
            and length_std.max() < 3.0 and spread.max() < 3.0)


TABLE_SPACING_M = 0.02          # mom3_compensation's knots (the screws' error: a 0.1 m period)


def mom3_compensation(bench: Bench) -> Outcome:
    config = load_machine("mom3")
    scenario = load_scenario("mom3_compensation")
    plant = {**scenario.plant, "compliance": MOM3_COMPLIANCE}
    bench.run("mom3_compensation")
    run_dir = bench.work / "mom3_compensation"
    geometry = identify_run(config, run_dir, "gough", validate_every=4)
    both = identify_run(config, run_dir, "gough", validate_every=4, table_spacing_m=TABLE_SPACING_M)
    files = {}
    for name, result in (("geometry", geometry), ("tables", both)):
        files[name] = write_machine_file(bench.work / f"mom3.{name}.yaml", calibrated_machine_data(
            config, result, f"mom3_compensation ({name}, gallery)", str(run_dir)))
    rms = both.extra["drive_error_rms_m"]
    screws = np.abs(np.asarray(scenario.plant["screw_errors_m"]))
    errors = {"classical (encoders), geometry calibrated": _square_error(bench, "geometry", "computed_torque", plant,
                                                                         files["geometry"]),
              "classical (encoders), geometry and tables": _square_error(bench, "tables", "computed_torque", plant,
                                                                         files["tables"]),
              "sensor space (Gough struts)": _square_error(bench, "sensor", "sensor_space", plant)}
    o = Outcome()
    o.check("the drives' errors the geometry leaves (each screw's, 15-25 um amplitude) taken out by their tables: "
            "the RMS of each drive's true position minus its compensated reading below a quarter of before",
            "; ".join(f"{n}: {1e6 * b:.2f} -> {1e6 * a:.2f} um" for n, b, a in
                      zip(config.model.leg_names, rms["before"], rms["after"])),
            all(a < 0.25 * b for a, b in zip(rms["after"], rms["before"])) and min(rms["before"]) > 0.5 * screws.min()
            / np.sqrt(2.0))
    v0, v1 = geometry.extra["validation"], both.extra["validation_compensated"]
    o.check("validation on the dwells kept out: the Gough's tool position from the encoders, geometry alone "
            "against geometry and tables (at least halved)",
            f"RMS {1e6 * v0['rms_after_m']:.2f} um -> {1e6 * v1['rms_m']:.2f} um",
            v1["rms_m"] < 0.5 * v0["rms_after_m"])
    g, t, sensor = (errors[k][1] for k in errors)
    o.check("MoM3 §7 with the tables: classical control on the encoders over the square closes at least half of "
            "what the screws left between it and sensor-space control",
            f"geometry {1e6 * g:.1f} um, with tables {1e6 * t:.1f} um, sensor space {1e6 * sensor:.1f} um RMS",
            all(v[0] == "completed" for v in errors.values()) and (g - t) > 0.5 * (g - sensor))
    o.table = [["control (the Delta as built, screws off)", "RMS / max tool error over the square (um)"]]
    o.table += [[k, f"{1e6 * v[1]:.1f} / {1e6 * v[2]:.1f}"] for k, v in errors.items()]
    return o


EXPERIMENTS = (
    Experiment("archi_calibration", "ARCHI calibrates itself from its redundancy, or with a laser tracker; the "
               "drives stop fighting", "ARCHI", "§4.1 with MoM3 §3's redundancy: self-calibration",
               ("archi_calibration", "archi_laser_calibration", "archi_fig12"), archi_calibration),
    Experiment("genhexkins_calibration", "The hexapod as built, calibrated with a laser tracker",
               "LinuxCNC", "genhexkins geometry, every joint and scale off", ("genhexkins_calibration",
                                                                             "hexapod_demo"),
               genhexkins_calibration),
    Experiment("mom3_calibration", "The Delta calibrated with its Gough; the encoders alone against sensor space",
               "MoM3", "§7 with a calibrated Delta, Table 2's load", ("mom3_calibration", "mom3_fig19"),
               mom3_calibration),
    Experiment("mom3_compensation", "Screw errors: compensation tables identified with the geometry",
               "MoM3", "§7 with a calibrated and compensated Delta", ("mom3_compensation", "mom3_fig19"),
               mom3_compensation),
)
