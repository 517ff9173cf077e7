"""The visual-hull baseline: carving (sqfit.views.carving), the EMS point fit (sqfit.fitting.pointcloud),
stage HULL and the chain alias ``hull`` (sqfit.fitting.hull)."""

import numpy as np
import pytest

import sqfit
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.hull import object_hull
from sqfit.fitting.pointcloud import fit_points, radial_residuals
from sqfit.fitting.stages import to_superquadric
from sqfit.geometry.camera import Camera, look_at, project
from sqfit.geometry.superquadric import contains, sample_surface_uniform, volume
from sqfit.metrics import iou_3d
from sqfit.testing import PAPER_INTRINSICS, polygon_mask, random_superquadric
from sqfit.views.carving import FINE_CELLS, VoxelHull, carve, fill_polygon, object_pixels, visual_hull

SQ = sqfit.Superquadric([1.0, 0.6, 0.4], [0.5, 1.2], [0.3, -0.2, 0.1], [0.3, 0.2, 0.5])


def _cameras(views=4, height=4.0):
    angles = 2.0 * np.pi * np.arange(views) / views
    return [Camera(PAPER_INTRINSICS, look_at([10.0 * np.cos(t), 10.0 * np.sin(t), height], [0.0, 0.0, 0.0]))
            for t in angles]


def _observations(sq, cameras):
    return [sqfit.Observation.from_mask(c, polygon_mask(sq, c), rng=0) for c in cameras]


@pytest.fixture(scope="module")
def hull():
    return visual_hull(_observations(SQ, _cameras()), [0.0, 0.0, 0.0], 1.0)


def test_object_pixels_give_the_mask_back():
    cam = _cameras()[1]
    mask = polygon_mask(SQ, cam)
    assert np.array_equal(object_pixels(sqfit.Observation.from_mask(cam, mask, rng=0)), mask)


def test_fill_polygon_is_by_pixel_centre():
    square = np.array([[0.6, 0.6], [3.4, 0.6], [3.4, 2.4], [0.6, 2.4]])  # centres 1..3 x 1..2
    expected = np.zeros((4, 5), dtype=bool)
    expected[1:3, 1:4] = True
    assert np.array_equal(fill_polygon(square, (4, 5)), expected)


def test_hull_contains_the_superquadric_and_is_not_much_larger(hull):
    rng = np.random.default_rng(0)
    # Points of the superquadric, shrunk by one voxel's diagonal from its surface.
    shrunk = sqfit.Superquadric(np.array(SQ.size) - np.sqrt(3.0) * hull.voxel, SQ.shape, SQ.position, SQ.rotation)
    lo, hi = np.array(SQ.position) - 1.2, np.array(SQ.position) + 1.2
    points = rng.uniform(lo, hi, (20000, 3))
    points = points[contains(shrunk, points)]
    assert len(points) > 1000
    assert hull.contains(points).all()
    assert volume(SQ) < hull.volume < 2.0 * volume(SQ)


def test_a_hull_contains_the_points_of_its_occupied_voxels_only():
    occupied = np.zeros((4, 4, 4), dtype=bool)
    occupied[1, 2, 3] = True
    hull = VoxelHull(occupied, np.array([1.0, 2.0, 3.0]), 0.5)
    points = [[1.5, 3.0, 4.5], [1.5, 3.0, 4.74], [1.5, 3.0, 4.76], [0.0, 0.0, 0.0], [3.5, 3.0, 4.5], [1.5, 2.5, 4.5],
              [1.5, 3.0, 4.25], [1.5, 3.0, 4.75]]  # halfway between two centres: the upper voxel
    assert hull.contains(points).tolist() == [True, True, False, False, False, False, True, False]
    assert hull.contains(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="points"):
        hull.contains([1.0, 2.0, 3.0])


def test_surface_points_lie_on_the_hull_boundary(hull):
    points = hull.surface_points()
    # Half a voxel in and out of every surface point: one side kept, the other carved.
    cell = (points - hull.origin) / hull.voxel
    frac = np.abs(cell - np.round(cell))
    assert np.all(np.sum(frac > 0.25, axis=1) == 1)  # each point is on exactly one face
    assert len(points) > 1000


def test_an_occluded_pixel_does_not_carve():
    cams = _cameras()
    mask = polygon_mask(SQ, cams[0])
    rows, cols = np.nonzero(mask)
    occluder = np.zeros_like(mask)
    occluder[:, cols.min():(cols.min() + cols.max()) // 2] = True  # hides the left half of the object
    seen = mask & ~occluder
    occluded = sqfit.Observation.from_mask(cams[0], seen, rng=0, occluder=occluder)
    unaware = sqfit.Observation.from_mask(cams[0], seen, rng=0)
    others = _observations(SQ, cams[1:])
    # Points of the superquadric that project onto the occluder in view 0.
    points = sample_surface_uniform(sqfit.Superquadric(np.array(SQ.size) * 0.9, SQ.shape, SQ.position, SQ.rotation),
                                    400, rng=0)
    uv, _ = project(cams[0], points)
    hidden = occluder[np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)]
    assert hidden.sum() > 50
    assert carve([occluded] + others, points[hidden]).all()
    assert not carve([unaware] + others, points[hidden]).any()


