"""``pkm-calibrate``: calibrating a machine from the command line.

    pkm-calibrate plan genhexkins --poses 30 --out calibration.nc

``plan`` chooses the poses (poses.select_poses: the observability index O1 over
candidates drawn in the workspace) and writes them as a G-code program that pkm-run
runs: a move and a dwell at each pose, where the instrument reads. Machines on struts
for now (the rail machines' error model is to come).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from pkm_kinematics import load_machine
from pkm_kinematics.errors import ConfigError, FieldError
from pkm_kinematics.struts import StrutMachine

from .identify import identifiability
from .poses import calibration_program, candidate_poses, observability_index, select_poses
from .strut_errors import StrutErrorModel


def plan(args) -> str:
    config = load_machine(args.machine)
    machine = config.model
    if not isinstance(machine, StrutMachine):
        raise FieldError("machine", f"{args.machine}: calibration plans machines on struts for now "
                                    f"(genhexkins, hexapod8), not {type(machine).__name__}")
    model = StrutErrorModel(machine, tuple(args.tool))
    candidates = candidate_poses(machine, args.candidates, args.seed)
    q, _ = machine.inverse_kinematics_batch(candidates)
    jac = model.jacobian(np.zeros(model.size), q)
    which = identifiability(jac, model.names)
    free = list(which.identified)
    blocks = jac[:, free].reshape(len(candidates), 3, len(free))
    chosen = select_poses(blocks, args.poses)
    index = observability_index(blocks[chosen].reshape(-1, len(free)) / np.linalg.norm(jac[:, free], axis=0))
    comment = f"{args.machine}, O1 {index:.4g} (Borm & Menq) of {len(free)} parameters, tool {list(args.tool)} m"
    return calibration_program(machine.task_space, candidates[chosen], args.dwell_s, args.feed, comment)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-calibrate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", help="choose the poses and write the calibration program")
    p.add_argument("machine")
    p.add_argument("--poses", type=int, default=30)
    p.add_argument("--candidates", type=int, default=400)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tool", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"),
                   help="the point the instrument measures, platform frame (m)")
    p.add_argument("--dwell-s", type=float, default=0.5)
    p.add_argument("--feed", type=float, default=600.0, help="mm/min")
    p.add_argument("--out", type=Path, help="the program file (default: standard output)")
    args = parser.parse_args(argv)
    try:
        text = plan(args)
    except (FieldError, ConfigError, ValueError) as exc:
        print(f"pkm-calibrate: {exc}", file=sys.stderr)
        return 2
    if args.out is None:
        sys.stdout.write(text)
    else:
        args.out.write_text(text, encoding="utf-8")
        print(f"{args.out}: {args.poses} poses")
    return 0


if __name__ == "__main__":
    sys.exit(main())
