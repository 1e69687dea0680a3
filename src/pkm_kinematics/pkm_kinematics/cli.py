"""``pkm-analyze``: size and check a machine from the command line.

    pkm-analyze condition --machine archi --x 1.0 --y -0.4 --theta-range -200 200
    pkm-analyze resolution --machine mom3
    pkm-analyze orthoglide-size --cube 0.2 --psi-min 0.5 --psi-max 2.0
    pkm-analyze workspace --machine sliding_star
    pkm-analyze gough-optimize --machine mom3
    pkm-analyze report --machine archi
    pkm-analyze dosr

A readable table by default, JSON with ``--json``. Bad input exits with status 2 and
one line on stderr naming the field, ``pkm-analyze: error: --samples: must be an
integer >= 2, got 0``: argument values are checked by the argparse ``type=``
validators below, everything else (machine files, ranges, unreachable poses) by the
commands, which raise KinematicsError.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict

import numpy as np

from . import analysis
from .config import MachineConfig, load_machine, machine_names
from .errors import KinematicsError, UnreachablePoseError
from .yaml_files import UnreadableFileError
from .parallelogram import ParallelogramMachine, tilt_urad
from .rails import RailMachine
from .task_space import PLANAR


# ----------------------------------------------------------- argument checks
# One validator per kind of value; argparse reports their message as
# "argument --name: <message>", which main() prints as one line.
def real(lo: float = -math.inf, hi: float = math.inf):
    """A finite number in [lo, hi]; refuses nan, inf and values that overflow (1e999)."""
    allowed = ("a finite number" if lo == -math.inf and hi == math.inf
               else f"a number in [{lo:g}, {hi:g}]")

    def check(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text}")
        return value
    return check


def integer(lo: int, hi: int | None = None):
    """An integer in [lo, hi] (hi None: no upper bound), e.g. ``integer(2)`` for a
    number of samples along an axis."""
    allowed = f"an integer >= {lo}" if hi is None else f"an integer in [{lo}, {hi}]"

    def check(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if value < lo or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {value}")
        return value
    return check


FINITE = real()
# Grid and sweep axes include both ends, so they need at least two samples.
AXIS_SAMPLES = integer(2)
# Lengths (m): beyond 1 km is a typo, not a machine (and from about 1e154 m the
# kinematics' squares overflow); under a micrometre the Orthoglide sizing underflows.
POSITION_M = real(-1e3, 1e3)
SIZE_M = real(1e-6, 1e3)


class UsageError(Exception):
    """A command-line argument argparse refused (message names the argument)."""


class _Parser(argparse.ArgumentParser):
    """Raises UsageError instead of printing the usage and exiting, so that main()
    reports every bad input the same way (one line, status 2). Sub-commands use the
    same class."""

    def error(self, message: str):
        raise UsageError(message.removeprefix("argument "))


def _table(title: str, rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    lines = [title, "-" * len(title)]
    lines += [f"  {k.ljust(width)}  {v}" for k, v in rows]
    return "\n".join(lines)


def _um(v: float) -> str:
    return f"{v * 1e6:.3f} um"


def _jsonable(workspace: dict) -> dict:
    return {k: np.asarray(v).tolist() for k, v in workspace.items()}


def _load(name: str) -> MachineConfig:
    """load_machine, with an unreadable file reported against --machine."""
    try:
        return load_machine(name)
    except (OSError, UnreadableFileError) as exc:
        reason = getattr(exc, "strerror", None) or getattr(exc, "reason", None) or str(exc)
        raise KinematicsError(f"--machine: cannot read {name!r}: {reason}") from None


def _planar_machine(name: str) -> RailMachine:
    model = _load(name).model
    if not (isinstance(model, RailMachine) and model.task_space is PLANAR):
        raise KinematicsError(f"--machine: {name!r} is not a planar machine (condition sweeps need theta)")
    return model


# ------------------------------------------------------------------- commands
def cmd_condition(args) -> tuple[dict, str]:
    machine = _planar_machine(args.machine)
    lo, hi = args.theta_range
    if not lo < hi:
        raise KinematicsError(f"--theta-range: need MIN < MAX, got {lo} {hi}")
    sweep = analysis.condition_sweep(machine, args.x, args.y, lo, hi, samples=args.samples)
    full = sweep.full_condition
    unreachable = int(np.isnan(full).sum())      # NaN: a leg cannot reach its platform point
    if unreachable == len(full):
        raise UnreachablePoseError(_unreachable_message(machine, args.x, args.y, sweep.theta_deg))
    data = {
        "machine": machine.name, "x_m": args.x, "y_m": args.y, "theta_range_deg": [lo, hi],
        "full_machine": {"legs": machine.n_legs, "condition_min": float(np.nanmin(full)),
                         "condition_max": float(np.nanmax(full)),
                         "reachable": bool(np.isfinite(full).all())},
        "sub_machines": {
            machine.sub_machine_name(legs): {
                "singular_angles_deg": sweep.singular_angles_deg[legs],
                "condition_max_sampled": float(np.nanmax(sweep.sub_condition[legs])),
            } for legs in machine.sub_machines()},
    }
    rows = [("full machine condition", f"{data['full_machine']['condition_min']:.4f} .. "
             f"{data['full_machine']['condition_max']:.4f}")]
    if unreachable:
        rows.append(("unreachable", f"at {unreachable} of {len(full)} sampled angles (left out above)"))
    for name, sub in data["sub_machines"].items():
        angles = ", ".join(f"{a:.4f}" for a in sub["singular_angles_deg"]) or "none"
        rows.append((f"{name} singular at (deg)", angles))
    text = _table(f"Conditioning of {machine.name} at x={args.x} m, y={args.y} m, "
                  f"theta in [{lo}, {hi}] deg (ARCHI Fig. 10)", rows)
    return data, text


def _unreachable_message(machine: RailMachine, x: float, y: float, theta_deg: np.ndarray) -> str:
    """Names the pose, the angles tried and, from the IK at the middle angle, the leg
    that cannot reach."""
    message = (f"--x, --y: pose x={x:g} m, y={y:g} m of {machine.name} is unreachable at every "
               f"sampled theta in [{theta_deg[0]:g}, {theta_deg[-1]:g}] deg")
    try:
        machine.inverse_kinematics([x, y, math.radians(theta_deg[len(theta_deg) // 2])], check_limits=False)
    except UnreachablePoseError as exc:
        message += f"; e.g. {exc}"
    return message


def cmd_resolution(args) -> tuple[dict, str]:
    cfg = _load(args.machine)
    if cfg.metrology is None:
        raise KinematicsError(f"--machine: {args.machine!r} has no metrology section")
    met = cfg.metrology
    res = analysis.gough_resolution(met.platform, met.encoder_resolution_m, met.tool_box,
                                    met.workspace_center, met.workspace_size_m, args.points)
    data = {"machine": cfg.name, "encoder_resolution_m": met.encoder_resolution_m,
            "tool_box_m": met.tool_box.tolist(), **asdict(res)}
    rows = [("encoder resolution", _um(met.encoder_resolution_m)),
            ("worst position resolution", _um(res.position_m) + "   (MoM3 §5.6: about 6 um)"),
            ("worst orientation resolution", f"{res.orientation_rad * 1e6:.2f} urad"),
            ("  of which tilt (x, y axes)", f"{res.tilt_rad * 1e6:.2f} urad   (paper: about 30 urad)"),
            ("  of which about z", f"{res.twist_rad * 1e6:.2f} urad"),
            ("worst tool-level resolution", _um(res.tool_m) + "   (paper: 12 um)"),
            ("at plate position (m)", str([round(v, 4) for v in res.worst_plate_position])),
            ("strut lengths over workspace", f"{res.strut_range[0]:.4f} .. {res.strut_range[1]:.4f} m"),
            ("struts within limits", str(res.struts_within_limits))]
    return data, _table(f"Gough metrology resolution of {cfg.name} (MoM3 §5.5, worst case)", rows)


def cmd_orthoglide_size(args) -> tuple[dict, str]:
    sizing = analysis.orthoglide_size(args.cube, args.psi_min, args.psi_max)
    data = asdict(sizing)
    rows = [("link length L", f"{sizing.link_length_m * 1e3:.2f} mm   (paper prototype: 310.9 mm)"),
            ("actuator range", f"{sizing.actuator_range_m * 1e3:.2f} mm   (paper prototype: 257.1 mm)"),
            ("joint limits (rho)", f"[{sizing.joint_limits_m[0] * 1e3:.2f}, {sizing.joint_limits_m[1] * 1e3:.2f}] mm"),
            ("range / cube size", f"{sizing.range_ratio:.3f}"),
            ("Q1, Q2 on x=y=z", f"{sizing.q1[0] * 1e3:.2f} mm, {sizing.q2[0] * 1e3:.2f} mm"),
            ("psi over the cube", f"{sizing.psi_range_on_cube[0]:.4f} .. {sizing.psi_range_on_cube[1]:.4f}")]
    return data, _table(f"Orthoglide sizing: {args.cube} m cube, {args.psi_min} <= psi <= {args.psi_max} "
                        "(Orthoglide §4.4)", rows)


def cmd_workspace(args) -> tuple[dict, str]:
    model = _load(args.machine).model
    summary = analysis.workspace_summary(model, args.points, args.theta_points)
    if summary.reachable_fraction == 0.0:
        raise UnreachablePoseError(
            f"--machine: no pose of the workspace of {model.name} ({json.dumps(_jsonable(model.workspace))}) "
            f"is reachable within the joint limits ({summary.poses} poses sampled)")
    data = {"machine": model.name, "workspace": _jsonable(model.workspace), **asdict(summary)}
    rows = [("workspace", json.dumps(data["workspace"])),
            ("poses sampled", str(summary.poses)),
            ("reachable within joint limits", f"{100 * summary.reachable_fraction:.1f} %"),
            ("condition number", f"{summary.condition_min:.3f} .. {summary.condition_max:.3f} "
                                 f"(median {summary.condition_median:.3f})"),
            ("worst-conditioned pose", str([round(v, 4) for v in summary.worst_pose]))]
    for name, (lo, hi) in zip(model.leg_names, summary.joint_range):
        rows.append((f"drive {name} travel", f"{lo:.4f} .. {hi:.4f} m"))
    if summary.transmission_min is not None:
        rows.append(("transmission factors", f"{summary.transmission_min:.4f} .. {summary.transmission_max:.4f}"))
    return data, _table(f"Workspace of {model.name}", rows)


def cmd_gough_optimize(args) -> tuple[dict, str]:
    cfg = _load(args.machine)
    if cfg.metrology is None:
        raise KinematicsError(f"--machine: {args.machine!r} has no metrology section")
    met = cfg.metrology
    design = analysis.optimize_gough_geometry(
        met.encoder_resolution_m, met.tool_box, met.workspace_center, met.workspace_size_m,
        met.platform.strut_limits, maxiter=args.maxiter, seed=args.seed)
    data = asdict(design)
    rows = [("r_base", f"{design.r_base * 1e3:.1f} mm"), ("r_plate", f"{design.r_plate * 1e3:.1f} mm"),
            ("alpha_base", f"{design.alpha_base_deg:.2f} deg"), ("alpha_plate", f"{design.alpha_plate_deg:.2f} deg"),
            ("worst tool-level resolution", _um(design.criterion_m)),
            ("strut lengths", f"{design.strut_range[0]:.4f} .. {design.strut_range[1]:.4f} m"),
            ("struts within limits", str(design.struts_within_limits)),
            ("criterion evaluations", str(design.evaluations))]
    return data, _table(f"Gough geometry optimised for {cfg.name} (MoM3 §5.5.3)", rows)


def cmd_dosr(args) -> tuple[dict, str]:
    """The degree of sensor redundancy (MoM3 §3) of each machine's sensor sets."""
    names = [args.machine] if args.machine else machine_names()
    data, rows = {}, []
    for name in names:
        cfg = _load(name)
        entries = analysis.sensor_redundancy(cfg.model.n_legs, cfg.metrology is not None,
                                             cfg.model.task_dof, cfg.model.spatiality)
        data[cfg.name] = [asdict(e) for e in entries]
        for e in entries:
            rows.append((f"{cfg.name}: {e.sensors} (C = {e.c})",
                         f"perfect (M = O = {e.o}): {e.dosr_perfect:+d} {analysis.measurement_verdict(e.dosr_perfect)}; "
                         f"imperfect (M = 6): {e.dosr_imperfect:+d} {analysis.measurement_verdict(e.dosr_imperfect)}"))
    return data, _table("Degree of sensor redundancy, dosr = C - (M - O + D), D = O = 3 (6 for the hexapods) (MoM3 §3)", rows)


