import numpy as np
import pytest

import sqfit
from sqfit import constants as C
from sqfit.metrics import iou_3d
from sqfit.fitting.line_gauge import ray_minima
from sqfit.fitting.raycost import posed_ray_residuals, ray_residuals
from sqfit.views.rays import CONTOUR, INSIDE, OUTSIDE, RaySet, contour_rays, outward_normals
from sqfit.geometry.superquadric import Superquadric, implicit
from sqfit.testing import paper_trial
from sqfit.kernels import backend
from sqfit.geometry.camera import world_bearings
from sqfit.geometry.silhouette import silhouette
from _helpers import turned_pose
from _numeric import central_difference

# Shapes near the ends of the soft bounds, but not on them (the penalty has a kink there).
SHAPES = [(0.11, 0.11), (0.11, 1.89), (1.89, 0.11), (1.89, 1.89), (1.0, 1.0), (0.5, 1.5)]


@pytest.fixture(scope="module")
def trial():
    return paper_trial(3)


def perturbed(trial, shape, seed):
    rng = np.random.default_rng(seed)
    xi = trial.gt.to_vector()
    xi[3:5] = shape
    xi[0:3] *= rng.uniform(0.7, 1.3, 3)
    xi[5:8] += rng.normal(size=3) * 0.2
    xi[8:11] += rng.normal(size=3) * 0.1
    return xi


@pytest.mark.parametrize("shape", SHAPES)
def test_ray_minima_match_brute_force(trial, shape):
    rays = contour_rays(trial.observations, 16)
    xi = perturbed(trial, shape, 1)
    d, log_m = ray_minima(xi, rays.origins, rays.directions)
    sq = Superquadric.from_vector(xi)
    depths = np.linspace(0.01, 30.0, 30001)
    for i in range(0, len(d), 5):
        lg = 0.5 * xi[3] * np.log(implicit(sq, rays.origins[i] + depths[:, None] * rays.directions[i]))
        assert log_m[i] <= lg.min() + 1e-9  # never above the grid minimum ...
        assert log_m[i] >= lg.min() - 1e-3  # ... and the grid is fine enough to be close


def test_ray_minima_warm_start_agrees(trial):
    rays = contour_rays(trial.observations, 16)
    xi = perturbed(trial, (0.5, 1.5), 2)
    d, log_m = ray_minima(xi, rays.origins, rays.directions)
    xi2 = xi.copy()
    xi2[5] += 1e-3
    _, cold = ray_minima(xi2, rays.origins, rays.directions)
    _, warm = ray_minima(xi2, rays.origins, rays.directions, d0=d)
    np.testing.assert_allclose(warm, cold, atol=1e-6)


# For e2 near 1.9 (octahedron-like sections) rays grazing an edge have their minimiser on a
# coordinate plane, where |y|^(2 / e2) is nearly a kink: central differences of such rows carry
# errors of ~1e-4, so there the Jacobian is compared at 1e-3 (it was off by up to ~0.5, an expected
# failure here, before the minimiser's motion with the plane was added:
# sqfit.fitting.raycost.crossing_correction).
KINKY_E2 = 1.8
# 3G's own lower bound (``constants.SILHOUETTE_SHAPE_BOUNDS``), just above it and just below (the
# penalty is soft), where boxes and cylinders end: powers of 2 / e ~ 130 stay finite in log space.
SHARP = C.SILHOUETTE_SHAPE_BOUNDS[0]
SHARP_SHAPES = [(1.1 * SHARP, 1.1 * SHARP), (1.1 * SHARP, 1.0), (1.0, 1.1 * SHARP), (0.8 * SHARP, 0.8 * SHARP)]
JAC_SHAPES = [(0.11, 0.11), (0.11, 1.89), (1.89, 0.11), (1.89, 1.89), (1.0, 1.0), (0.5, 1.5)] + SHARP_SHAPES


@pytest.mark.parametrize("shape", JAC_SHAPES)
@pytest.mark.parametrize("band", [0.0, 2.0])
def test_ray_residual_jacobian_matches_central_differences(trial, shape, band):
    rays = contour_rays(trial.observations, 16, band_px=band, n_inside=5)
    xi = perturbed(trial, shape, 4)
    r, J, _ = ray_residuals(xi, rays)
    assert r.shape == (len(rays) + 11,) and J.shape == (len(rays) + 11, 11)
    f = lambda x: ray_residuals(x, rays)[0]  # noqa: E731
    num, fine = central_difference(f, xi), central_difference(f, xi, h=1e-7)
    # Rays grazing an edge of an edgy shape (a kink of m) are not differentiable: where two step
    # sizes disagree, the difference quotient is meaningless; at most a few rays may be such.
    smooth = np.all(np.abs(num - fine) < 1e-4 * max(1.0, np.abs(num).max()), axis=1)
    assert smooth.mean() > 0.7
    tol = 1e-3 if shape[1] > KINKY_E2 else 1e-5
    np.testing.assert_allclose(J[smooth], num[smooth], atol=tol * max(1.0, np.abs(num).max()))


