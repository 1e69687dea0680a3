"""The compiled per-cycle kernels (pkm_kinematics.jit) against the same code
interpreted (``.py_func``) and against independent numpy references."""

import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_kinematics import jit, load_machine
from pkm_kinematics import distribution as dist
from pkm_kinematics import bars as bars_module
from pkm_kinematics import planar as planar_module
from pkm_kinematics.rotations import exp_so3


@pytest.fixture(scope="module")
def archi():
    return load_machine("archi")


def test_the_kernels_are_compiled_in_the_project_environment():
    # requirements.txt installs numba: the benchmarks and the loop must run compiled
    if os.environ.get("PKM_NO_JIT") == "1":
        pytest.skip("PKM_NO_JIT=1 asks for the interpreted kernels")
    assert jit.COMPILED
    assert planar_module._forward_kinematics_kernel is not planar_module._forward_kinematics_kernel.py_func


small = st.floats(-0.05, 0.05, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(dx=small, dy=small, dth=st.floats(-0.3, 0.3), leg_error=st.floats(-0.01, 0.01))
def test_forward_kinematics_kernel_matches_interpreted(archi, dx, dy, dth, leg_error):
    model = archi.model
    pose = model.home + [dx, dy, dth]
    q = model.inverse_kinematics(pose, check_limits=False)
    q[0] += leg_error                       # inconsistent drives: the Newton branch
    args = (model.bars, model.fk.pairs_array, model.fk.sides, q, *model.home.tolist(), 1e-12, 50)
    compiled = planar_module._forward_kinematics_kernel(*args)
    interpreted = planar_module._forward_kinematics_kernel.py_func(*args)
    assert [float(v) for v in compiled] == pytest.approx([float(v) for v in interpreted], rel=1e-12, abs=1e-15)
    if leg_error == 0.0:
        assert compiled[3] == planar_module.FK_CONVERGED
        np.testing.assert_allclose(compiled[:3], pose, atol=1e-12)


def test_forward_kinematics_reports_the_failures_by_name(archi):
    model = archi.model
    result = model.forward_kinematics([0.0, 0.0, 0.0, 0.0])
    assert not result.converged and "cannot close" in result.reason and "q1" in result.reason
    result = model.forward_kinematics(model.inverse_kinematics(model.home), max_iterations=0)
    assert not result.converged and result.reason == "no convergence in 0 iterations"


@settings(max_examples=60, deadline=None)
@given(rows=st.lists(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3), min_size=4, max_size=4),
       wrench=st.lists(st.floats(-500.0, 500.0), min_size=3, max_size=3), inf_norm=st.booleans())
def test_distribution_kernel_matches_interpreted_and_reproduces_the_wrench(rows, wrench, inf_norm):
    jac = np.array(rows)
    if np.linalg.matrix_rank(jac) < 3 or np.linalg.cond(jac) > 1e6:
        return
    compiled = dist.distribute_kernel(jac, *wrench, inf_norm, True)
    interpreted = dist.distribute_kernel.py_func(jac, *wrench, inf_norm, True)
    assert compiled[1] == interpreted[1]
    np.testing.assert_allclose(compiled[0], interpreted[0], rtol=1e-12, atol=1e-9)
    if compiled[1] == 0:
        cond2_eps = np.linalg.cond(jac) ** 2 * np.finfo(float).eps      # normal equations (below)
        np.testing.assert_allclose(jac.T @ compiled[0], wrench,
                                   atol=(1e-6 + 10.0 * cond2_eps) * (1.0 + np.abs(wrench).max()))
        reference = np.linalg.pinv(jac.T) @ np.array(wrench)
        # the kernel solves the normal equations (J^T J) y = F: a normwise relative
        # accuracy of ~cond(J)^2 eps (~2e-12 at the controller's max_condition 100)
        tol = (1e-9 + 10.0 * np.linalg.cond(jac) ** 2 * np.finfo(float).eps) * np.abs(reference).max() + 1e-9
        if inf_norm:      # no worse peak than the pseudo-inverse, which it starts from
            assert np.abs(compiled[0]).max() <= np.abs(reference).max() + tol
        else:
            np.testing.assert_allclose(compiled[0], reference, rtol=0.0, atol=tol)


