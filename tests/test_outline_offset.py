"""The outline offset of stage 3G (issue 22): rays moved along the outline normal, the offset estimated
with the superquadric (sqfit.views.rays, sqfit.fitting.raycost.posed_ray_residuals, sqfit.fitting.grazing)."""

import numpy as np
import pytest

import sqfit
from sqfit import constants as C
from sqfit.fitting import grazing
from sqfit.fitting.raycost import posed_ray_residuals, ray_residuals
from sqfit.geometry.camera import project
from sqfit.metrics import iou_3d
from sqfit.testing import paper_trial
from sqfit.views.rays import MIN_RADIUS_PX, RaySet, arc_normals, contour_rays
from _numeric import central_difference
from _helpers import stage


@pytest.fixture(scope="module")
def trial():
    return paper_trial(3)


def _disc(radius, centre=(50.0, 40.0), n=400):
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    # counter-clockwise in image coordinates (v down): positive shoelace area
    return np.stack([centre[0] + radius * np.cos(t), centre[1] - radius * np.sin(t)], axis=1)[::-1]


def _pixels(camera, directions):
    """Image points of ray directions (unit camera depth)."""
    return project(camera, camera.center + directions)[0]


def _biased(trial, delta):
    """``trial``'s observations with every mask's outline moved by ``delta`` px (sqsim's mask model)."""
    from sqsim.imaging.mask_models import bias_boundary

    rng = np.random.default_rng(0)
    return [sqfit.Observation.from_mask(cam, bias_boundary(m, delta), 100, "uniform", rng)
            for cam, m in zip(trial.cameras, trial.masks)]


# --------------------------------------------------------------------------- rays


def test_arc_normals_point_outward_on_a_disc():
    disc = _disc(20.0)
    arc = np.linspace(0.0, 100.0, 17)
    normals = arc_normals(disc, arc)
    at = disc[np.round(arc / (2 * np.pi * 20.0 / 400)).astype(int) % 400]
    radial = (at - [50.0, 40.0]) / 20.0
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", normals, radial) > np.cos(np.radians(2.0)))


@pytest.mark.parametrize("contour, half, match", [
    (np.zeros((2, 2)), 1.0, "at least 3 vertices"),
    (np.zeros((5, 3)), 1.0, r"contour must have shape \(n, 2\)"),
    (_disc(5.0), 0.0, "half_arc must be a finite number > 0"),
    (_disc(5.0), np.nan, "half_arc must be a finite number > 0"),
])
def test_arc_normals_validation(contour, half, match):
    with pytest.raises(ValueError, match=match):
        arc_normals(contour, [0.0], half)


def test_offsets_move_each_ray_by_a_pixel_along_the_inward_normal(trial):
    rays = contour_rays(trial.observations, 32)
    for v, o in enumerate(trial.observations):
        idx = np.flatnonzero(rays.view == v)
        cam = o.camera
        at = _pixels(cam, rays.directions[idx])
        moved = _pixels(cam, rays.directions[idx] + 0.7 * rays.offsets[idx])
        step = moved - at
        np.testing.assert_allclose(np.linalg.norm(step, axis=1), 0.7, rtol=1e-9)
        # the silhouette behind an outline that lies outside it is further in: towards the centroid
        assert np.all(np.einsum("ij,ij->i", step, at - o.centroid) < 0)


def test_radii_are_the_distance_from_the_centroid_along_the_normal(trial):
    rays = contour_rays(trial.observations, 32, n_inside=4)
    inside = rays.modes == 1
    assert np.all(np.isinf(rays.radii[inside])) and np.all(rays.offsets[inside] == 0)
    outline = rays.radii[~inside]
    assert np.all(outline >= MIN_RADIUS_PX)
    for v, o in enumerate(trial.observations):
        at = _pixels(o.camera, rays.directions[(rays.view == v) & ~inside])
        distance = np.linalg.norm(at - o.centroid, axis=1)
        assert np.all(rays.radii[(rays.view == v) & ~inside] <= distance + 1e-9)  # a projection of it


