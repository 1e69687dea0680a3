"""Identification time for each machine (its parameters and poses), and its scaling
with the number of poses.

    .venv/bin/python benchmarks/calibration.py [--poses 15 30 60 120] [--repeat 3]

Readings made here from the machine as built (as_built / the fig12 leg error) at poses
drawn in its workspace: ARCHI's self-calibration (4 encoders, 20 parameters, the poses
unknown too: 3 N more), genhexkins with a laser tracker (6 encoders and a point, 54
parameters); the CPU time of the identification alone (the least squares from the
nominal model, standard deviations included), best of ``--repeat``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pkm_calibration.as_built import as_built_struts, strut_gauge
from pkm_calibration.identify import identify
from pkm_calibration.poses import candidate_poses
from pkm_calibration.self_calibration import PlanarRailErrorModel, self_calibrate
from pkm_calibration.strut_errors import StrutErrorModel
from pkm_kinematics import load_machine
from pkm_kinematics.config import load_machine_data
from pkm_sim_hw.plant import true_machine


def cpu(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        start = time.process_time()
        out = fn()
        best = min(best, time.process_time() - start)
    return best, out


def archi_row(count: int, repeat: int) -> list:
    config = load_machine("archi")
    model = PlanarRailErrorModel(config.model)
    poses = candidate_poses(config.model, count, seed=count)
    truth = true_machine(config.model, (0.0, 0.0, 0.02, 0.0))
    q, _ = truth.inverse_kinematics_batch(poses)
    q = np.round(q * 1e6) / 1e6                        # the encoders' 1 um count
    seconds, result = cpu(lambda: self_calibrate(model, q, poses), repeat)
    k = model.names.index("length.q3")
    return ["ARCHI, self-calibration", model.size, len(result.identifiable.identified), count,
            f"{1e3 * seconds:.1f}", f"{1e6 * abs(result.theta[k] - 0.02):.2f}"]


def genhexkins_row(count: int, repeat: int, sigma_m: float = 2e-6) -> list:
    config = load_machine("genhexkins")
    model = StrutErrorModel(config.model, (0.0, 0.0, -0.05))
    poses = candidate_poses(config.model, count, seed=count)
    q_nominal, _ = config.model.inverse_kinematics_batch(poses)
    held = strut_gauge(model, q_nominal)
    data, truth, _ = as_built_struts(config, model, held, seed=count)
    built = load_machine_data(data).model
    q_true, _ = built.inverse_kinematics_batch(poses)
    rng = np.random.default_rng(count)
    _, _, dz, ds, _, _ = model.split(truth)
    q = (q_true - dz) / (1.0 + ds)                     # what the encoders read: l = q + z + s q
    y = model.predict(truth, q).y + sigma_m * rng.standard_normal((count, 3))
    seconds, result = cpu(lambda: identify(model, q, y, sigma_m, held=held), repeat)
    free = list(result.identifiable.identified)
    error = result.theta[free] - truth[free]
    statistic = error @ np.linalg.solve(result.covariance, error)
    return ["genhexkins, laser tracker", model.size, len(free), count, f"{1e3 * seconds:.1f}",
            f"chi2/dof {statistic / len(free):.2f}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, nargs="+", default=[20, 40, 80, 160])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rows = [["machine, instrument", "parameters", "identified", "poses", "CPU ms", "error"]]
    for count in args.poses:
        rows.append(archi_row(max(count, 20), args.repeat))        # 20 parameters, one equation a pose
    for count in args.poses:
        rows.append(genhexkins_row(max(count, 16), args.repeat))
    print("| " + " | ".join(rows[0]) + " |")
    print("|" + "---|" * len(rows[0]))
    for row in rows[1:]:
        print("| " + " | ".join(str(v) for v in row) + " |")
    print("error: ARCHI's |length.q3 - 20 mm| in um (1 um encoder counts); genhexkins: chi-square of the identified "
          "parameters' errors with their predicted covariance, per degree of freedom (about 1)")


if __name__ == "__main__":
    main()