@pytest.mark.parametrize("kernels", ["numba", "numpy"])
@pytest.mark.parametrize("shape", [(1.0, 1.8), (1.8, 1.0), (0.5, 1.9), (1.9, 0.3), (1.7, 1.6)])
def test_jacobian_where_the_minimiser_is_on_a_coordinate_plane(trial, kernels, shape):
    """Rays through the exact outline of superquadrics whose sections are diamond-like (``e > 1``)
    graze them at their edges, where the ray's minimiser lies on a coordinate plane and the slope of
    ``|y_j|^(2 / e)`` along the ray never reaches 0 in floating point: the Jacobian in the position
    and the rotation must carry the minimiser's motion with that plane
    (:func:`sqfit.fitting.raycost.crossing_correction`; without it off by 4-70 % per column here).
    Minimisers on an axis (two planes: rays through a pointed tip) are left out, as the correction
    leaves them."""
    if kernels == "numba":
        pytest.importorskip("numba")
    previous = backend.set_kernels(kernels)
    try:
        rng = np.random.default_rng(7)
        xi = np.r_[rng.uniform(0.5, 2.0, 3), shape, rng.uniform(-1.0, 1.0, 3), rng.uniform(-np.pi, np.pi, 3)]
        sq = Superquadric.from_vector(xi)
        origins, directions = [], []
        for cam in trial.cameras:
            b = world_bearings(cam, silhouette(sq, cam, 48))
            origins.append(np.broadcast_to(cam.center, b.shape))
            directions.append(b)
        n = sum(len(b) for b in directions)
        rays = RaySet(np.concatenate(origins), np.concatenate(directions), np.full(n, CONTOUR), np.ones(n),
                      np.zeros(n, dtype=int))
        x0 = xi * np.r_[1.02, 0.98, 1.01, np.ones(8)]  # the rays still graze near the edges
        _, J, d = ray_residuals(x0, rays, 0.0)
        f = lambda x: ray_residuals(x, rays, 0.0)[0][:n]  # noqa: E731
        num = central_difference(f, x0, h=1e-7)
        R = Superquadric.from_vector(x0).rotation_matrix
        near = np.abs((rays.origins + d[:, None] * rays.directions - x0[5:8]) @ R) / np.abs(x0[:3]) < 1e-6
        assert (near.sum(axis=1) == 1).sum() >= 10  # the case at hand: many minimisers on one plane
        kept = near.sum(axis=1) < 2
        pose = slice(5, 11)
        error = np.abs(J[:n][kept, pose] - num[kept, pose]).max(axis=0) / np.abs(num[kept, pose]).max(axis=0)
        assert error.max() < 1e-2, error
    finally:
        backend.set_kernels(previous)


def test_residual_sign_sees_both_sides(trial):
    rays = contour_rays(trial.observations, 32)
    xi = trial.gt.to_vector()
    r_true = ray_residuals(xi, rays)[0][:len(rays)]
    big, small = xi.copy(), xi.copy()
    big[0:3] *= 1.3
    small[0:3] *= 0.7
    assert np.abs(r_true).max() < 0.05  # rays through the true outline graze the true SQ
    assert np.mean(ray_residuals(big, rays)[0][:len(rays)]) < -0.02  # too large: rays pass through
    assert np.mean(ray_residuals(small, rays)[0][:len(rays)]) > 0.02  # too small: rays miss


def test_outward_normals_point_out_of_a_ccw_square():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])  # positive shoelace area
    n = outward_normals(square)
    np.testing.assert_allclose(np.einsum("ij,ij->i", n, square - 0.5) > 0, True)