def cmd_report(args) -> tuple[dict, str]:
    cfg = _load(args.machine)
    model = cfg.model
    home = model.home
    q = model.inverse_kinematics(home)
    fk = np.asarray(model.forward_kinematics_floats(q))
    sections = [_table(f"Machine {cfg.name} ({cfg.kind}, {model.n_legs} drives): {model.description}", [
        ("home pose", str(np.round(home, 6).tolist())),
        ("drive positions at home (m)", str(np.round(q, 6).tolist())),
        ("forward kinematics round trip", f"{float(np.abs(fk - home).max()):.2e}"),
        ("condition number at home", f"{model.condition_number(home):.4f}"),
    ])]
    data = {"machine": cfg.name, "home": np.asarray(home).tolist(), "q_home": q.tolist()}
    ws_data, ws_text = cmd_workspace(argparse.Namespace(machine=args.machine, points=args.points,
                                                        theta_points=args.theta_points))
    sections.append(ws_text)
    data["workspace"] = ws_data
    if isinstance(model, RailMachine) and model.task_space is PLANAR and model.n_legs > 3:
        c_data, c_text = cmd_condition(argparse.Namespace(
            machine=args.machine, x=float(home[0]), y=float(home[1]),
            theta_range=list(model.workspace["theta_deg"]), samples=4001))
        sections.append(c_text)
        data["condition"] = c_data
    if isinstance(model, ParallelogramMachine):          # MoM3 §4.1: the imperfect case's tilt
        grid = model.workspace_grid(args.points)
        tilts = np.array([tilt_urad(model.parasitic_rotation(p)) for p in grid])
        data["parasitic_rotation_urad"] = [float(tilts.min()), float(tilts.max())]
        sections.append(_table(f"Parasitic rotation of {cfg.name} (MoM3 §4.1, unequal parallelogram bars)", [
            ("over the workspace", f"{tilts.min():.1f} .. {tilts.max():.1f} urad ({len(grid)} positions)")]))
    if cfg.metrology is not None:
        r_data, r_text = cmd_resolution(argparse.Namespace(machine=args.machine, points=args.resolution_points))
        sections.append(r_text)
        data["resolution"] = r_data
    return data, "\n\n".join(sections)


