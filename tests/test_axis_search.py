import re

import numpy as np
import pytest

import sqfit
from sqfit import constants as C
from sqfit.fitting.axis_screen import CANDIDATES, axis_candidates, batch_levenberg_marquardt
from sqfit.metrics import iou_3d
from sqfit.fitting.raycost import batch_log_gauge_jacobian, batch_ray_residuals, log_gauge_jacobian, ray_residuals
from sqfit.views.rays import INSIDE, RaySet, contour_rays
from sqfit.testing import paper_trial
from _helpers import stage, through_3h, turned_pose


@pytest.fixture(scope="module")
def trial():
    return paper_trial(3)


@pytest.fixture(scope="module")
def start(trial):
    return sqfit.fit(trial.observations, "1-2").superquadric.to_vector()


def test_candidates_are_the_input_and_its_symmetric_reparametrisations(start):
    X = axis_candidates(start)
    assert X.shape == (len(CANDIDATES), C.N_PARAMS)
    np.testing.assert_allclose(X[0], start)
    # Permutations keep the sizes (as a set) and the centre; e = (1, 1) stays an ellipsoid.
    for row in X[[2, 4]]:
        np.testing.assert_allclose(np.sort(row[0:3]), np.sort(start[0:3]))
    np.testing.assert_allclose(X[:, 5:8], np.tile(start[5:8], (len(X), 1)))


@pytest.mark.parametrize("xi, match", [(np.ones(10), r"xi must have shape \(11,\)"),
                                       (np.r_[np.ones(10), np.nan], "xi contains NaN")])
def test_candidates_validation(xi, match):
    with pytest.raises(ValueError, match=match):
        axis_candidates(xi)