def test_band_rays_have_inside_and_outside_modes(trial):
    rays = contour_rays(trial.observations, 10, band_px=1.5, n_inside=3)
    assert np.sum(rays.modes == INSIDE) == 3 * (10 + 3) and np.sum(rays.modes == OUTSIDE) == 30
    assert not np.any(rays.modes == CONTOUR)
    np.testing.assert_allclose(np.bincount(rays.view, rays.weights ** 2), 1.0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(n_contour=2), "n_contour must be an integer >= 3"),
    (dict(n_contour=4.5), "n_contour must be an integer >= 3"),
    (dict(band_px=-1.0), "band_px must be a finite number >= 0"),
    (dict(band_px=np.nan), "band_px must be a finite number >= 0"),
    (dict(n_inside=-1), "n_inside must be an integer >= 0"),
])
def test_contour_rays_validation(trial, kwargs, match):
    with pytest.raises(ValueError, match=match):
        contour_rays(trial.observations, **kwargs)


def test_contour_rays_needs_observations(trial):
    with pytest.raises(ValueError, match="observations must not be empty"):
        contour_rays([])
    with pytest.raises(TypeError, match=r"observations\[0\] must be a sqfit.Observation"):
        contour_rays(["mask"])


@pytest.mark.parametrize("views, kwargs", [(1, {}), (4, {}), (4, dict(smooth_px=2.0)), (4, dict(band_px=1.0, n_inside=3))])
def test_contour_rays_pass_the_checks_they_skip(trial, views, kwargs):
    """contour_rays builds its RaySet without re-running RaySet's checks: what it builds must pass
    them unchanged (dtypes, shapes, finite values, radii > 0)."""
    rays = contour_rays(trial.observations[:views], 12, **kwargs)
    fields = ("origins", "directions", "modes", "weights", "view", "two_sided", "offsets", "radii")
    checked = RaySet(*(getattr(rays, f) for f in fields))
    for f in fields:
        a, b = getattr(rays, f), getattr(checked, f)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), f


def test_rayset_validation():
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    with pytest.raises(ValueError, match="modes must be CONTOUR"):
        RaySet(o, d, [0, 5], [1.0, 1.0], [0, 0])
    with pytest.raises(ValueError, match="weights must be >= 0"):
        RaySet(o, d, [0, 1], [1.0, -1.0], [0, 0])
    with pytest.raises(ValueError, match=r"directions must have shape \(2, 3\)"):
        RaySet(o, np.ones((3, 3)), [0, 1], [1.0, 1.0], [0, 0])


def test_outward_normals_validation():
    with pytest.raises(ValueError, match="contour must have at least 3 vertices"):
        outward_normals(np.zeros((2, 2)))


def test_stage_3g_is_registered_and_the_default_chain_is_pinned():
    assert "3G" in sqfit.STAGES
    # 2M: moments start; 3H: axis screen, then 3G (tests/test_axis_search.py); 3R: tests/test_trimmed_stage.py;
    # 3U: tests/test_two_parts.py, running 3V (tests/test_least_volume.py) and, where it keeps no part, 3W
    # (tests/test_weighted_overlap.py)
    assert sqfit.DEFAULT_CHAIN == "1-2M-3H-3R-3U"


@pytest.mark.parametrize("seed", [0, 3])
def test_chain_1_2_3g_recovers_paper_trials(seed):
    trial = paper_trial(seed)
    # Seed 3 ends 1-2-3G in a wrong-axes basin (0.81; 3H fixes it: test_axis_search.py), where the
    # looser default prior of the pose corrections (50) slides further (0.78), and so does a free
    # outline offset, which absorbs some of the wrong basin's misfit (0.68): pin the earlier 20, no offset.
    result = sqfit.fit(trial.observations, "1-2-3G", options={"pose_sigma_deg": 20.0, "outline_offset_sigma_px": 0.0})
    assert result.ok
    assert iou_3d(result.superquadric, trial.gt) > 0.8


# --------------------------------------------------------------------------- pose refinement

def posed(xi, seed, scale=0.02):
    return np.r_[xi, np.random.default_rng(seed).normal(size=9) * scale]


@pytest.mark.parametrize("shape", [(0.11, 0.11), (1.89, 0.11), (1.0, 1.0), (0.5, 1.5)] + SHARP_SHAPES[:2])
def test_posed_ray_residual_jacobian_matches_central_differences(trial, shape):
    rays = contour_rays(trial.observations, 16)
    x = posed(perturbed(trial, shape, 4), 5)
    r, J, _ = posed_ray_residuals(x, rays, 0.01)
    assert r.shape == (len(rays) + 11 + 9,) and J.shape == (len(rays) + 11 + 9, 20)
    f = lambda y: posed_ray_residuals(y, rays, 0.01)[0]  # noqa: E731
    num, fine = central_difference(f, x), central_difference(f, x, h=1e-7)
    smooth = np.all(np.abs(num - fine) < 1e-4 * max(1.0, np.abs(num).max()), axis=1)
    assert smooth.mean() > 0.7
    assert np.abs(J[:len(rays), 11:]).max() > 1e-2  # the rotation columns are not trivially zero
    np.testing.assert_allclose(J[smooth], num[smooth], atol=1e-5 * max(1.0, np.abs(num).max()))