def test_a_point_outside_an_image_is_not_carved_by_that_view():
    cams = _cameras()
    obs = _observations(SQ, cams)
    centre = np.array([SQ.position])
    assert carve(obs, centre).all()
    blob = np.zeros((480, 640), dtype=bool)
    blob[10:20, 10:20] = True  # a mask elsewhere: the centre's pixel is background
    k = cams[0].intrinsics
    for cx, kept in ((k.cx, False), (-5000.0, True)):  # the centre inside / outside view 0's image
        camera = sqfit.Camera(sqfit.Intrinsics(k.width, k.height, k.fx, k.fy, cx, k.cy), cams[0].pose)
        view0 = sqfit.Observation.from_mask(camera, blob, rng=0)
        assert carve([view0] + obs[1:], centre)[0] == kept


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_point_fit_recovers_a_superquadric_among_outliers(seed):
    rng = np.random.default_rng(seed)
    sq = random_superquadric(rng)
    surface = sample_surface_uniform(sq, 1200, rng=rng)
    lo, hi = surface.min(axis=0), surface.max(axis=0)
    outliers = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), (300, 3))  # 20 % of the cloud
    points = rng.permutation(np.vstack([surface, outliers]))
    fit = fit_points(points)
    assert iou_3d(sq, to_superquadric(fit.xi)) > 0.95
    # Posterior inlier probabilities separate the two.
    z = fit_points(np.vstack([surface, outliers])).inlier
    assert np.mean(z[:1200] > 0.5) > 0.95 and np.mean(z[1200:] > 0.5) < 0.5


def test_radial_jacobian_matches_differences():
    rng = np.random.default_rng(3)
    xi = random_superquadric(rng).to_vector()
    points = xi[5:8] + rng.normal(size=(40, 3)) * xi[0:3].mean()
    _, J = radial_residuals(xi, points, jacobian=True)
    numeric = np.empty_like(J)
    for i in range(11):
        step = np.zeros(11)
        step[i] = 1e-6 * max(1.0, abs(xi[i]))
        numeric[:, i] = (radial_residuals(xi + step, points) - radial_residuals(xi - step, points)) / (2 * step[i])
    np.testing.assert_allclose(J, numeric, rtol=1e-5, atol=1e-6)


def test_hull_chain_fits_and_the_alias_expands():
    obs = _observations(SQ, _cameras())
    result = sqfit.fit(obs, chain="hull")
    assert result.ok and result.chain == "HULL"
    assert iou_3d(SQ, result.superquadric) > 0.75
    refined = sqfit.fit(obs, chain="HULL-3H")
    assert refined.ok and iou_3d(SQ, refined.superquadric) > 0.95


def test_hull_chain_refuses_an_initial_superquadric():
    with pytest.raises(ValueError, match="starts with stage 'HULL'"):
        sqfit.fit(_observations(SQ, _cameras()), chain="hull", initial=SQ)


def test_experiment_chain_list_expands_hull():
    from sqsim.runs.experiment import parse_chains

    assert parse_chains("default,hull,HULL-3H") == [sqfit.DEFAULT_CHAIN, "HULL", "HULL-3H"]


@pytest.mark.parametrize("kwargs, match", [
    (dict(points=np.zeros((5, 3))), "points must hold >= 11"),
    (dict(points=np.zeros((20, 2))), r"points must have shape \(n, 3\)"),
    (dict(points=np.ones((20, 3))), "all equal"),
    (dict(points=np.random.default_rng(0).normal(size=(20, 3)), outlier_weight=1.0), "outlier_weight"),
    (dict(points=np.random.default_rng(0).normal(size=(20, 3)), max_points=5), "max_points"),
])
def test_point_fit_rejects_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        fit_points(**kwargs)


def test_carving_rejects_bad_input():
    obs = _observations(SQ, _cameras())
    with pytest.raises(ValueError, match=">= 2 observations"):
        carve(obs[:1], np.zeros((1, 3)))
    with pytest.raises(ValueError, match="half_size"):
        visual_hull(obs, [0.0, 0.0, 0.0], -1.0)
    with pytest.raises(ValueError, match="radius"):
        carve(obs, np.zeros((1, 3)), radius=-0.1)
    with pytest.raises(TypeError, match="sqfit.Observation"):
        object_pixels(np.zeros((4, 4)))


def test_object_hull_carves_at_the_resolution_asked_for():
    obs = ObservationSet(_observations(SQ, _cameras()))
    default, coarse = object_hull(obs), object_hull(obs, fine=FINE_CELLS // 2)
    assert coarse.voxel == pytest.approx(2.0 * default.voxel, rel=0.1)
    assert max(default.occupied.shape) > 1.8 * max(coarse.occupied.shape)
    # the same solid either way, within the carvings' half-voxel rounding
    assert volume(SQ) < min(default.volume, coarse.volume) and max(default.volume, coarse.volume) < 2.0 * volume(SQ)
    assert coarse.volume == pytest.approx(default.volume, rel=0.15)
