"""The one machine model against the per-kind code it replaced: the seed machines'
IK, J_m, its derivative, the velocity terms, the FK and the batches at 40 poses each,
as that code computed them (data/model_reference.npz, written at commit 8e88b64 by
data/make_model_reference.py), agree within 1e-9 (issue 23: every figure unchanged).
The per-pose and batched paths of today's model are also checked against each other,
so the reference is not the only witness."""

from pathlib import Path

import numpy as np
import pytest

from pkm_kinematics import load_machine

DATA = Path(__file__).with_name("data")
REFERENCE = np.load(DATA / "model_reference.npz")
MACHINES = ("archi", "sliding_star", "orthoglide", "mom3")


def test_the_reference_was_made_by_the_generator_shipped_beside_it():
    import importlib.util
    spec = importlib.util.spec_from_file_location("make_ref", DATA / "make_model_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.MACHINES == MACHINES
    assert {k.split("/")[0] for k in REFERENCE.files} == set(MACHINES)


@pytest.mark.parametrize("name", MACHINES)
def test_the_model_reproduces_the_per_kind_code_within_1e_9(name):
    model = load_machine(name).model
    ref = {k.split("/")[1]: REFERENCE[k] for k in REFERENCE.files if k.startswith(name + "/")}
    xs, vs = ref["x"], ref["v"]
    assert len(xs) >= 30
    terms = [model.velocity_terms_arrays(x, v) for x, v in zip(xs, vs)]
    for i, key in enumerate(("q", "jacobian", "qdot", "bias")):
        np.testing.assert_allclose(np.array([t[i] for t in terms]), ref[key], rtol=1e-9, atol=1e-12, err_msg=key)
    np.testing.assert_allclose([model.jacobian_derivative(x, v) for x, v in zip(xs, vs)], ref["jacobian_derivative"],
                               rtol=1e-9, atol=1e-12)
    forward = [model.forward_kinematics_floats(q, x + 1e-3) for q, x in zip(ref["q"], xs)]
    np.testing.assert_allclose(forward, ref["forward"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(model.jacobian_batch(xs), ref["jacobian_batch"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(model.inverse_kinematics_batch(xs)[0], ref["ik_batch"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(model.condition_number_batch(xs), ref["condition"], rtol=1e-9)
    # the batch is the per-pose kernel on every row: the same numbers, bit for bit
    np.testing.assert_array_equal(model.jacobian_batch(xs), np.array([t[1] for t in terms]))