def test_smoothed_points_average_the_outline(trial):
    plain = contour_rays(trial.observations, 32)
    smooth = contour_rays(trial.observations, 32, smooth_px=2.0)
    cam = trial.observations[0].camera
    a = _pixels(cam, plain.directions[plain.view == 0])
    b = _pixels(cam, smooth.directions[smooth.view == 0])
    shift = np.linalg.norm(a - b, axis=1)
    assert 0 < shift.max() < 1.0  # within the staircase of the outline, not beside it
    np.testing.assert_array_equal(plain.offsets, smooth.offsets)


@pytest.mark.parametrize("kwargs, match", [
    ({"smooth_px": -1.0}, "smooth_px must be a finite number >= 0"),
    ({"smooth_px": np.inf}, "smooth_px must be a finite number >= 0"),
])
def test_contour_rays_validation(trial, kwargs, match):
    with pytest.raises(ValueError, match=match):
        contour_rays(trial.observations, 8, **kwargs)


def test_rayset_checks_offsets_and_radii():
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    rays = RaySet(o, d, [0, 0], [1.0, 1.0], [0, 0])
    assert np.all(rays.offsets == 0) and np.all(np.isinf(rays.radii))
    with pytest.raises(ValueError, match=r"offsets must have shape \(2, 3\)"):
        RaySet(o, d, [0, 0], [1.0, 1.0], [0, 0], offsets=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="radii must be > 0"):
        RaySet(o, d, [0, 0], [1.0, 1.0], [0, 0], radii=[1.0, 0.0])


# --------------------------------------------------------------------------- residuals


def _x(trial, pose, groups, seed=5):
    rng = np.random.default_rng(seed)
    xi = trial.gt.to_vector() * np.r_[1.1, 0.9, 1.05, 1.0, 1.0, np.ones(6)] + np.r_[np.zeros(5), 0.05, -0.05, 0.02,
                                                                                      0.02, 0.0, 0.0]
    return np.r_[xi, rng.normal(size=9) * 0.01 if pose else [], rng.normal(size=groups) * 0.6]


@pytest.mark.parametrize("pose", [True, False])
@pytest.mark.parametrize("per_view", [False, True])
def test_offset_jacobian_matches_central_differences(trial, pose, per_view):
    rays = contour_rays(trial.observations, 16, smooth_px=2.0)
    groups = rays.view if per_view else None
    g = 3 if per_view else 1
    x = _x(trial, pose, g)
    sigma = 0.02 if pose else 0.0

    def f(y):
        return posed_ray_residuals(y, rays, sigma, offset_sigma_px=0.5, offset_groups=groups)[0]

    r, J, _ = posed_ray_residuals(x, rays, sigma, offset_sigma_px=0.5, offset_groups=groups)
    p = 9 if pose else 0
    assert r.shape == (len(rays) + 11 + p + g,) and J.shape == (len(r), 11 + p + g)
    num = central_difference(f, x)
    n = len(rays)
    assert np.abs(J[:n, -g:]).max() > 1e-3  # the offset columns are not trivially zero
    np.testing.assert_allclose(J, num, atol=1e-6 * max(1.0, np.abs(num).max()))
    np.testing.assert_allclose(r[-g:], x[-g:] / 0.5)


def test_zero_offsets_give_the_plain_residuals(trial):
    rays = contour_rays(trial.observations, 16)
    xi = trial.gt.to_vector() * np.r_[1.2, 1.0, 0.9, 1.0, 1.0, np.ones(6)]
    r0, J0, _ = ray_residuals(xi, rays)
    r, J, _ = posed_ray_residuals(np.r_[xi, 0.0], rays, 0.0, offset_sigma_px=1.0)
    np.testing.assert_allclose(r[:len(r0)], r0, atol=1e-15)
    np.testing.assert_allclose(J[:len(r0), :11], J0, atol=1e-15)


