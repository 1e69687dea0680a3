"""Writes model_reference.npz: the seed machines' kinematics at fixed poses, as the
per-kind code computed them before the bar model replaced it (commit 8e88b64). The
equivalence test (test_model_equivalence.py) pins today's model to it within 1e-9.
Regenerate it only for a change that is meant to move these numbers, and say so.

    .venv/bin/python tests/kinematics/data/make_model_reference.py
"""

from pathlib import Path

import numpy as np

from pkm_kinematics import load_machine

MACHINES = ("archi", "sliding_star", "orthoglide", "mom3")


def poses(model, n: int = 40) -> np.ndarray:
    """n reachable poses of the workspace grid (every k-th), with twists."""
    grid = model.workspace_grid(7, 7)
    reachable = [x for x in grid if model.inverse_kinematics_batch(x[None])[1][0]]
    step = max(1, len(reachable) // n)
    return np.array(reachable[::step][:n])


def reference(name: str) -> dict:
    model = load_machine(name).model
    xs = poses(model)
    rng = np.random.default_rng(7)
    vs = rng.normal(0.0, 0.2, xs.shape)
    out = {"x": xs, "v": vs}
    terms = [model.velocity_terms_arrays(x, v) for x, v in zip(xs, vs)]
    for i, key in enumerate(("q", "jacobian", "qdot", "bias")):
        out[key] = np.array([t[i] for t in terms])
    out["jacobian_derivative"] = np.array([model.jacobian_derivative(x, v) for x, v in zip(xs, vs)])
    out["forward"] = np.array([model.forward_kinematics_floats(q, x + 1e-3) for q, x in zip(out["q"], xs)])
    out["jacobian_batch"] = model.jacobian_batch(xs)
    out["ik_batch"] = model.inverse_kinematics_batch(xs)[0]
    out["condition"] = model.condition_number_batch(xs)
    return {f"{name}/{k}": v for k, v in out.items()}


if __name__ == "__main__":
    data = {}
    for name in MACHINES:
        data.update(reference(name))
    path = Path(__file__).with_name("model_reference.npz")
    np.savez_compressed(path, **data)
    print(f"wrote {path} ({path.stat().st_size} bytes, {len(data)} arrays)")