def test_posed_residuals_at_zero_correction_are_the_plain_ones(trial):
    rays = contour_rays(trial.observations, 16)
    xi = perturbed(trial, (0.5, 1.5), 6)
    r0, J0, _ = ray_residuals(xi, rays)
    r, J, _ = posed_ray_residuals(np.r_[xi, np.zeros(9)], rays, 0.02)
    np.testing.assert_allclose(r[:len(r0)], r0)
    np.testing.assert_allclose(J[:len(r0), :11], J0)
    np.testing.assert_allclose(r[len(r0):], 0.0)


def test_posed_correction_turns_rays_like_the_camera_rotation(trial):
    """A correction ``w`` equals the first-order camera rotation ``R' = exp([w]x) R``, camera frame
    ``delta = R^T w`` (the model of ``sqsim.imaging.noise.perturb_pose``)."""
    from sqfit.fitting.grazing import camera_corrections

    delta = np.array([[0.01, -0.02, 0.005], [0.0, 0.0, 0.0], [-0.01, 0.01, 0.02]])
    rotated = [sqfit.Observation(sqfit.Camera(o.camera.intrinsics, turned_pose(o.camera.pose, dv)), o.samples,
                                 o.contour, o.centroid, o.area_px, o.touches_border)
               for o, dv in zip(trial.observations, delta)]
    xi = trial.gt.to_vector()
    plain = ray_residuals(xi, contour_rays(rotated, 32))[0][:96]
    rotations = np.stack([o.camera.rotation for o in trial.observations])
    w = np.einsum("vij,vj->vi", rotations, delta).ravel()
    np.testing.assert_allclose(camera_corrections(w, rotations), delta, atol=1e-15)
    corrected = posed_ray_residuals(np.r_[xi, w], contour_rays(trial.observations, 32), 1.0)[0][:96]
    uncorrected = ray_residuals(xi, contour_rays(trial.observations, 32))[0][:96]
    change = np.abs(plain - uncorrected).max()
    assert change > 0.01  # the rotation matters ...
    assert np.abs(corrected - plain).max() < 0.02 * change  # ... and the correction reproduces it


@pytest.mark.parametrize("x, sigma, match", [
    (np.zeros(11), 0.01, r"x must have shape \(20,\)"),
    (np.zeros(20), 0.0, r"x must have shape \(11,\)"),  # sigma 0: no rotation unknowns
    (np.zeros(20), np.inf, "sigma_rad must be a finite number >= 0"),
    (np.zeros(20), -0.1, "sigma_rad must be a finite number >= 0"),
])
def test_posed_ray_residuals_validation(trial, x, sigma, match):
    with pytest.raises(ValueError, match=match):
        posed_ray_residuals(x, contour_rays(trial.observations, 8), sigma)


@pytest.mark.parametrize("value", [-1.0, np.nan])
def test_pose_sigma_option_validation(value):
    with pytest.raises(ValueError, match="pose_sigma_deg must be a finite number >= 0"):
        sqfit.FitOptions(pose_sigma_deg=value)


def test_pose_refinement_explains_a_rotated_camera():
    """One camera turned by 1 degree: with pose refinement 3G reaches a lower cost (the views
    become consistent) and reports the corrections."""
    trial = paper_trial(1)
    obs = list(trial.observations)
    o = obs[0]
    obs[0] = sqfit.Observation(sqfit.Camera(o.camera.intrinsics, turned_pose(o.camera.pose, np.radians([0, 1, 0]))),
                               o.samples, o.contour, o.centroid, o.area_px, o.touches_border)
    plain = sqfit.fit(obs, "1-2-3G", options={"pose_sigma_deg": 0.0})
    refined = sqfit.fit(obs, "1-2-3G", options={"pose_sigma_deg": 20.0})
    assert plain.ok and refined.ok
    assert "camera rotation corrections [deg, camera frame]" in refined.stages[-1].message
    assert "corrections" not in plain.stages[-1].message
    assert refined.cost < 0.9 * plain.cost  # the prior rows included