@pytest.mark.parametrize("offset", [0.8, -0.8])
def test_offset_turns_rays_like_shifted_rays(trial, offset):
    rays = contour_rays(trial.observations, 16)
    xi = trial.gt.to_vector()
    r, _, _ = posed_ray_residuals(np.r_[xi, offset], rays, 0.0, offset_sigma_px=1.0)
    plain = ray_residuals(xi, grazing.shifted_rays(rays, [offset]))[0]
    n = len(rays)
    # the same rays; an inward offset's rows carry the radius factor exp(-o / h), an outward one's none
    factor = np.exp(-min(offset, 0.0) / rays.radii)
    np.testing.assert_allclose(r[:n], plain[:n] * factor, atol=1e-15)


@pytest.mark.parametrize("sigma, offset_sigma, x_len, match", [
    (0.0, 1.0, 11, r"x must have shape \(12,\)"),
    (-1.0, 1.0, 12, "sigma_rad must be a finite number >= 0"),
    (0.0, -1.0, 12, "offset_sigma_px must be a finite number >= 0"),
    (0.0, np.nan, 12, "offset_sigma_px must be a finite number >= 0"),
])
def test_posed_residuals_validate_the_offsets(trial, sigma, offset_sigma, x_len, match):
    with pytest.raises(ValueError, match=match):
        posed_ray_residuals(np.ones(x_len), contour_rays(trial.observations, 8), sigma, offset_sigma_px=offset_sigma)


def test_offset_groups_are_checked(trial):
    rays = contour_rays(trial.observations, 8)
    with pytest.raises(ValueError, match=r"offset_groups must have shape \(24,\)"):
        posed_ray_residuals(np.ones(12), rays, 0.0, offset_sigma_px=1.0, offset_groups=[0, 1])
    with pytest.raises(ValueError, match="offset_groups must be >= 0"):
        posed_ray_residuals(np.ones(12), rays, 0.0, offset_sigma_px=1.0, offset_groups=-np.ones(24))


def test_prior_follows_the_residual_noise():
    r = np.full(100, 0.01)
    np.testing.assert_allclose(grazing.offset_prior(1.0, r), [[0.01]])
    np.testing.assert_allclose(grazing.offset_prior(2.0, 3 * r), [[0.015]])


def test_views_prior_is_the_inverse_covariance():
    r = np.full(100, 0.01)
    W = grazing.offset_prior(1.0, r, 3, 0.5)
    cov = np.ones((3, 3)) + 0.25 * np.eye(3)
    np.testing.assert_allclose(W.T @ W, np.linalg.inv(cov) * 1e-4, rtol=1e-12)


def test_offset_prior_matrix_gives_the_prior_rows(trial):
    rays = contour_rays(trial.observations, 8)
    W = np.array([[2.0, 0.0, 0.0], [1.0, 3.0, 0.0], [0.5, 0.5, 4.0]])
    x = np.r_[trial.gt.to_vector(), 0.1, -0.2, 0.3]
    r, J, _ = posed_ray_residuals(x, rays, 0.0, offset_sigma_px=1.0, offset_groups=rays.view, offset_prior=W)
    np.testing.assert_allclose(r[-3:], W @ x[-3:])
    np.testing.assert_array_equal(J[-3:, -3:], W)
    with pytest.raises(ValueError, match=r"offset_prior must have shape \(3, 3\)"):
        posed_ray_residuals(x, rays, 0.0, offset_sigma_px=1.0, offset_groups=rays.view, offset_prior=np.eye(2))


# --------------------------------------------------------------------------- estimator


@pytest.mark.parametrize("delta", [1.0, -1.0])
def test_3g_recovers_a_boundary_bias(delta):
    trial = paper_trial(2)
    obs = _biased(trial, delta)
    fixed = sqfit.fit(obs, "3G", initial=trial.gt, options={"outline_offset_sigma_px": 0.0})
    free = sqfit.fit(obs, "3G", initial=trial.gt)
    estimate = free.stages[-1].outline_offset_px
    assert len(estimate) == 1 and abs(estimate[0] - delta) < 0.3 and free.outline_offset_px == estimate
    assert iou_3d(free.superquadric, trial.gt) > iou_3d(fixed.superquadric, trial.gt) + 0.03
    assert iou_3d(free.superquadric, trial.gt) > 0.97