# ----------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pkm-analyze", description=__doc__.split("\n\n")[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter,
                     epilog="machines: config/machines/*.yaml")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    sub = parser.add_subparsers(dest="command", required=True)

    def machine_arg(p, default=None):
        p.add_argument("--machine", default=default, required=default is None,
                       help="machine name (config/machines/NAME.yaml) or a YAML path")

    p = sub.add_parser("condition", help="condition numbers and sub-machine singular angles (ARCHI Fig. 10)")
    machine_arg(p)
    p.add_argument("--x", type=POSITION_M, required=True, help="platform x (m)")
    p.add_argument("--y", type=POSITION_M, required=True, help="platform y (m)")
    p.add_argument("--theta-range", type=FINITE, nargs=2, required=True, metavar=("MIN", "MAX"),
                   help="deg, MIN < MAX")
    p.add_argument("--samples", type=AXIS_SAMPLES, default=4001, help="angles sampled before refinement (>= 2)")
    p.set_defaults(func=cmd_condition)

    p = sub.add_parser("resolution", help="worst-case Gough metrology resolution (MoM3 §5.5)")
    machine_arg(p)
    p.add_argument("--points", type=AXIS_SAMPLES, default=7, help="grid points per workspace axis (>= 2)")
    p.set_defaults(func=cmd_resolution)

    p = sub.add_parser("orthoglide-size", help="size an Orthoglide for a cube and psi bounds (§4.4)")
    p.add_argument("--cube", type=SIZE_M, required=True, help="cube side (m)")
    p.add_argument("--psi-min", type=FINITE, required=True, help="in (0, 1)")
    p.add_argument("--psi-max", type=FINITE, required=True, help="> 1")
    p.set_defaults(func=cmd_orthoglide_size)

    p = sub.add_parser("workspace", help="reachability, conditioning and drive travel over the workspace")
    machine_arg(p)
    p.add_argument("--points", type=AXIS_SAMPLES, default=11, help="grid points per position axis (>= 2)")
    p.add_argument("--theta-points", type=AXIS_SAMPLES, default=13, help="grid points in theta (planar, >= 2)")
    p.set_defaults(func=cmd_workspace)

    p = sub.add_parser("gough-optimize", help="optimise the Gough geometry for tool-level resolution")
    machine_arg(p)
    p.add_argument("--maxiter", type=integer(1), default=40, help="differential-evolution generations (>= 1)")
    # numpy's generator seeds are 32-bit unsigned.
    p.add_argument("--seed", type=integer(0, 2**32 - 1), default=1, help="random seed, in [0, 2^32 - 1]")
    p.set_defaults(func=cmd_gough_optimize)

    p = sub.add_parser("dosr", help="degree of sensor redundancy of each machine's sensor sets (MoM3 §3)")
    p.add_argument("--machine", default=None, help="one machine (default: every machine in config/machines)")
    p.set_defaults(func=cmd_dosr)

    p = sub.add_parser("report", help="kinematic report of a machine")
    machine_arg(p, default="archi")
    p.add_argument("--points", type=AXIS_SAMPLES, default=11, help="workspace grid points per position axis (>= 2)")
    p.add_argument("--theta-points", type=AXIS_SAMPLES, default=13, help="workspace grid points in theta (>= 2)")
    p.add_argument("--resolution-points", type=AXIS_SAMPLES, default=7,
                   help="resolution grid points per axis (>= 2)")
    p.set_defaults(func=cmd_report)
    return parser


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        data, text = args.func(args)
    except (UsageError, KinematicsError, ValueError) as exc:
        print(f"pkm-analyze: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print("pkm-analyze: error: not enough memory for the requested grid: lower --points, "
              "--theta-points or --samples", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(data, indent=2, default=lambda o: None if isinstance(o, float) and math.isnan(o) else str(o)))
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
