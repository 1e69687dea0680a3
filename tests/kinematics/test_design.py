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


def test_the_closed_form_eigenvalues_match_numpy():
    """Gram matrices J^T J of random J, and rotated diagonal ones with the two smaller
    eigenvalues nearly equal (where Smith's formula alone loses ~sqrt(eps)): the
    smallest within 1e-6 relative down to cond(J) = 1e4."""
    rng = np.random.default_rng(3)
    cases = [np.diag([1.0, 1.0, 1.0]), np.diag([2.0, 2.0, 5.0]), np.diag([3.0, 1e-6, 1.0])]
    for _ in range(500):
        a = rng.normal(size=(3, 3)) * rng.uniform(0.01, 100.0, size=3)
        cases.append(a.T @ a)
    for small in (1e-4, 1e-6, 1e-8):
        for spread in (1.0, 1.0 + 1e-9, 1.001, 1.1, 3.0):
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            cases.append(q @ np.diag([1.0, small, small * spread]) @ q.T)
            cases.append(q @ np.diag([1.0, 1.0 / spread, small]) @ q.T)       # the two larger nearly equal
    for m in cases:
        lo, hi = symmetric3_eigen_extremes(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
        ref = np.linalg.eigvalsh(m)
        assert hi == pytest.approx(ref[-1], rel=1e-8)       # ~sqrt(eps) where it is nearly double
        assert lo == pytest.approx(ref[0], rel=1e-6, abs=1e-16 * ref[-1])


@pytest.mark.parametrize("name, scale", [("archi", 1.0), ("sliding_star", 1.0), ("sliding_star", 0.7)])
def test_planar_metrics_match_numpy_over_the_grid(name, scale):
    """The base machines, and Sliding Star with links 0.7 times as long (part of its
    workspace out of reach): reach, cond(J_m), psi = 1/sigma (Orthoglide §4.3), travel,
    and the worst machine left after a drive failure, against numpy on the same grid."""
    base = load_machine(name).model
    legs = [dataclasses.replace(leg, link_length=leg.link_length * scale) for leg in base.legs]
    machine = base.with_legs(base.name, legs) if scale != 1.0 else base
    poses = workspace_poses(base, 7, 5)
    m = planar_metrics(base, ["link_length_scale"], [[scale]], poses)
    q, ok = machine.inverse_kinematics_batch(poses)
    jac = machine.jacobian_batch(poses)
    ok &= np.isfinite(jac).all(axis=(1, 2))
    assert 0 < ok.sum() and (scale == 1.0 or ok.mean() < 1.0)
    j = jac[ok]
    sv = np.linalg.svd(j, compute_uv=False)
    cond = sv[:, 0] / sv[:, -1]
    psi = 1.0 / sv
    assert m["reach"][0] == pytest.approx(ok.mean())
    assert m["cond_min"][0] == pytest.approx(cond.min(), rel=1e-7)
    assert m["cond_max"][0] == pytest.approx(cond.max(), rel=1e-7)
    assert m["tf_min"][0] == pytest.approx(psi.min(), rel=1e-7)
    assert m["tf_max"][0] == pytest.approx(psi.max(), rel=1e-7)
    assert m["travel_max_m"][0] == pytest.approx((q[ok].max(axis=0) - q[ok].min(axis=0)).max(), rel=1e-12)
    left = list(itertools.combinations(range(machine.n_legs), machine.n_legs - 1))
    worst = np.max([np.linalg.cond(j[:, list(s)]) for s in left], axis=0)
    assert m["failure_cond_max"][0] == pytest.approx(worst.max(), rel=1e-6)


@pytest.mark.parametrize("name", ["sliding_star", "archi"])
def test_a_variant_is_the_machine_built_with_those_dimensions(name):
    """Scaled links and platform, and the rails moved along their normal (y for both
    machines' x rails) away from the home position: ARCHI's home is at y = -0.4 m,
    off its rail line at y = 0, so the home position matters there."""
    machine = load_machine(name).model
    home_y = machine.home[1]
    legs = [dataclasses.replace(leg, link_length=leg.link_length * 1.1,
                                platform_point=tuple(0.8 * v for v in leg.platform_point),
                                rail_origin=(leg.rail_origin[0], home_y + 1.2 * (leg.rail_origin[1] - home_y)))
            for leg in machine.legs]
    edited = machine.with_legs(machine.name, legs)
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
