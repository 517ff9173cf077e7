"""One answer (issue 22, point 3): the default chain does not depend on the sampling seed.

Stage 2M (:mod:`sqfit.fitting.moments`), the exact polygon moments it uses, the deterministic
samples of the 3H rescue (:mod:`sqfit.views.grid`), and the default chain fitted on the same masks
with different sampling seeds.
"""

import numpy as np
import pytest
from skimage.measure import points_in_poly

import sqfit
from sqfit import Observation
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.moments import mask_moments_3d
from sqfit.geometry.polygon import batch_polygon_moments, polygon_moments
from sqfit.metrics import iou_3d
from sqfit.testing import paper_trial
from sqfit.views.grid import grid_samples, with_grid_samples, with_outline_samples
from _helpers import stage


def _ellipse(a, b, angle, centre, n=4000):
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c, s = np.cos(angle), np.sin(angle)
    x, y = a * np.cos(t), b * np.sin(t)
    return np.stack([c * x - s * y, s * x + c * y], axis=1) + centre


def _resampled(trial, seed, n_samples=100):
    """The trial's masks observed again with another sampling seed."""
    rng = np.random.default_rng(seed)
    return [Observation.from_mask(cam, m, n_samples, "uniform", rng) for cam, m in zip(trial.cameras, trial.masks)]


# ---------------------------------------------------------------------------------------------
# polygon_moments


def test_polygon_moments_of_a_rectangle_either_orientation():
    rect = np.array([[1.0, 2.0], [5.0, 2.0], [5.0, 4.0], [1.0, 4.0]])
    for poly in (rect, rect[::-1]):
        area, centroid, cov = polygon_moments(poly)
        assert area == pytest.approx(8.0)
        np.testing.assert_allclose(centroid, [3.0, 3.0])
        np.testing.assert_allclose(cov, np.diag([16.0 / 12.0, 4.0 / 12.0]), atol=1e-12)


def test_polygon_moments_of_an_ellipse():
    # Uniform over an ellipse of semi-axes (a, b): variances a^2 / 4 and b^2 / 4 along its axes.
    angle = 0.6
    area, centroid, cov = polygon_moments(_ellipse(30.0, 10.0, angle, [200.0, 100.0]))
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    assert area == pytest.approx(np.pi * 300.0, rel=1e-5)
    np.testing.assert_allclose(centroid, [200.0, 100.0], atol=1e-9)
    np.testing.assert_allclose(cov, R @ np.diag([225.0, 25.0]) @ R.T, rtol=1e-5)


@pytest.mark.parametrize("polygon, match", [(np.zeros((2, 2)), ">= 3 vertices"),
                                            (np.zeros((4, 3)), r"polygon must have shape \(n, 2\)"),
                                            ([[0, 0], [1, 1], [2, 2]], "zero area"),
                                            ([[0, 0], [1, 0], [np.nan, 1]], "polygon contains NaN")])
def test_polygon_moments_validation(polygon, match):
    with pytest.raises(ValueError, match=match):
        polygon_moments(polygon)


# ---------------------------------------------------------------------------------------------
# Stage 2M


def test_mask_moments_3d_equal_the_moments_of_back_projected_uniform_samples():
    # Many uniform samples back-projected at fixed depths: their pooled mean and covariance
    # converge to the exact ones (equal samples per view = equal-weight mixture).
    trial = paper_trial(3)
    obs = ObservationSet(_resampled(trial, 7, n_samples=40000))
    depths = np.array([9.0, 10.5, 11.0])
    points = obs.origins + obs.rays * depths[obs.view_of_sample][:, None]
    mean, cov = mask_moments_3d(obs, depths)
    np.testing.assert_allclose(mean, points.mean(axis=0), atol=0.01)
    np.testing.assert_allclose(cov, np.cov(points.T), atol=0.02 * np.abs(cov).max())


@pytest.mark.parametrize("depths, views, match", [(np.ones(2), None, r"depths must be \(3,\)"),
                                                  (np.array([1.0, -1.0, 1.0]), None, "> 0"),
                                                  (np.ones(3), np.zeros(3, bool), "at least one True")])
def test_mask_moments_3d_validation(depths, views, match):
    obs = ObservationSet(paper_trial(3).observations)
    with pytest.raises(ValueError, match=match):
        mask_moments_3d(obs, depths, views)


@pytest.mark.parametrize("seed", [3, 5, 11])
def test_stage_2m_is_stage_2_in_the_limit_of_many_samples(seed):
    trial = paper_trial(seed)
    many = sqfit.fit(_resampled(trial, 1, n_samples=20000), "1-2").superquadric
    exact = sqfit.fit(trial.observations, "1-2M").superquadric
    assert iou_3d(many, exact) > 0.97
    np.testing.assert_allclose(exact.shape, [1.0, 1.0])


