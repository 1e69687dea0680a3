"""``pkm-calibrate``: calibrating a machine in three commands (procedure.py).

    pkm-calibrate plan archi --poses 30 --out archi_calibration.nc
    pkm-run config/scenarios/archi_calibration.yaml        # runs and records the program
    pkm-calibrate identify archi runs/archi_calibration --out archi.calibrated.yaml

``plan`` chooses the poses (the observability index O1 over candidates drawn in the
workspace) and writes them as a G-code program: a move and a dwell at each pose.
``identify`` finds the dwells of the recorded run, identifies what the readings can
identify (the rest named and held at nominal), prints the parameters with their
standard deviations and the residuals before and after, and writes the calibrated
machine file (default: beside the nominal one, ``<name>.calibrated.yaml``), which a
scenario's ``model`` key gives the controller. ``--instrument`` auto: self-calibration
from the redundancy on a redundant machine on rails (ARCHI), a laser tracker on the tool
point of a strut machine (its encoders' zeros and scales go into the file as
compensation tables), the Gough metrology on a machine on rails that has one (MoM3).
``--table-spacing-m``: each drive's compensation table too, also written as LinuxCNC
comp files beside the machine file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pkm_kinematics import load_machine
from pkm_kinematics.compensation import comp_file_text
from pkm_kinematics.config import config_dir, machine_names
from pkm_kinematics.errors import ConfigError, FieldError

from .as_built import as_built_struts, strut_gauge
from .machine_files import calibrated_path, write_machine_file
from .poses import candidate_poses
from .procedure import calibrated_machine_data, identify_run, plan_calibration
from .strut_errors import StrutErrorModel


def _nominal_path(machine: str) -> Path:
    return config_dir() / "machines" / f"{machine}.yaml" if machine in machine_names() else Path(machine)


def plan(args) -> str:
    config = load_machine(args.machine)
    result = plan_calibration(config, args.poses, args.instrument, args.candidates, args.seed, tuple(args.tool),
                              args.angle_half_range_deg, args.dwell_s, args.feed)
    print(f"{config.name}: {result.method}; {result.identifiable.describe()}; O1 {result.observability:.4g}",
          file=sys.stderr)
    return result.program


def identify(args) -> str:
    config = load_machine(args.machine)
    result = identify_run(config, args.run, args.instrument, args.min_dwell_s,
                          None if args.tool is None else tuple(args.tool), args.sigma_m,
                          validate_every=args.validate_every, table_spacing_m=args.table_spacing_m)
    moving = result.extra.get("unsettled", 0)
    lines = [f"{config.name}: {result.method}, {result.dwells} dwells"
             + (f" ({moving} left out: the machine had not settled)" if moving else "")
             + f"; {result.identifiable.describe()}",
             f"residual RMS {1e6 * result.misfit_before_m:.3f} um (nominal) -> {1e6 * result.misfit_after_m:.3f} um"]
    lines += [f"  {name:<18} {value:>16} {std:>10}" for name, value, std in result.table()]
    validation = result.extra.get("validation")
    if validation:
        lines.append(f"validation on {validation['dwells']} dwells kept out: the instrument's residual RMS "
                     f"{1e6 * validation['rms_before_m']:.2f} um (nominal) -> {1e6 * validation['rms_after_m']:.2f} um")
    tables = result.extra.get("compensation")
    if tables is not None:
        rms = result.extra["drive_error_rms_m"]
        lines.append("drive errors left by the geometry, RMS um: " + ", ".join(
            f"{n} {1e6 * b:.2f} -> {1e6 * a:.2f}" for n, b, a in zip(config.model.leg_names, rms["before"],
                                                                    rms["after"])) + " (with the tables)")
        if "validation_compensated" in result.extra:
            lines.append(f"validation with the tables: {1e6 * result.extra['validation_compensated']['rms_m']:.2f} um")
    out = args.out or calibrated_path(_nominal_path(args.machine))
    data = calibrated_machine_data(config, result, args.label or Path(args.run).name, str(Path(args.run)))
    write_machine_file(out, data, f"{config.name}, calibrated by pkm-calibrate identify from {args.run}\n"
                                  f"({result.method}); the nominal file: {_nominal_path(args.machine)}")
    lines.append(f"{out}: the calibrated machine file (a scenario's model: {out})")
    if tables is not None:       # LinuxCNC comp files beside it, one per drive (COMP_FILE_TYPE 1, metres)
        for name, table in zip(config.model.leg_names, tables.tables):
            comp = Path(out).with_name(f"{Path(out).stem}.{name}.comp")
            comp.write_text(comp_file_text(table), encoding="utf-8")
            lines.append(f"{comp}: drive {name}'s compensation table ({len(table.positions)} points)")
    return "\n".join(lines) + "\n"


def as_built(args) -> str:
    """A simulated machine as built (as_built.py): its file, and the plant's errors to set."""
    config = load_machine(args.machine)
    if config.kind != "struts":
        raise FieldError("machine", f"{args.machine}: as-built machines of strut machines for now")
    model = StrutErrorModel(config.model, tuple(args.tool))
    pool = candidate_poses(config.model, 200, args.seed)
    held = strut_gauge(model, config.model.inverse_kinematics_batch(pool)[0])
    data, _, scales = as_built_struts(config, model, held, args.seed, args.joint_std_m, args.scale_std)
    header = (f"{config.name} as built: pkm-calibrate as-built {args.machine} --seed {args.seed} --joint-std-m "
              f"{args.joint_std_m:g} --scale-std {args.scale_std:g}\nthe plant's encoders: plant.link_length_errors "
              f"{[round(v, 9) for v in scales]}")
    write_machine_file(args.out, data, header)
    return f"{args.out}: plant.link_length_errors {[round(v, 9) for v in scales]}\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-calibrate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", help="choose the poses and write the calibration program")
    p.add_argument("machine")
    p.add_argument("--poses", type=int, default=30)
    p.add_argument("--candidates", type=int, default=400)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--angle-half-range-deg", type=float, default=None,
                   help="narrow the rotations drawn to +-this (default: the workspace's)")
    p.add_argument("--dwell-s", type=float, default=0.5)
    p.add_argument("--feed", type=float, default=600.0, help="mm/min")
    p.add_argument("--out", type=Path, help="the program file (default: standard output)")
    i = sub.add_parser("identify", help="identify the geometry from a recorded calibration run")
    i.add_argument("machine")
    i.add_argument("run", type=Path, help="the run directory (pkm-run's)")
    i.add_argument("--min-dwell-s", type=float, default=0.2)
    i.add_argument("--sigma-m", type=float, default=None, help="the readings' noise (default: module doc)")
    i.add_argument("--label", default="", help="the calibration's name (default: the run's directory)")
    i.add_argument("--out", type=Path, help="the calibrated machine file (default: beside the nominal one)")
    i.add_argument("--table-spacing-m", type=float, default=None,
                   help="identify each drive's compensation table too, knots this far apart (where the instrument "
                        "fixes the pose: MoM3 and its Gough); written in the machine file and as LinuxCNC comp files")
    i.add_argument("--validate-every", type=int, default=0,
                   help="keep every k-th dwell out of the identification to validate it (default: none)")
    b = sub.add_parser("as-built", help="a simulated machine as built: seeded errors on what calibration identifies")
    b.add_argument("machine")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--joint-std-m", type=float, default=5e-4)
    b.add_argument("--scale-std", type=float, default=2e-4)
    b.add_argument("--tool", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"))
    b.add_argument("--out", type=Path, required=True)
    for q in (p, i):
        q.add_argument("--instrument", choices=("auto", "none", "laser", "gough", "gough-struts"), default="auto",
                       help="the instrument read at the poses (auto: a laser tracker on a strut machine; none, "
                            "self-calibration from the redundancy, on a redundant machine on rails; the Gough "
                            "metrology's pose on one with a metrology section; gough-struts: its six struts, "
                            "the Gough's own joints identified too)")
        q.add_argument("--tool", type=float, nargs=3, default=(0.0, 0.0, 0.0) if q is p else None,
                       metavar=("X", "Y", "Z"), help="the point the instrument measures, platform frame (m)"
                       + ("" if q is p else "; default: the run's laser tracker's (run.json)"))
    args = parser.parse_args(argv)
    try:
        text = {"plan": plan, "identify": identify, "as-built": as_built}[args.command](args)
    except (FieldError, ConfigError, ValueError, FileNotFoundError) as exc:
        print(f"pkm-calibrate: {exc}", file=sys.stderr)
        return 2
    if args.command == "plan" and args.out is not None:
        args.out.write_text(text, encoding="utf-8")
        print(f"{args.out}: {args.poses} poses")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