def test_distribution_errors_name_the_cause():
    with pytest.raises(dist.DistributionError, match="rank < 3"):
        dist.min_two_norm([(1.0, 0.0, 0.0)] * 4, [1.0, 0.0, 0.0])
    with pytest.raises(dist.DistributionError, match="does not reproduce"):
        dist.check_wrench([(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)], [1.0, 1.0, 1.0], [1.0, 1.0, 2.0])


@settings(max_examples=40, deadline=None)
@given(p=st.lists(st.floats(-0.02, 0.02), min_size=3, max_size=3),
       w=st.lists(st.floats(-0.2, 0.2), min_size=3, max_size=3))
def test_gough_jacobian_rows_is_the_inverse_of_the_inverse_jacobian(archi, p, w):
    platform = archi.metrology.platform
    position = platform.home_position + np.array(p)
    rotation = exp_so3(np.array(w))
    rows = platform.jacobian_rows(position.tolist(), tuple(rotation.ravel().tolist()))
    np.testing.assert_allclose(np.array(rows) @ platform.inverse_jacobian(position, rotation), np.eye(6),
                               atol=1e-9)
    interpreted = bars_module.pose_from_lengths_jacobian_kernel.py_func(platform.bars, *position.tolist(),
                                                                        *rotation.ravel().tolist())
    np.testing.assert_allclose(rows, interpreted, rtol=1e-9, atol=1e-10)     # numba's inverse, numpy's
    assert math.isfinite(sum(map(sum, rows)))


def test_kernel_wrappers_check_shapes_and_accept_integers():
    rows = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 0.0)]
    dist.check_wrench(np.array(rows), np.array([1, 1, 1, 0]), np.array([1, 1, 1]))     # integer arrays
    with pytest.raises(ValueError, match="forces: expected 4"):
        dist.check_wrench(rows, [1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="jac: expected n rows of 4"):
        dist.check_wrench(rows, [1.0, 1.0, 1.0, 0.0], [1.0, 1.0, 1.0, 0.0])
    with pytest.raises(ValueError, match="values: expected 4"):
        dist.least_squares_rows(rows, [1.0, 2.0])
    with pytest.raises(dist.DistributionError, match="rank < 3"):
        dist.least_squares_rows([], [])
    with pytest.raises(ValueError, match="n: expected 4"):
        dist.min_inf_norm_1d([1.0, 2.0, 3.0, 4.0], [1.0, 0.0])
    from pkm_kinematics.distribution import gram_condition
    assert gram_condition([]) == 1.0
    assert gram_condition(np.eye(3)) == pytest.approx(1.0)
    assert gram_condition(np.diag([1.0, 1.0, 4.0])) == pytest.approx(4.0)


def test_the_cache_key_covers_every_file_with_kernels():
    # numba's cache notices edits to a kernel's own file only: a kernel calling one of
    # another file would run stale machine code unless that file is in the cache key
    from pathlib import Path
    src = Path(__file__).resolve().parents[2] / "src"
    with_kernels = {f"{path.parent.name}/{path.name}" for path in src.glob("pkm_*/pkm_*/*.py")
                    if "@kernel" in path.read_text()}
    keyed = {name for name, _ in jit._kernel_sources()}
    assert {"pkm_sim_hw/rail_step.py", "pkm_sim_hw/drives.py", "pkm_controller/laws.py"} <= with_kernels
    assert with_kernels - keyed == set(), f"kernel files outside numba's cache key: {with_kernels - keyed}"


def test_a_checked_direct_call_refuses_an_argument_of_another_type(monkeypatch):
    if not jit.COMPILED:
        pytest.skip("interpreted: direct_call is the function itself")
    monkeypatch.setenv(jit.CHECK_DIRECT_CALLS_ENV, "1")
    call = jit.direct_call(dist.least_squares_kernel)
    rows, values = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), np.array([1.0, 2.0, 3.0])
    expected = dist.least_squares_kernel(rows, values)
    assert call(rows, values) == expected
    with pytest.raises(TypeError, match=r"least_squares_kernel: argument 1 is array\(int64"):
        call(rows, np.array([1, 2, 3]))
    with pytest.raises(TypeError, match=r"argument 0 is array\(float64, 1d"):
        call(values, values)