def test_offset_stays_near_zero_on_clean_masks():
    trial = paper_trial(1)
    kept = sqfit.fit(trial.observations, options={"idle_nuisances_plain": False})
    assert kept.outline_offset_px == stage(kept, "3H").outline_offset_px
    assert grazing.describe_offsets(kept.outline_offset_px) in stage(kept, "3H").message
    assert kept.to_dict()["outline_offset_px"] == kept.outline_offset_px
    assert abs(kept.outline_offset_px[0]) < 0.2
    # by default an offset that small is idle: 3H ends with plain 3G, and no offset is reported
    result = sqfit.fit(trial.observations)
    assert "nuisances were idle" in stage(result, "3H").message
    assert stage(result, "3H").outline_offset_px is None and result.outline_offset_px is None
    assert result.to_dict()["outline_offset_px"] is None
    assert iou_3d(result.superquadric, trial.gt) > 0.98


def test_default_chain_reports_the_offset_per_view_on_request():
    trial = paper_trial(1)
    result = sqfit.fit(_biased(trial, 1.0), options={"outline_offset": "view"})
    message = stage(result, "3H").message
    assert "outline offset [px] (view)" in message
    estimate = np.array(result.outline_offset_px)
    assert estimate.shape == (3,) and np.all(np.abs(estimate - 1.0) < 0.6)


def test_offsets_can_be_switched_off():
    trial = paper_trial(1)
    result = sqfit.fit(trial.observations, options={"outline_offset_sigma_px": 0.0})
    assert stage(result, "3H").outline_offset_px is None and result.outline_offset_px is None
    assert "outline offset [px]" not in stage(result, "3H").message


def _box_trial(index):
    """Observations of trial ``index`` of ``scenes/boxes.toml`` (seed 0: a trimesh box, clean masks) and its mesh."""
    from pathlib import Path

    from sqsim.imaging.render import get_renderer
    from sqsim.imaging.trial import observations, simulate_trial
    from sqsim.world.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "boxes.toml")
    sim = simulate_trial(scene, index, get_renderer(scene.masks.renderer, scene.intrinsics))
    box = sim.objects[0]
    return observations(sim, box.id, scene), box.mesh


def test_offset_is_not_estimated_for_a_shape_at_its_bound(monkeypatch):
    from sqfit.metrics import iou_3d_mesh

    obs, mesh = _box_trial(0)
    result = sqfit.fit(obs)
    assert grazing.at_shape_bound(result.superquadric.to_vector())
    assert result.outline_offset_px is None and "outline offset not estimated" in stage(result, "3H").message
    monkeypatch.setattr(grazing, "SHAPE_AT_BOUND", -1.0)  # estimated all the same: the box grows
    # (and kept: 3H's plain 3G where the offset is idle would drop this small one, sqfit.fitting.plain_run)
    free = sqfit.fit(obs, options={"idle_nuisances_plain": False})
    # -0.066 px, IoU 0.9849 against 0.9882 (-0.14 px with 3G's bound at 0.03, README "Real masks")
    assert free.outline_offset_px[0] < -0.05
    assert iou_3d_mesh(result.superquadric, mesh) > iou_3d_mesh(free.superquadric, mesh) + 0.003


def test_sharp_start_sets_only_flat_exponents_to_the_bound():
    from sqfit.fitting.plain_run import PLAIN_SHAPE_MIN, SHARP_BELOW, sharp_start

    xi = paper_trial(1).gt.to_vector()
    xi[3:5] = 0.9, 1.4
    assert sharp_start(xi) is None
    xi[3:5] = SHARP_BELOW / 2, 1.0
    start = sharp_start(xi)
    assert start[3] == PLAIN_SHAPE_MIN and start[4] == 1.0
    assert C.SHAPE_DOMAIN[0] < PLAIN_SHAPE_MIN <= C.SILHOUETTE_SHAPE_BOUNDS[0]
    assert np.array_equal(np.delete(start, 3), np.delete(xi, 3)) and xi[3] == SHARP_BELOW / 2  # a copy