def test_batch_residuals_equal_one_at_a_time(trial, start):
    X = axis_candidates(start)
    X[:, 3:5] = [[0.3, 1.2], [1.0, 1.0], [1.7, 0.5], [0.05, 0.2], [0.6, 1.9], [1.0, 0.02]]
    rays = contour_rays(trial.observations, 16)
    r, J, d = batch_ray_residuals(X, rays)
    assert r.shape == (6, len(rays) + 11) and J.shape == (6, len(rays) + 11, 11) and d.shape == (6, len(rays))
    for i, xi in enumerate(X):
        ri, Ji, di = ray_residuals(xi, rays)
        np.testing.assert_allclose(r[i], ri, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(J[i], Ji, rtol=1e-9, atol=1e-12)
    # Warm starts give the same minima.
    r2, _, _ = batch_ray_residuals(X, rays, d0=d)
    np.testing.assert_allclose(r2, r, atol=1e-9)


def test_silhouette_penalty_allows_flat_shapes_below_the_paper_bound(trial, start):
    rays = contour_rays(trial.observations, 16)
    n = len(rays)
    flat = start.copy()
    flat[3:5] = 0.05  # inside 3G's bounds, outside eq. 7's
    assert np.all(ray_residuals(flat, rays)[0][n:] == 0)
    flat[3:5] = C.SILHOUETTE_SHAPE_BOUNDS[0] / 2
    assert np.all(ray_residuals(flat, rays)[0][n + 3:n + 5] > 0)


def test_batch_residuals_validation(trial):
    rays = contour_rays(trial.observations, 16)
    with pytest.raises(ValueError, match=r"X must have shape \(n, 11\)"):
        batch_ray_residuals(np.ones(11), rays)
    with pytest.raises(TypeError, match="rays must be a sqfit.views.rays.RaySet"):
        batch_ray_residuals(np.ones((2, 11)), "rays")


def test_batch_lm_decreases_every_cost(trial, start):
    rays = contour_rays(trial.observations, 16)
    X0 = axis_candidates(start)
    r0, _, _ = batch_ray_residuals(X0, rays)
    X, cost = batch_levenberg_marquardt(X0, rays, 5)
    assert np.all(cost <= 0.5 * (r0 ** 2).sum(axis=1))
    assert np.all(cost < 0.9 * 0.5 * (r0 ** 2).sum(axis=1))  # 5 steps from a sphere: a real descent
    X_same, cost_same = batch_levenberg_marquardt(X0, rays, 0)
    np.testing.assert_array_equal(X_same, X0)
    np.testing.assert_allclose(cost_same, 0.5 * (r0 ** 2).sum(axis=1))


@pytest.mark.parametrize("iterations", [-1, 2.5])
def test_batch_lm_validation(trial, start, iterations):
    rays = contour_rays(trial.observations, 16)
    with pytest.raises(ValueError, match="iterations must be an integer >= 0"):
        batch_levenberg_marquardt(axis_candidates(start), rays, iterations)


def test_default_chain_resolves_axes_on_a_block_of_paper_trials():
    """Seeds 0-9 (not picked): 1-2-3G ends below 0.8 on several (wrong axes), the default on fewer.

    (Before issue 22 the default started from stage 2's random samples and ended above 0.85 on all
    ten; with these samples only: trial 9, which the three views hardly tell apart, ends anywhere in
    0.52-0.89 over sampling seeds 0-7 with 1-2-3H.)"""
    ious = {"1-2-3G": [], sqfit.DEFAULT_CHAIN: []}
    for seed in range(10):
        t = paper_trial(seed)
        for chain in ious:
            result = sqfit.fit(t.observations, chain)
            assert result.ok, result.message
            ious[chain].append(iou_3d(result.superquadric, t.gt))
    new, old = np.array(ious[sqfit.DEFAULT_CHAIN]), np.array(ious["1-2-3G"])
    assert old.min() < 0.8
    assert (new < 0.8).sum() < (old < 0.8).sum() and np.median(new) > 0.97
    last = stage(sqfit.fit(paper_trial(0).observations), "3H")
    assert last.message.startswith("3H: start ")


def test_batch_log_gauge_jacobian_equals_one_at_a_time():
    rng = np.random.default_rng(3)
    X = np.c_[rng.uniform(0.2, 2.0, (6, 3)), rng.uniform(0.05, 1.95, (6, 2)), rng.normal(size=(6, 3)),
              rng.normal(size=(6, 3))]
    points = 2.0 * rng.normal(size=(6, 40, 3))
    log_g, d_xi = batch_log_gauge_jacobian(X, points)
    assert log_g.shape == (6, 40) and d_xi.shape == (6, 40, 11)
    for i, xi in enumerate(X):
        lg, J = log_gauge_jacobian(xi, points[i])
        np.testing.assert_allclose(log_g[i], lg, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(d_xi[i], J, rtol=1e-9, atol=1e-12)


def test_batch_residuals_keep_hinges_and_one_sided_rays(trial, start):
    """Band rays (INSIDE/OUTSIDE hinges) and one-sided rays are masked as in ray_residuals."""
    X = axis_candidates(start)
    band = contour_rays(trial.observations, 16, band_px=2.0, n_inside=10)
    one_sided = np.zeros(len(band), dtype=bool)
    one_sided[::3] = True
    rays = RaySet(band.origins, band.directions, band.modes, band.weights, band.view, two_sided=~one_sided)
    r, J, _ = batch_ray_residuals(X, rays)
    for i, xi in enumerate(X):
        ri, Ji, _ = ray_residuals(xi, rays)
        np.testing.assert_allclose(r[i], ri, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(J[i], Ji, rtol=1e-9, atol=1e-12)
    # The one-sided contour/outside rays never carry an "outside" (negative) residual.
    hinged = one_sided & (rays.modes != INSIDE)
    assert hinged.any() and np.all(r[:, :len(rays)][:, hinged] >= 0.0)


def test_rescue_refits_a_result_that_misses_the_masks(monkeypatch):
    # paper_trial(80): the screen and 3G end in 3G's "far, huge" minimum (R-IOU-M 0.28, IoU 0.03);
    # the rescue through 3D-3A and the screen recovers the object.
    from sqfit.fitting import axis_screen

    trial = paper_trial(80)
    monkeypatch.setattr(axis_screen, "RESCUE_R_IOU_M", 0.0)
    first = sqfit.fit(trial.observations, "1-2-3H")
    assert first.r_iou_m < 0.5 and iou_3d(first.superquadric, trial.gt) < 0.1
    assert any(w.startswith("poor fit") for w in first.warnings)
    monkeypatch.setattr(axis_screen, "RESCUE_R_IOU_M", 0.5)
    rescued = sqfit.fit(trial.observations, "1-2-3H")
    assert rescued.r_iou_m > 0.8 and iou_3d(rescued.superquadric, trial.gt) > 0.7
    # ~0.015: R-IOU-M against the outline hulls (sqfit.views.grid). The "far, huge" first fit needs
    # rotation corrections of several degrees, so 3G takes the cameras for noisy and refines every
    # candidate under the noise-scaled pose prior (tests/test_pose_noise.py); 0.264 under the fixed prior
    # (0.016 with 3G's shape bound at 0.03; 0.015 since the Jacobians follow minimisers on a
    # coordinate plane, sqfit.fitting.raycost.crossing_correction).
    assert re.match(r"rescue: R-IOU-M 0\.0[0-4]\d < 0\.5, re-fitted through 3D-3A-3H", rescued.stages[-1].message)
    assert "kept the rescue" in rescued.stages[-1].message
    assert not any(w.startswith("poor fit") for w in rescued.warnings)
    assert rescued.stages[-1].nfev > first.stages[-1].nfev


def test_rescue_keeps_the_first_fit_when_a_stage_fails(monkeypatch):
    from sqfit.fitting import axis_screen

    def broken(state, obs, options):
        raise np.linalg.LinAlgError("Singular matrix")

    trial = paper_trial(80)
    monkeypatch.setitem(sqfit.STAGES, "3A", broken)
    result = sqfit.fit(trial.observations, "1-2-3H")
    assert result.status == "ok"
    assert "rescue (3D-3A-3H) failed: Singular matrix" in result.stages[-1].message
    monkeypatch.setattr(axis_screen, "RESCUE_R_IOU_M", 0.0)
    assert result.superquadric == sqfit.fit(trial.observations, "1-2-3H").superquadric


def test_ray_minimiser_budget_is_honoured():
    # Box-like shape: the ray minima sit at near-kinks, where the solver bisects; one step cannot
    # converge there, the default budget does, and an ellipsoid is exact after one Newton step.
    trial = paper_trial(3)
    rays = contour_rays(trial.observations, 16)
    box = trial.gt.to_vector().copy()
    box[3:5] = 0.05
    from sqfit.fitting.line_gauge import batch_ray_minima

    d_full, m_full = batch_ray_minima(box[None], rays.origins, rays.directions)
    d_one, m_one = batch_ray_minima(box[None], rays.origins, rays.directions, max_newton=1)
    assert np.abs(d_one - d_full).max() > 1e-4
    assert np.all(m_one >= m_full - 1e-12)  # a minimiser stopped early never undercuts the minimum
    ell = trial.gt.to_vector().copy()
    ell[3:5] = 1.0
    d_full, _ = batch_ray_minima(ell[None], rays.origins, rays.directions)
    d_two, _ = batch_ray_minima(ell[None], rays.origins, rays.directions, max_newton=2)
    np.testing.assert_allclose(d_two, d_full, rtol=1e-8)


@pytest.mark.parametrize("kernels", ["numba", "numpy"])
def test_the_screen_penalises_shapes_below_its_own_bound(kernels, request):
    from sqfit.fitting import axis_screen
    from sqfit.kernels import backend

    previous = backend.set_kernels(kernels)
    request.addfinalizer(lambda: backend.set_kernels(previous))
    assert axis_screen.SCREEN_SHAPE_MIN > C.SILHOUETTE_SHAPE_BOUNDS[0]
    trial = paper_trial(1)
    rays = contour_rays(trial.observations)
    xi = trial.gt.to_vector()
    xi[3] = 0.02  # between 3G's bound (0.015) and the screen's (0.03)
    with np.errstate(all="ignore"):  # as the stages run it (numpy's ray minimiser overflows on the way)
        r3g, _, _ = batch_ray_residuals(xi[None], rays)
        rscreen, _, _ = batch_ray_residuals(xi[None], rays, bounds=axis_screen.SCREEN_BOUNDS)
    n = len(rays)
    assert np.isfinite(r3g).all() and np.isfinite(rscreen).all()
    np.testing.assert_array_equal(r3g[0, :n], rscreen[0, :n])  # the same rays
    assert r3g[0, n + 3] == 0.0 and rscreen[0, n + 3] > 0.0  # only the screen holds e1 = 0.02 back


def _slab_trial(seed, rotation_noise_deg=0.0):
    """A thin, box-like superquadric (0.15 x 0.8 x 1.2 m half-axes) in a random orientation, four
    views 4 m up on a 10 m circle; the observations' cameras turned by ``rotation_noise_deg`` about
    random axes (their masks from the true cameras)."""
    from sqfit.geometry.camera import Camera
    from sqfit.geometry.superquadric import Superquadric
    from sqfit.testing import paper_cameras, polygon_mask
    from sqfit.views.observation import Observation

    rng = np.random.default_rng(seed)
    gt = Superquadric([0.15, 0.8, 1.2], [0.1, 0.1], [0.0, 0.0, 0.0], rng.uniform(-np.pi, np.pi, 3))
    observations = []
    for cam in paper_cameras(4, height=4.0):
        mask = polygon_mask(gt, cam)
        pose = cam.pose
        if rotation_noise_deg:
            axis = rng.normal(size=3)
            pose = turned_pose(pose, np.radians(rotation_noise_deg) * axis / np.linalg.norm(axis))
        observations.append(Observation.from_mask(Camera(cam.intrinsics, pose), mask, 100, "uniform", rng))
    return gt, observations


def test_default_chain_keeps_thin_slabs_thin_on_clean_masks():
    # 3H's pose corrections and outline offset traded against the thin axis (before: up to 4 % too
    # thick, median 3D IoU 0.977 on these eight, the lowest 0.941); where they are idle the fit is
    # plain 3G from the refinement's result (sqfit.fitting.axis_screen, step 3)
    ious, thin = [], []
    for seed in range(8):
        gt, observations = _slab_trial(seed)
        result = sqfit.fit(observations, "default", rng=np.random.default_rng(0))
        assert "nuisances were idle" in stage(result, "3H").message and result.outline_offset_px is None
        ious.append(iou_3d(result.superquadric, gt))
        thin.append(np.sort(result.superquadric.to_vector()[:3])[0] / 0.15)
    assert np.median(ious) >= 0.982 and min(ious) >= 0.97
    assert np.median(thin) <= 1.02


def test_refinement_keeps_its_nuisances_where_the_cameras_disagree():
    gt, observations = _slab_trial(0, rotation_noise_deg=1.5)
    result = sqfit.fit(observations, "default", rng=np.random.default_rng(0))
    assert "nuisances were idle" not in stage(result, "3H").message


def test_refinement_keeps_its_nuisances_where_no_superquadric_grazes_the_outline():
    # a table (a top on four legs): 3H's cost stays far above 3T's trigger, the nuisances are idle
    # (no camera correction) but the plain re-fit is not taken: 3T/3TP's domain, whose results it
    # only moved (household tables, monitors, lamps; sqfit.fitting.axis_screen)
    from sqfit import Observation, Superquadric
    from sqfit.fitting.outline import TRIGGER_COST
    from sqfit.testing import paper_cameras, polygon_mask

    top = Superquadric([0.8, 0.5, 0.04], [0.1, 0.1], [0.0, 0.0, 0.75], [0.0, 0.0, 0.3])
    corners = [top.rotation_matrix @ [sx * 0.7, sy * 0.4, 0.0] for sx in (-1, 1) for sy in (-1, 1)]
    legs = [Superquadric([0.03, 0.03, 0.37], [0.1, 0.1], c + [0.0, 0.0, 0.37], [0.0, 0.0, 0.3]) for c in corners]
    rng = np.random.default_rng(0)
    observations = []
    for cam in paper_cameras(views=4, radius=8.0, height=4.0):
        mask = polygon_mask(top, cam)
        for leg in legs:
            mask |= polygon_mask(leg, cam)
        observations.append(Observation.from_mask(cam, mask, rng=rng))
    refined = stage(sqfit.fit(observations), "3H")
    assert refined.cost > TRIGGER_COST
    assert "nuisances were idle" not in refined.message


def test_an_offset_the_plain_fit_does_not_keep_is_idle(household, monkeypatch):
    """scenes/household.toml, books, seed 4, trial 5: 3H's refinement ends with an outline offset of -0.36 px
    (the pages' recess taken for an inward offset) and the book 1.1 times too thick; the plain fit costs
    1.14 times as much, and 3G from it with the offset free keeps the offset at 0.000 px. The offset was the
    refinement's basin's: plain 3G, 3D IoU 0.786 -> 0.924 when this was written."""
    from sqfit.fitting import axis_screen
    from sqfit.metrics import iou_3d_mesh

    book, obs = household("book", 4, 5)
    result = sqfit.fit(obs)
    refined = stage(result, "3H")
    assert "the refinement's outline offset was its basin's" in refined.message and result.outline_offset_px is None
    monkeypatch.setattr(axis_screen, "PLAIN_BASIN_COST_RATIO", 0.0)  # the idle test before
    kept = sqfit.fit(obs)
    assert "nuisances were idle" not in stage(kept, "3H").message
    assert np.abs(kept.outline_offset_px).max() > axis_screen.IDLE_OFFSET_PX
    assert iou_3d_mesh(result.superquadric, book.mesh) > iou_3d_mesh(kept.superquadric, book.mesh) + 0.05


@pytest.mark.parametrize("scene, index, patch", [
    # 1 px over-segmentation: offset +0.45 px, plain fit 1.10 times the cost, but from it the offset returns
    # to +0.58 px (IoU 0.814; taken plain 0.625)
    ("paper-bias1", 45, ("offset_from_plain", lambda rays, x, options: (np.zeros(1), 0))),
    # 1 px erosion: offset -0.31 px; from the plain fit the offset stays at -0.01 px, but that fit costs
    # 1.98 times the refinement (IoU 0.890; taken plain 0.485)
    ("paper-erode1", 96, ("PLAIN_BASIN_COST_RATIO", 3.0)),
])
def test_an_offset_the_masks_hold_is_kept(scene_trial, monkeypatch, scene, index, patch):
    from sqfit.fitting import axis_screen

    truth, obs = scene_trial(scene, index)
    result = sqfit.fit(obs)
    message = stage(result, "3H").message
    assert "nuisances were idle" not in message and "offset by" in message
    monkeypatch.setattr(axis_screen, *patch)
    plain = sqfit.fit(obs)
    assert "its basin's" in stage(plain, "3H").message
    assert iou_3d(result.superquadric, truth.superquadric) > iou_3d(plain.superquadric, truth.superquadric) + 0.1


def test_offset_from_plain_estimates_one_offset_per_group(trial):
    from dataclasses import replace
    from sqfit.fitting.costs import ObservationSet
    from sqfit.fitting.grazing import outline_rays
    from sqfit.fitting.pipeline import FitOptions
    from sqfit.fitting.axis_screen import IDLE_OFFSET_PX
    from sqfit.fitting.plain_run import offset_from_plain

    rays, options = outline_rays(ObservationSet(trial.observations), 64), FitOptions()
    truth = trial.gt.to_vector()
    offsets, nfev = offset_from_plain(rays, truth, options)
    # clean masks, started at the true superquadric: idle (0.105 px when this was written)
    assert offsets.shape == (1,) and abs(offsets[0]) < IDLE_OFFSET_PX / 2 and nfev > 0
    per_view, _ = offset_from_plain(rays, truth, replace(options, outline_offset="view"))
    assert per_view.shape == (len(trial.observations),) and np.abs(per_view).max() < IDLE_OFFSET_PX


def test_the_basin_test_is_not_run_on_offsets_beyond_its_reach(scene_trial, monkeypatch):
    """paper-bias1 trial 19: 3H's offset +0.95 px, beyond PLAIN_BASIN_OFFSET_MAX_PX: no plain run is paid for
    (from the plain fit the offset returns to +1.04 px; the fit is the same either way)."""
    from sqfit.fitting import axis_screen

    calls = []
    original = axis_screen.plain_fit

    def spy(rays, xi, options):
        calls.append(1)
        return original(rays, xi, options)

    monkeypatch.setattr(axis_screen, "plain_fit", spy)
    truth, obs = scene_trial("paper-bias1", 19)
    result = sqfit.fit(obs)
    assert np.abs(result.outline_offset_px).max() > axis_screen.PLAIN_BASIN_OFFSET_MAX_PX and not calls
    monkeypatch.setattr(axis_screen, "PLAIN_BASIN_OFFSET_MAX_PX", np.inf)
    tested = sqfit.fit(obs)
    assert calls and np.array_equal(tested.superquadric.to_vector(), result.superquadric.to_vector())


def test_an_inward_offset_at_the_size_floor_is_tested_from_the_plain_fits_own_floor(household):
    """scenes/household.toml, books, seed 14, trial 18: 3H's refinement holds the book at the size floor (0.1 m)
    with rounded edges and an inward offset (-0.42 px) that thins the outline of a superquadric the floor keeps
    too thick. The plain fit is a box below the floor (1.07 times the refinement's cost); freed from it at the
    floor it is held to, the offset returned (-0.91 px), at its own floor it stays at 0: the plain fit is taken
    (3D IoU 0.555 -> 0.932 when this was written)."""
    from sqfit.metrics import iou_3d_mesh
    from sqfit.fitting.plain_run import AT_FLOOR

    book, obs = household("book", 14, 18)
    result = sqfit.fit(obs)
    message = stage(result, "3H").message
    assert "its basin's" in message and "below the size floor" in message
    assert min(result.superquadric.size) < 0.1 * (1 - AT_FLOOR)  # below the floor
    assert iou_3d_mesh(result.superquadric, book.mesh) > 0.9


def test_pose_noise_at_the_size_floor_is_tested_against_the_plain_fit(household):
    """scenes/household.toml, books, seed 14, trial 9: re-screened on outlines offset inward, 3H's refinement
    holds the book at the size floor (0.1 m) with an offset of -1.5 px and rotation corrections that say the
    cameras disagree (0.29 deg RMS, above the 0.25 deg trigger); the plain fit (no corrections, no offset, a box
    below the floor) costs 0.46 times that refinement, whose cost counts its priors: the plain fit is taken, the
    given cameras kept (3D IoU 0.433 -> 0.954 when this was written)."""
    from sqfit.metrics import iou_3d_mesh
    from sqfit.fitting.costs import ObservationSet
    from sqfit.fitting.pipeline import FitOptions
    from sqfit.fitting.plain_run import AT_FLOOR

    book, obs = household("book", 14, 9)
    result = sqfit.fit(obs)
    message = stage(result, "3H").message
    assert "pose noise and outline offset were its basin's" in message
    assert min(result.superquadric.size) < 0.1 * (1 - AT_FLOOR)  # below the floor
    assert result.outline_offset_px is None
    assert iou_3d_mesh(result.superquadric, book.mesh) > 0.9
    # 3H's state hands on the given cameras, not the refinement's corrections (which 3R would re-fit under)
    state = through_3h(ObservationSet(list(obs)), FitOptions())
    assert "pose noise and outline offset were its basin's" in state.message and state.camera_corrections is None
    # without the offset (no 3G run from the plain fit with the offset freed) the test is the cost alone
    alone = sqfit.fit(obs, options={"outline_offset_sigma_px": 0})
    assert "the refinement's pose noise was its basin's" in stage(alone, "3H").message
    assert iou_3d_mesh(alone.superquadric, book.mesh) > 0.9


def test_at_size_floor_reads_the_floor_as_a_soft_bound():
    from sqfit.fitting.pipeline import FitOptions
    from sqfit.fitting.plain_run import AT_FLOOR, at_size_floor

    options = FitOptions()  # size_min_m 0.1
    assert at_size_floor([0.5, -0.1 * (1 + AT_FLOOR / 2), 0.3] + [1.0] * 8, options)  # signs ignored
    assert at_size_floor([0.5, 0.05, 0.3] + [1.0] * 8, options)  # below it
    assert not at_size_floor([0.5, 0.1 * (1 + 2 * AT_FLOOR), 0.3] + [1.0] * 8, options)
