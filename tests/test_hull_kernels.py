"""The visual hull's compiled kernels (sqfit.kernels.hull_kernels): the carving test and EMS's radial
residuals give what the numpy code gives (the same carvings; residuals and Jacobians to rounding)."""

import numpy as np
import pytest

import sqfit
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.hull import object_hull
from sqfit.fitting.pointcloud import fit_points, radial_residuals
from sqfit.geometry.camera import Camera, look_at
from sqfit.kernels import backend
from sqfit.testing import PAPER_INTRINSICS, polygon_mask, random_superquadric, truncated_trial
from sqfit.views.carving import background_clearance, carve

pytest.importorskip("numba")


def _with(name, f, *args, **kwargs):
    previous = backend.set_kernels(name)
    try:
        assert backend.kernels_name() == name
        return f(*args, **kwargs)
    finally:
        backend.set_kernels(previous)


def _views(sq, views=4):
    angles = 2.0 * np.pi * np.arange(views) / views + 0.3
    cams = [Camera(PAPER_INTRINSICS, look_at([10.0 * np.cos(t), 10.0 * np.sin(t), 4.0], [0.0, 0.0, 0.0]))
            for t in angles]
    return [sqfit.Observation.from_mask(c, polygon_mask(sq, c), rng=0) for c in cams]


@pytest.mark.parametrize("radius", [0.0, 0.05, 0.4])
def test_compiled_carving_is_the_numpy_carving(radius):
    obs = _views(sqfit.Superquadric([1.0, 0.6, 0.4], [0.5, 1.2], [0.3, -0.2, 0.1], [0.3, 0.2, 0.5]))
    rng = np.random.default_rng(1)
    # around the object, far outside the images, and behind the cameras (the 10 m circle)
    points = np.concatenate([rng.uniform(-2.0, 2.0, (20000, 3)), rng.uniform(-30.0, 30.0, (5000, 3))])
    clearances = [background_clearance(o) for o in obs]
    ours = _with("numba", carve, obs, points, radius, clearances)
    theirs = _with("numpy", carve, obs, points, radius, clearances)
    assert np.array_equal(ours, theirs)
    assert 0 < ours.sum() < len(points)


@pytest.mark.parametrize("seed", [0, 3])
def test_compiled_hull_is_the_numpy_hull_with_cut_views(seed):
    trial = truncated_trial(seed, cut_fraction=0.3, cut_views=1)  # a view's outline leaves the image
    obs = ObservationSet(trial.observations)
    ours, theirs = (_with(name, object_hull, obs) for name in ("numba", "numpy"))
    assert ours.voxel == theirs.voxel and np.array_equal(ours.origin, theirs.origin)
    assert np.array_equal(ours.occupied, theirs.occupied) and ours.occupied.any()


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # numpy's path at the centre point
def test_compiled_radial_residuals_agree_with_numpy():
    rng = np.random.default_rng(2)
    for _ in range(20):
        sq = random_superquadric(rng)
        xi = np.concatenate([sq.size * rng.choice([-1.0, 1.0], 3), sq.shape, sq.position, sq.rotation])
        points = sq.position + rng.normal(0.0, 1.5, (300, 3))
        points[:5] = sq.position + np.array([[1.0, 0.0, 0.0], [0.0, -2.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0],
                                             [0.3, 0.4, 0.0]]) @ sq.rotation_matrix.T  # on the local axes and planes
        d1, J1 = _with("numba", radial_residuals, xi, points, jacobian=True)
        d0, J0 = _with("numpy", radial_residuals, xi, points, jacobian=True)
        np.testing.assert_allclose(d1, d0, rtol=1e-12, atol=1e-12)
        finite = np.isfinite(J0).all(axis=1)
        assert finite[:3].all() and not finite[3]  # the centre itself has no direction
        np.testing.assert_array_equal(np.isfinite(J1), np.isfinite(J0))
        # Off the local axes and planes, to rounding. On them (the first five points) a coordinate is
        # the rotation's rounding noise (~1e-16), and the Jacobian terms it scales are too: finite alike.
        np.testing.assert_allclose(J1[5:], J0[5:], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(_with("numba", radial_residuals, xi, points), d1, rtol=0, atol=0)


def test_compiled_point_fit_is_the_numpy_fit():
    obs = ObservationSet(_views(sqfit.Superquadric([1.2, 0.5, 0.4], [0.3, 1.4], [0.0, 0.2, 0.1], [0.4, -0.3, 1.0])))
    points = object_hull(obs).surface_points()
    ours, theirs = (_with(name, fit_points, points) for name in ("numba", "numpy"))
    np.testing.assert_allclose(ours.xi, theirs.xi, rtol=0, atol=1e-9)
    assert ours.iterations == theirs.iterations and ours.switches == theirs.switches