def test_idle_plain_run_also_starts_from_sharp_edges(monkeypatch):
    """A box's fit from the refinement's result stops with rounded edges and a thicker body at
    nearly the same cost; the second start with sharp edges finds a lower cost and the box."""
    from sqfit.fitting import plain_run
    from sqfit.metrics import iou_3d_mesh

    obs, mesh = _box_trial(15)
    result = sqfit.fit(obs)
    assert "plain 3G from sharp edges" in stage(result, "3H").message
    monkeypatch.setattr(plain_run, "SHARP_BELOW", 0.0)  # no second start
    rounded = sqfit.fit(obs)
    assert "sharp edges" not in stage(rounded, "3H").message
    assert stage(result, "3H").cost < stage(rounded, "3H").cost  # both plain 3G costs
    sharp_e, rounded_e = (stage(f, "3H").superquadric.to_vector()[3:5] for f in (result, rounded))
    assert max(sharp_e) < max(rounded_e)
    # the plain runs' own bound, below the other silhouette stages'
    assert min(sharp_e) < C.SILHOUETTE_SHAPE_BOUNDS[0] - 0.003
    # 0.974 against 0.943 when this was written
    assert iou_3d_mesh(result.superquadric, mesh) > iou_3d_mesh(rounded.superquadric, mesh) + 0.015


def test_at_shape_bound():
    xi = paper_trial(1).gt.to_vector()
    xi[3:5] = 0.5, C.SILHOUETTE_SHAPE_BOUNDS[0] + 0.001
    assert grazing.at_shape_bound(xi)
    xi[4] = C.SILHOUETTE_SHAPE_BOUNDS[0] + 2 * grazing.SHAPE_AT_BOUND
    assert not grazing.at_shape_bound(xi)


def test_describe_offsets():
    message = grazing.describe_offsets(np.array([0.5, -1.25]), "view")
    assert message == "outline offset [px] (view): +0.500, -1.250"


def test_offset_follows_the_fit_through_the_chain():
    """The offset goes with the superquadric it was estimated with: a stage that passes its input on
    keeps it, a stage that moves the fit without estimating one drops it."""
    trial = paper_trial(2)
    obs = _biased(trial, 1.0)
    # 3T passes a fit that grazes its outline on unchanged (3G cost below its trigger)
    result = sqfit.fit(obs, "3G-3T", initial=trial.gt)
    g, t = stage(result, "3G"), stage(result, "3T")
    assert g.outline_offset_px is not None and abs(g.outline_offset_px[0] - 1.0) < 0.3
    assert "kept the input" in t.message and t.outline_offset_px == g.outline_offset_px
    assert result.outline_offset_px == g.outline_offset_px
    # 3A moves it by another cost, which has no offset
    moved = sqfit.fit(obs, "3G-3A", initial=trial.gt)
    assert stage(moved, "3G").outline_offset_px == g.outline_offset_px
    assert not np.array_equal(moved.superquadric.to_vector(), stage(moved, "3G").superquadric.to_vector())
    assert stage(moved, "3A").outline_offset_px is None and moved.outline_offset_px is None
    assert moved.to_dict()["stages"][0]["outline_offset_px"] == g.outline_offset_px


@pytest.mark.parametrize("options, match", [
    ({"outline_offset_sigma_px": -1.0}, "outline_offset_sigma_px must be a finite number >= 0"),
    ({"outline_offset": "pixel"}, "outline_offset must be one of"),
    ({"outline_offset_view_sigma_px": 0.0}, "outline_offset_view_sigma_px must be a finite number > 0"),
])
def test_options_validation(options, match):
    with pytest.raises(ValueError, match=match):
        sqfit.FitOptions(**options)
