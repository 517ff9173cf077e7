import numpy as np
import pytest

from sqfit import Superquadric
from sqfit.fitting.costs import (ObservationSet, g5_residuals, penalty, penalty_jacobian, radial_terms, riou_residuals,
                         rotation_and_derivatives, sample_points)
from sqfit.geometry.superquadric import euler_derivatives, euler_to_matrix, radial_distance
from sqfit.testing import paper_trial
from _numeric import central_difference

SHAPES = [(0.1, 0.1), (0.1, 1.9), (1.9, 0.1), (1.9, 1.9), (1.0, 1.0), (0.37, 1.42)]


@pytest.fixture(scope="module")
def trial():
    return paper_trial(3)


@pytest.mark.parametrize("shape", SHAPES)
def test_radial_terms_value_and_jacobian(shape):
    rng = np.random.default_rng(int(100 * shape[0] + 7 * shape[1]))
    for _ in range(3):
        xi = np.r_[rng.uniform(0.2, 3, 3), shape, rng.uniform(-2, 2, 3), rng.uniform(-np.pi, np.pi, 3)]
        pts = xi[5:8] + rng.normal(size=(25, 3)) * xi[0:3].mean()
        g, d_xi, d_pt = radial_terms(xi, pts)
        np.testing.assert_allclose(g, radial_distance(Superquadric.from_vector(xi), pts), atol=1e-12)
        num = central_difference(lambda x: radial_terms(x, pts)[0], xi)
        scale = np.abs(num).max()
        np.testing.assert_allclose(d_xi, num, atol=1e-6 * scale)
        num_pt = np.stack([central_difference(lambda p: radial_terms(xi, np.vstack([pts[:i], p, pts[i + 1:]]))[0][i:i + 1],
                                              pts[i].copy())[0] for i in range(len(pts))])
        np.testing.assert_allclose(d_pt, num_pt, atol=1e-6 * np.abs(num_pt).max())


def test_radial_terms_finite_on_the_axes():
    xi = np.array([1.0, 2.0, 0.5, 0.1, 1.9, 0, 0, 0, 0, 0, 0])
    pts = np.array([[0.5, 0, 0], [0, 3, 0], [0, 0, 0.2], [1, 1, 0]], float)
    g, d_xi, d_pt = radial_terms(xi, pts)
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(d_xi)) and np.all(np.isfinite(d_pt))
    np.testing.assert_allclose(g[:3], [0.5, -1.0, 0.3], atol=1e-12)


def test_rotation_and_derivatives_match_superquadric_module():
    r = np.array([0.4, -1.1, 2.9])
    R, dR = rotation_and_derivatives(r)
    np.testing.assert_allclose(R, euler_to_matrix(r), atol=1e-15)
    np.testing.assert_allclose(dR, euler_derivatives(r), atol=1e-15)


@pytest.mark.parametrize("shape", [(0.1, 0.1), (1.9, 1.9), (1.0, 1.0), (0.6, 1.3)])
@pytest.mark.parametrize("scaled", [True, False])
def test_g5_jacobian_blocks_against_finite_differences(trial, shape, scaled):
    obs = ObservationSet(trial.observations)
    rng = np.random.default_rng(5)
    xi = trial.gt.to_vector().copy()
    xi[3:5] = shape
    xi[0] = 0.05  # below the size bound: the penalty is active
    depths = rng.uniform(5, 15, len(obs.rays))
    r, A, D, P = g5_residuals(xi, depths, obs, 100.0, scaled)
    n = len(depths)
    assert r.shape == (n + 11,) and A.shape == (n, 11) and D.shape == (n,) and P.shape == (11,)
    num_A = central_difference(lambda x: g5_residuals(x, depths, obs, 100.0, scaled)[0][:n], xi)
    np.testing.assert_allclose(A, num_A, atol=1e-6 * np.abs(num_A).max())
    h = 1e-6
    num_D = (g5_residuals(xi, depths + h, obs, 100.0, scaled)[0][:n]
             - g5_residuals(xi, depths - h, obs, 100.0, scaled)[0][:n]) / (2 * h)
    np.testing.assert_allclose(D, num_D, atol=1e-6 * np.abs(num_D).max())
    num_P = central_difference(lambda x: g5_residuals(x, depths, obs, 100.0, scaled)[0][n:], xi)
    off_kink = np.abs(xi - np.array([0.1] * 5 + [9] * 6)) > 1e-3  # eps = 0.1 is exactly at the bound
    off_kink &= np.abs(xi - 1.9) > 1e-3
    np.testing.assert_allclose(np.diag(num_P)[off_kink], P[off_kink], atol=1e-6)
    assert P[0] == -100.0