# every direct call (jit.direct_call: no conversion, another type is undefined behaviour)
# of the scenarios that reach them, each argument checked against the declared types
_CHECK_RUNS = """
import json, sys, tempfile
from pathlib import Path
from pkm_bringup.processes import use_ros_environment
use_ros_environment()
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_kinematics import jit
status = {}
with tempfile.TemporaryDirectory() as tmp:
    for name in sys.argv[1:]:      # recorded: unrecorded, the Gough solves no pose nobody reads
        s = load_scenario(name, {"duration_s": 0.2, "record": True})
        status[name] = run_scenario(s, Path(tmp) / name, progress=False, report=False, engine="direct")["status"]
    # the same run with every controller cycle interpreted: the kernels the compiled
    # prepare (pkm_controller.compiled_prepare) calls inside itself, called one by one
    from pkm_controller import compiled_prepare
    compiled_prepare.COMPILE_PREPARE = False
    s = load_scenario("archi_demo", {"duration_s": 0.2, "record": False})
    status["archi_demo interpreted"] = run_scenario(s, Path(tmp) / "interpreted", progress=False, report=False,
                                                    engine="direct")["status"]
    # recorded with the bag written in this process: the Gough's DKM solved in the loop
    # (a process of one thread solves it in the bag's writer, whose calls are not counted here)
    from pkm_bringup import direct_recording
    direct_recording.may_fork = lambda: False
    s = load_scenario("archi_demo", {"duration_s": 0.2, "record": True})
    status["archi_demo bag here"] = run_scenario(s, Path(tmp) / "here", progress=False, report=False,
                                                 engine="direct")["status"]
# what no run reaches here: a strut machine's warm forward kinematics, the Gough's
# DKM outside the sensor's fused reading (its interpreted path, tools), and the compiled
# reading of a true pose decoded (one the kernel of its bytes does not read: another frame)
from pkm_common.poses import machine_pose_components, pose_components, pose_from_components
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.struts import StrutFK
hexapod = load_machine("hexapod8").model
StrutFK(hexapod).solve(hexapod.inverse_kinematics(hexapod.home))
archi = load_machine("archi")
sensor = GoughSensorModel(archi.metrology)
pose = pose_from_components(*machine_pose_components(archi.model.task_space, archi.model.home.tolist()))
sensor.estimate(sensor.measure(*pose))
import numpy as np
fields = np.array([*pose[0], *pose_components(*pose)[1]], dtype=float)
sensor.measure_fields(fields, np.empty(6))
print(json.dumps({"status": status, "checked": jit.CHECKED}))
"""


@pytest.mark.slow
def test_every_direct_call_of_the_loops_gets_its_declared_types():
    import json
    import subprocess
    import sys
    from pathlib import Path
    if not jit.COMPILED:
        pytest.skip("interpreted: direct_call is the function itself")
    scenarios = ["archi_demo", "mom3_square", "hexapod_metrology", "hexapod_demo"]
    env = {**os.environ, jit.CHECK_DIRECT_CALLS_ENV: "1"}
    done = subprocess.run([sys.executable, "-c", _CHECK_RUNS, *scenarios], capture_output=True, text=True,
                          env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["status"] == {name: "completed" for name in [*scenarios, "archi_demo interpreted",
                                                            "archi_demo bag here"]}, out
    reached = {"planar_encoder_state_kernel", "spheres_encoder_state_kernel", "sensor_space_desired_kernel",
               "rail_gough_check_kernel", "innovation_kernel", "rail_step_kernel",
               "strut_dynamics_step_kernel", "strut_outputs_kernel", "true_lengths_kernel", "readings_kernel",
               "estimate_kernel", "dkm_solve_kernel", "sensor_space_command_kernel", "cartesian_command_kernel"}
    reached |= {"forward_kinematics_warm_kernel", "prepare_kernel", "complete_kernel", "sample_reference_kernel",
                "measure_message_kernel"}
    assert reached <= set(out["checked"]), sorted(reached - set(out["checked"]))
    assert len(reached) == 19
    sites = {line.split("direct_call(")[1].split(")")[0].split(".")[-1]
             for path in (Path(__file__).resolve().parents[2] / "src").glob("pkm_*/pkm_*/*.py")
             for line in path.read_text().splitlines() if "= direct_call(" in line}
    assert sites == reached, (sorted(sites - reached), sorted(reached - sites))     # every one of them