def test_stage_2m_does_not_depend_on_the_samples():
    trial = paper_trial(5)
    a = sqfit.fit(_resampled(trial, 0), "1-2M").stages[-1].superquadric
    b = sqfit.fit(_resampled(trial, 1), "1-2M").stages[-1].superquadric
    assert a == b
    c = sqfit.fit(_resampled(trial, 0), "1-2").stages[-1].superquadric
    d = sqfit.fit(_resampled(trial, 1), "1-2").stages[-1].superquadric
    assert c != d  # stage 2 does: the test above can fail


# ---------------------------------------------------------------------------------------------
# Deterministic samples


@pytest.mark.parametrize("n", [20, 100, 500])
def test_grid_samples_are_about_n_points_inside(n):
    poly = _ellipse(40.0, 15.0, 0.3, [300.0, 200.0], n=600)
    pts = grid_samples(poly, n)
    assert 0.8 * n <= len(pts) <= 1.2 * n
    assert points_in_poly(pts, poly).all()
    np.testing.assert_array_equal(pts, grid_samples(poly, n))


def test_grid_samples_match_a_point_in_polygon_test_on_a_concave_outline():
    trial = paper_trial(9)
    for o in trial.observations:
        pts = grid_samples(o.contour, 300)
        assert points_in_poly(pts, o.contour).all()
        # No grid point inside was left out: the finer grid's count scales with the area.
        assert abs(len(pts) - 300) < 0.15 * 300


def test_grid_samples_refine_on_a_thin_region():
    sliver = np.array([[0.0, 0.0], [400.0, 0.0], [400.0, 1.0], [0.0, 1.0]])  # 400 px^2, 1 px wide
    pts = grid_samples(sliver, 100)
    assert len(pts) >= 50 and points_in_poly(pts, sliver).all()


def test_grid_samples_validation():
    with pytest.raises(ValueError, match="n must be an integer >= 3"):
        grid_samples(_ellipse(5.0, 5.0, 0.0, [0.0, 0.0]), 2)
    with pytest.raises(TypeError, match="observation must be a sqfit.Observation"):
        with_grid_samples(np.zeros((3, 2)))
    with pytest.raises(TypeError, match="observation must be a sqfit.Observation"):
        with_outline_samples(np.zeros((3, 2)))


def test_with_grid_and_outline_samples_keep_the_view():
    o = paper_trial(3).observations[0]
    for other in (with_grid_samples(o), with_outline_samples(o)):
        assert other.camera is o.camera
        np.testing.assert_array_equal(other.contour, o.contour)
        np.testing.assert_array_equal(other.centroid, o.centroid)
        assert (other.sample_labels == 0).all() or len(set(other.sample_labels)) == 1
    assert abs(len(with_grid_samples(o).samples) - len(o.samples)) < 0.2 * len(o.samples)
    np.testing.assert_array_equal(with_outline_samples(o).samples, o.contour)


# ---------------------------------------------------------------------------------------------
# The default chain


@pytest.mark.parametrize("seed", [0, 5, 27, 80])
def test_default_chain_gives_one_answer_whatever_the_sampling_seed(seed):
    trial = paper_trial(seed)
    fits = [sqfit.fit(_resampled(trial, s)) for s in (0, 1, 2)]
    assert fits[0].chain == sqfit.DEFAULT_CHAIN
    assert fits[0].superquadric == fits[1].superquadric == fits[2].superquadric


def test_the_rescue_gives_one_answer_whatever_the_sampling_seed(monkeypatch):
    # Force the rescue (3D-3A on the samples in the past) on every fit.
    from sqfit.fitting import axis_screen

    monkeypatch.setattr(axis_screen, "RESCUE_R_IOU_M", 1.01)
    trial = paper_trial(80)
    fits = [sqfit.fit(_resampled(trial, s)) for s in (0, 1)]
    assert all("re-fitted through 3D-3A-3H" in stage(f, "3H").message for f in fits)
    assert fits[0].superquadric == fits[1].superquadric


def test_batch_polygon_moments_equal_one_at_a_time():
    polys = [o.contour for o in paper_trial(3).observations] + [_ellipse(3.0, 1.0, 0.2, [5.0, 5.0], n=50)]
    area, centroid, cov = batch_polygon_moments(polys)
    for i, p in enumerate(polys):
        a, c, s = polygon_moments(p)
        assert area[i] == pytest.approx(a)
        np.testing.assert_allclose(centroid[i], c)
        np.testing.assert_allclose(cov[i], s)
    with pytest.raises(ValueError, match="at least one polygon"):
        batch_polygon_moments([])
    with pytest.raises(ValueError, match=r"polygons\[1\] must have shape"):
        batch_polygon_moments([polys[0], np.zeros((3, 3))])