def test_g5_is_volume_scaled_g4(trial):
    obs = ObservationSet(trial.observations)
    xi = trial.gt.to_vector()
    depths = np.full(len(obs.rays), 9.0)
    g4 = g5_residuals(xi, depths, obs, scaled=False)[0]
    g5 = g5_residuals(xi, depths, obs, scaled=True)[0]
    n = len(depths)
    np.testing.assert_allclose(g5[:n], g4[:n] * (np.prod(xi[0:3]) + 1))
    np.testing.assert_allclose(g4[:n], radial_distance(trial.gt, sample_points(obs, depths)))


def test_penalty_values_and_slopes():
    xi = np.array([0.05, 1.0, 2.0, 0.0, 2.5, 7, 7, 7, 9, 9, 9])
    np.testing.assert_allclose(penalty(xi, 1.0), [0.05, 0, 0, 0.1, 0.6, 0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(penalty(xi, 100.0), 100 * penalty(xi, 1.0))
    np.testing.assert_array_equal(penalty_jacobian(xi, 2.0), [-2, 0, 0, -2, 2, 0, 0, 0, 0, 0, 0])
    inside = np.array([1, 1, 1, 0.1, 1.9, 0, 0, 0, 0, 0, 0], float)
    assert not penalty(inside, 1.0).any()


def test_riou_residuals_at_ground_truth(trial):
    obs = ObservationSet(trial.observations)
    gt = trial.gt.to_vector()
    far = gt.copy()
    far[5:8] += 50.0  # around / behind the cameras: no silhouette, IoU 0
    r, start = riou_residuals(np.stack([gt, far]), obs)
    assert r.shape == (2, 3 + 11) and start.h.shape[:2] == (2, 3)
    # The hull of 100 uniform samples is a bit smaller than the silhouette.
    assert np.all(r[0, :3] < 0.2) and not r[0, 3:].any()
    np.testing.assert_array_equal(r[1, :3], 1.0)
    r_contour, _ = riou_residuals(gt[None], obs, polygon="contour")
    assert np.all(r_contour[0, :3] < 0.05)


def test_observation_set_rejects_other_types(trial):
    with pytest.raises(TypeError, match=r"observations\[1\] must be a sqfit.Observation"):
        ObservationSet([trial.observations[0], "mask"])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("shape, k, tol", [(None, 48, 0.1), ((0.1, 0.1), 48, 0.1), ((0.3, 1.6), 48, 0.1),
                                           ((1.9, 1.9), 512, 0.03), ((0.1, 1.9), 512, 0.03)])
def test_riou_analytic_jacobian_against_central_differences(seed, shape, k, tol):
    """The analytic R-IOU Jacobian (vertex velocities x edge flux) matches central differences of
    the residuals: the difference is the vertices' sliding along the silhouette, an effect of the
    polygon discretisation. At 48 vertices it is below 10 %, except for pointed shapes (e near
    1.9: nearly every vertex sits on a corner, the faces between are chords), whose shape columns
    need more vertices to agree."""
    t = paper_trial(seed)
    obs = ObservationSet(t.observations)
    rng = np.random.default_rng(seed)
    xi = t.gt.to_vector() + rng.normal(size=11) * [0.05, 0.05, 0.05, 0.1, 0.1, 0.05, 0.05, 0.05, 0.1, 0.1, 0.1]
    if shape is not None:
        xi[3:5] = shape
    r, h, d_views = riou_residuals(xi[None], obs, n_directions=k, jacobian=True)
    r_plain, _ = riou_residuals(xi[None], obs, n_directions=k)
    np.testing.assert_allclose(r, r_plain, atol=1e-9)
    assert np.all(r[0, :3] < 0.9)  # overlapping: a gradient exists
    J = d_views()
    assert J.shape == (1, 3, 11)
    num = central_difference(lambda x: riou_residuals(x[None], obs, n_directions=k)[0][0, :3], xi)
    for v in range(3):
        err = np.abs(J[0, v] - num[v]).max()
        assert err <= tol * np.abs(num[v]).max() + 1e-6, (v, J[0, v], num[v])


def test_riou_analytic_jacobian_is_zero_without_overlap(trial):
    obs = ObservationSet(trial.observations)
    xi = trial.gt.to_vector().copy()
    away = xi.copy()
    away[5:8] += 50.0  # around / behind the cameras: no silhouette
    beside = xi.copy()
    beside[0:3] = 0.1
    beside[5:8] += 3.0 * np.abs(xi[0:3]).max() * obs.rotations[0][:, 0]  # off to the side in view 0
    r, _, d_views = riou_residuals(np.stack([away, beside]), obs, jacobian=True)
    J = d_views()
    np.testing.assert_array_equal(r[0, :3], 1.0)
    np.testing.assert_array_equal(J[0], 0.0)
    assert r[1, 0] == 1.0 and not J[1, 0].any()


def test_riou_analytic_jacobian_needs_hull_polygons(trial):
    obs = ObservationSet(trial.observations)
    with pytest.raises(ValueError, match="convex observation polygons"):
        riou_residuals(trial.gt.to_vector()[None], obs, polygon="contour", jacobian=True)
