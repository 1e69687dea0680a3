"""Design sweeps (pkm_kinematics.design) against independent references: numpy's
eigenvalues, SVDs and condition numbers, machines built from edited configs, a
brute-force Pareto front, and the Gough resolution analysis."""

import dataclasses
import itertools

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.analysis import cube_points, gough_resolution
from pkm_kinematics.design import (GOUGH_METRICS, gough_metrics, pareto_front, planar_metrics, planar_variants,
                                   symmetric3_eigen_extremes, workspace_poses)
from pkm_kinematics.planar import PlanarMachine


def test_the_closed_form_eigenvalues_match_numpy():
    rng = np.random.default_rng(3)
    cases = [np.diag([1.0, 1.0, 1.0]), np.diag([2.0, 2.0, 5.0]), np.diag([3.0, 1e-6, 1.0])]
    for _ in range(500):
        a = rng.normal(size=(3, 3)) * rng.uniform(0.01, 100.0, size=3)
        cases.append(a.T @ a)
    for m in cases:
        lo, hi = symmetric3_eigen_extremes(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
        ref = np.linalg.eigvalsh(m)
        assert hi == pytest.approx(ref[-1], rel=1e-12)
        assert lo == pytest.approx(ref[0], rel=1e-6, abs=1e-13 * ref[-1])


@pytest.mark.parametrize("name", ["archi", "sliding_star"])
def test_planar_metrics_of_the_base_machine_match_numpy_over_the_grid(name):
    machine = load_machine(name).model
    poses = workspace_poses(machine, 7, 5)
    m = planar_metrics(machine, ["link_length_scale"], [[1.0]], poses)
    q, ok = machine.inverse_kinematics_batch(poses)
    jac = machine.jacobian_batch(poses)
    ok &= np.isfinite(jac).all(axis=(1, 2))
    j = jac[ok]
    sv = np.linalg.svd(j, compute_uv=False)
    cond = sv[:, 0] / sv[:, -1]
    assert m["reach"][0] == pytest.approx(ok.mean())
    assert m["cond_min"][0] == pytest.approx(cond.min(), rel=1e-7)
    assert m["cond_max"][0] == pytest.approx(cond.max(), rel=1e-7)
    assert m["tf_min"][0] == pytest.approx(sv[:, -1].min(), rel=1e-7)
    assert m["tf_max"][0] == pytest.approx(sv[:, 0].max(), rel=1e-7)
    assert m["travel_max_m"][0] == pytest.approx((q[ok].max(axis=0) - q[ok].min(axis=0)).max(), rel=1e-12)
    subs = list(itertools.combinations(range(machine.n_legs), 3))
    best = np.min([np.linalg.cond(j[:, list(s)]) for s in subs], axis=0)
    assert m["sub_cond_max"][0] == pytest.approx(best.max(), rel=1e-6)


def test_a_variant_is_the_machine_built_with_those_dimensions():
    machine = load_machine("sliding_star").model
    legs = [dataclasses.replace(leg, link_length=leg.link_length * 1.1,
                                platform_point=tuple(0.8 * v for v in leg.platform_point),
                                rail_origin=(leg.rail_origin[0], 1.2 * leg.rail_origin[1]))
            for leg in machine.legs]
    edited = PlanarMachine(machine.name, legs, machine.home_pose, machine.workspace)
    variant = planar_variants(machine, ["link_length_scale", "platform_scale", "rail_spacing_scale"],
                              [[1.1, 0.8, 1.2]])
    poses = workspace_poses(machine, 5, 3)
    got = planar_metrics(machine, ["link_length_scale", "platform_scale", "rail_spacing_scale"], [[1.1, 0.8, 1.2]],
                         poses)
    ref = planar_metrics(edited, ["link_length_scale"], [[1.0]], poses)
    np.testing.assert_allclose(variant[0], planar_variants(edited, [], np.zeros((1, 0)))[0], rtol=1e-15)
    for k in ref:
        assert got[k][0] == pytest.approx(ref[k][0], rel=1e-12), k
    with pytest.raises(ValueError, match="wheel_base: not a planar design parameter"):
        planar_variants(machine, ["wheel_base"], [[1.0]])


def test_the_pareto_front_is_the_brute_force_one():
    rng = np.random.default_rng(7)
    x = np.round(rng.normal(size=(400, 3)), 1)                     # rounded: many ties
    x[5] = np.nan
    senses = ["min", "max", "min"]
    signed = x * np.array([1, -1, 1])
    ref = np.zeros(len(x), dtype=bool)
    for i in range(len(x)):
        if np.isnan(signed[i]).any():
            continue
        others = np.delete(signed, i, axis=0)
        others = others[~np.isnan(others).any(axis=1)]
        ref[i] = not np.any(np.all(others <= signed[i], axis=1) & np.any(others < signed[i], axis=1))
    got = pareto_front(x, senses)
    assert np.array_equal(got, ref) and 0 < got.sum() < 100


def test_the_gough_metrics_of_the_mom3_design_are_the_resolution_analysis():
    met = load_machine("mom3").metrology
    m = gough_metrics(met, [], np.zeros((1, 0)), points_per_axis=3)
    ref = gough_resolution(met.platform, met.encoder_resolution_m, met.tool_box, met.workspace_center,
                           met.workspace_size_m, 3)
    assert set(m) == set(GOUGH_METRICS)
    assert m["tool_resolution_m"][0] == pytest.approx(ref.tool_m, rel=1e-12)
    assert m["position_resolution_m"][0] == pytest.approx(ref.position_m, rel=1e-12)
    assert [m["strut_min_m"][0], m["strut_max_m"][0]] == pytest.approx(ref.strut_range, rel=1e-12)
    # a smaller plate radius resolves the orientation worse: the tool-level figure grows
    smaller = gough_metrics(met, ["r_plate_m"], [[0.04]], points_per_axis=3)
    assert smaller["tool_resolution_m"][0] > m["tool_resolution_m"][0]
    assert len(cube_points(met.workspace_center, met.workspace_size_m, 3)) == 27
