"""The compiled kernels (sqfit.kernels.ray_kernels) against the numpy code they replace (sqfit.kernels.backend).

Problems with known answers: the same residuals, Jacobians, ray minima and fits from both paths.
Jacobians agree to 1e-12 where they are well conditioned; at points close to a coordinate plane of
a pointed superquadric (``e`` near 1.9) the terms ``|y_i| ** (2 / e - 1)`` amplify the rounding of
``y = R^T (x - p)`` (BLAS with FMA in numpy, plain products compiled), so there the agreement is
relative (``test_ray_residuals_agree_on_a_paper_trial``).
"""

import os
import subprocess
import sys

import numpy as np
import pytest

import sqfit
from sqfit.fitting import axis_screen, costs, line_gauge, raycost
from sqfit.kernels import backend
from sqfit.views.rays import contour_rays
from sqfit.testing import paper_trial
from _helpers import stage

pytest.importorskip("numba")

#: Shapes ``[ax, ay, az, e1, e2]`` of the equality tests: ellipsoid, box-like, pointed, mixed.
SHAPES = [(1.0, 0.5, 0.8, 1.0, 1.0), (0.6, 1.2, 0.4, 0.2, 0.3), (0.9, 0.7, 1.1, 1.6, 1.4),
          (2.0, 0.3, 0.5, 0.5, 1.2)]


@pytest.fixture
def kernels():
    """Run a callable under each implementation: ``kernels(f) -> (numba result, numpy result)``."""
    previous = backend.set_kernels(None)

    def both(f):
        out = []
        for name in ("numba", "numpy"):
            backend.set_kernels(name)
            assert backend.kernels_name() == name
            out.append(f())
        return out

    yield both
    backend.set_kernels(previous)


def _xi(shape, rng):
    return np.r_[shape, rng.uniform(-0.5, 0.5, 3), rng.uniform(-np.pi, np.pi, 3)]


def _close(a, b, tol):
    """``|a - b| <= tol * max(1, |b|)`` elementwise."""
    a, b = np.asarray(a), np.asarray(b)
    return np.all(np.abs(a - b) <= tol * np.maximum(1.0, np.abs(b)))


@pytest.mark.parametrize("shape", SHAPES)
def test_radial_terms_agree_at_generic_points(kernels, shape):
    rng = np.random.default_rng(1)
    xi = _xi(shape, rng)
    points = xi[5:8] + rng.normal(size=(200, 3))
    (g_k, dxi_k, dp_k), (g_n, dxi_n, dp_n) = kernels(lambda: costs.radial_terms(xi, points))
    assert _close(g_k, g_n, 1e-12) and _close(dxi_k, dxi_n, 1e-12) and _close(dp_k, dp_n, 1e-12)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("scaled", [True, False])
def test_g5_residuals_agree(kernels, shape, scaled):
    rng = np.random.default_rng(5)
    obs = costs.ObservationSet(paper_trial(1).observations)
    xi = _xi(shape, rng)
    xi[5:8] = paper_trial(1).gt.position  # the samples' rays pass near the centre
    xi[2] = -xi[2]  # a negative size: the volume factor keeps its sign
    depths = rng.uniform(5.0, 15.0, len(obs.rays))
    out_k, out_n = kernels(lambda: costs.g5_residuals(xi, depths, obs, 100.0, scaled=scaled))
    for a, b in zip(out_k, out_n):
        assert a.shape == b.shape and _close(a, b, 1e-12)
    assert np.any(out_n[0][-11:] != 0)  # a penalty row is active (the negative size)


@pytest.mark.parametrize("shape", SHAPES)
def test_log_gauge_jacobian_agrees_at_generic_points(kernels, shape):
    rng = np.random.default_rng(2)
    X = np.stack([_xi(shape, rng) for _ in range(3)])
    points = X[:, None, 5:8] + rng.normal(size=(3, 50, 3))
    (lg_k, d_k), (lg_n, d_n) = kernels(lambda: raycost.batch_log_gauge_jacobian(X, points))
    assert _close(lg_k, lg_n, 1e-12) and _close(d_k, d_n, 1e-12)


def _fine_minima(xi, origins, directions, far=20.0, points=4001):
    """``log g`` minimum of each ray over a fine grid of depths in ``(0, far]``."""
    grid = np.linspace(1e-3, far, points)
    pts = origins[:, None] + grid[None, :, None] * directions[:, None]
    return raycost.batch_log_gauge_jacobian(np.repeat(xi[None], len(grid), 0), pts.transpose(1, 0, 2))[0].T.min(axis=1)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("warm,start", [(False, "grid"), (True, "grid"), (False, "nearest")])
def test_ray_minima_agree(kernels, shape, warm, start):
    rng = np.random.default_rng(3)
    xi = _xi(shape, rng)
    origins = rng.normal(size=(100, 3)) * 0.5 + [0.0, 0.0, -8.0]
    directions = xi[5:8] + rng.normal(size=(100, 3)) * 0.8 - origins
    directions /= directions[:, 2:3]
    d0 = line_gauge.ray_minima(xi, origins, directions)[0] * 1.01 if warm else None
    (d_k, m_k), (d_n, m_n) = kernels(lambda: line_gauge.ray_minima(xi, origins, directions, d0, start))
    assert _close(d_k, d_n, 1e-12) and _close(m_k, m_n, 1e-12)
    if warm:  # warm rays stop after a few Newton steps (line_gauge's _MAX_NEWTON_WARM): not always converged
        return
    # and the answer is the minimum: no point of a fine grid along each ray is lower
    assert np.all(m_k <= _fine_minima(xi, origins, directions) + 1e-9)
    if start == "nearest":  # the one minimum along each line, whichever start
        d_g, m_g = line_gauge.ray_minima(xi, origins, directions)
        assert _close(m_k, m_g, 1e-9) and _close(d_k, d_g, 1e-6)


#: A slab 20:1:7, e = (0.05, 0.2) (a candidate of 3H's screen on ``paper_trial(3)``): Newton's first
#: step from the nearest point lands on a coordinate plane of the superquadric, where ``k_z = u_z /
#: q_z`` is huge; written as ``k_z + wA (K1 - k_z)`` the slope there lost every digit to cancellation
#: (0 or noise), the bracket was cut on its sign and 12 of the 48 rays stopped far above their minimum.
SLAB = [9.308153150586058, 0.4654076575293029, 3.306392722792937, 0.05, 0.2, -0.7566926242216431,
        0.3626094901621303, -3.7140414984906704, 2.9372248604591054, 1.2717452041459227, 0.3900517922112328]


@pytest.mark.parametrize("start", line_gauge.STARTS)
def test_ray_minima_of_a_slab_whose_newton_steps_hit_its_planes(kernels, start):
    xi = np.array(SLAB)
    rays = contour_rays(paper_trial(3).observations, 16)
    (d_k, m_k), (d_n, m_n) = kernels(lambda: line_gauge.ray_minima(xi, rays.origins, rays.directions, None, start))
    assert _close(m_k, m_n, 1e-12)
    fine = _fine_minima(xi, rays.origins, rays.directions, far=40.0, points=40001)
    assert np.all(m_k <= fine + 1e-6) and np.all(m_n <= fine + 1e-6)


def test_ray_minima_reject_an_unknown_start():
    with pytest.raises(ValueError, match="start must be one of"):
        line_gauge.ray_minima(_xi(SHAPES[0], np.random.default_rng(0)), np.zeros((1, 3)), np.ones((1, 3)), None, "middle")


def test_ray_residuals_agree_on_a_paper_trial(kernels):
    trial = paper_trial(3)
    rays = contour_rays(trial.observations, 16, band_px=1.5, n_inside=8)
    xi = trial.gt.to_vector()
    X = axis_screen.axis_candidates(xi * np.r_[1.2, 0.9, 1.1, 1, 1, np.ones(6)] + np.r_[np.zeros(5), 0.1, 0.1, -0.1,
                                                                                          0.05, 0, 0])
    xp = np.r_[X[0], 0.01, -0.02, 0.005, 0.0, 0.01, 0.0, 0.003, 0.0, 0.0]

    def evaluate():
        r, J, d = raycost.batch_ray_residuals(X, rays, rtol=1e-6, max_newton=10)
        warm = raycost.batch_ray_residuals(X * 1.001, rays, d0=d)
        return (r, J, d) + warm + raycost.posed_ray_residuals(xp, rays, 0.5) + raycost.ray_residuals(X[0], rays)

    fast, slow = kernels(evaluate)
    for k, (a, b) in enumerate(zip(fast, slow)):
        if k % 3 == 1:  # Jacobians: see the module docstring
            assert _close(a, b, 1e-7), k
        else:
            assert _close(a, b, 1e-12), k
    # the ellipsoid and flat candidates are well conditioned: there the Jacobians agree to 1e-12 too
    assert _close(fast[1][0], slow[1][0], 1e-12) and _close(fast[7], slow[7], 1e-12)


@pytest.mark.parametrize("pose", [True, False])
@pytest.mark.parametrize("per_view", [False, True])
def test_offset_residuals_agree(kernels, pose, per_view):
    # the outline offsets of 3G (posed_ray_residuals): per object or per view, with and without the
    # rotation unknowns, on rays that include one-sided and interior (offset-free) rays
    trial = paper_trial(3)
    rays = contour_rays(trial.observations, 16, band_px=1.5, n_inside=8, smooth_px=2.0)
    groups = rays.view if per_view else None
    xi = trial.gt.to_vector() * np.r_[1.2, 0.9, 1.1, 1, 1, np.ones(6)] + np.r_[np.zeros(5), 0.1, 0.1, -0.1, 0.05, 0, 0]
    rng = np.random.default_rng(4)
    x = np.r_[xi, rng.normal(size=9) * 0.01 if pose else [], rng.normal(size=3 if per_view else 1)]
    sigma = 0.5 if pose else 0.0

    # per view: a correlated prior (sqfit.fitting.grazing.offset_prior), as the views' offsets share the object's
    prior = np.linalg.inv(np.linalg.cholesky(np.ones((3, 3)) + 0.25 * np.eye(3))) if per_view else None

    def evaluate():
        r, J, d = raycost.posed_ray_residuals(x, rays, sigma, offset_sigma_px=1.5, offset_groups=groups,
                                              offset_prior=prior)
        return (r, J, d) + raycost.posed_ray_residuals(x * 1.001, rays, sigma, d0=d, offset_sigma_px=1.5,
                                                       offset_groups=groups, offset_prior=prior)

    fast, slow = kernels(evaluate)
    for k, (a, b) in enumerate(zip(fast, slow)):
        assert a.shape == b.shape and _close(a, b, 1e-12), k
    assert np.abs(slow[1][:len(rays), -1]).max() > 1e-3  # an offset column that is not zero


def test_screen_agrees(kernels):
    trial = paper_trial(0)
    rays = contour_rays(trial.observations, axis_screen.N_SCREEN_CONTOUR)
    X = axis_screen.axis_candidates(trial.gt.to_vector() * np.r_[1.3, 0.8, 1.1, 0.8, 1.2, np.ones(6)])
    (X_k, c_k), (X_n, c_n) = kernels(lambda: axis_screen.batch_levenberg_marquardt(X, rays, 12))
    # A start that has converged goes on taking steps of ~1e-9 driven by round-off, accepted or not by
    # the cost's last bits, which the two implementations sum in different orders: the points agree to
    # ~1e-8 (here 2e-9 with numba 0.68 / numpy 2.4, up to 7e-9 on paper trials 0-5; 1e-14 until the
    # start converges), the costs to 1e-11.
    assert np.abs(X_k - X_n).max() < 1e-7 and _close(c_k, c_n, 1e-9)
    assert np.all(c_k < axis_screen.batch_levenberg_marquardt(X, rays, 0)[1])  # it descended


def test_fits_agree_on_a_biased_mask(kernels):
    # 1 px over-segmentation: the default chain estimates the outline offset and screens again on
    # rays offset by it (sqfit.fitting.axis_screen.RESCREEN_PX)
    from sqsim.imaging.mask_models import bias_boundary

    trial = paper_trial(0)
    rng = np.random.default_rng(0)
    obs = [sqfit.Observation.from_mask(c, bias_boundary(m, 1.0), 100, "uniform", rng)
           for c, m in zip(trial.cameras, trial.masks)]
    a, b = kernels(lambda: sqfit.fit(obs))
    assert "re-screened" in stage(a, "3H").message
    assert np.abs(a.superquadric.to_vector() - b.superquadric.to_vector()).max() < 1e-9


@pytest.mark.parametrize("chain, seeds", [("1-2-3D", range(5)), ("1-2-3H", (0, 3, 4))])
def test_fits_agree(kernels, chain, seeds):
    # seeds whose last LM run does not stop on a knife edge (README "Fitter speed": on others a
    # rounding difference moves the stopping step; the fits are then distribution-equal)
    for seed in seeds:
        obs = paper_trial(seed).observations
        a, b = kernels(lambda: sqfit.fit(obs, chain).superquadric.to_vector())
        assert np.abs(a - b).max() < 1e-9, seed


def test_set_kernels_rejects_unknown_names():
    with pytest.raises(ValueError, match="kernels must be one of"):
        backend.set_kernels("fortran")


def test_environment_variable_is_checked():
    code = "import sqfit.kernels.backend as b; b.compiled()"
    env = dict(os.environ, SQFIT_KERNELS="fortran")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode != 0 and "SQFIT_KERNELS must be one of" in out.stderr


def test_environment_variable_selects_numpy():
    code = "import sqfit.kernels.backend as b, sys; print(b.kernels_name(), 'numba' in sys.modules)"
    env = dict(os.environ, SQFIT_KERNELS="numpy")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["numpy", "False"]


def test_compiled_path_is_the_default_when_numba_is_installed():
    # CI installs numba (a core dependency): the suite must run the compiled path unless told not to
    if os.environ.get(backend.ENV_VAR, "auto") in ("auto", "numba"):
        code = "import sqfit.kernels.backend as b; print(b.kernels_name())"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        assert out.stdout.strip() == "numba"


# ------------------------------------------------------------------------------------------------
# R-IOU-M: silhouettes, convex IoU and hulls (sqfit.kernels.silhouette_kernels)


def _perturbed_starts(seed, count=4):
    trial = paper_trial(seed)
    rng = np.random.default_rng(seed)
    X = np.stack([trial.gt.to_vector() * np.r_[rng.uniform(0.7, 1.3, 5), np.ones(6)]
                  + np.r_[np.zeros(5), rng.normal(0.0, 0.3, 6)] for _ in range(count)])
    return trial, X


def _truncated_starts(seed, count=4):
    """A truncated trial (two views cut by the image border) and ``count`` superquadrics near its truth."""
    from sqfit.testing import truncated_trial

    trial = truncated_trial(seed, cut_fraction=0.3, cut_views=2)
    rng = np.random.default_rng(seed)
    X = np.stack([trial.gt.to_vector() * np.r_[rng.uniform(0.8, 1.2, 5), np.ones(6)]
                  + np.r_[np.zeros(5), rng.normal(0.0, 0.1, 6)] for _ in range(count)])
    return trial, X


@pytest.mark.parametrize("seed", range(6))
def test_silhouettes_agree(kernels, seed):
    from sqfit.geometry.silhouette import batch_silhouettes

    trial, X = _perturbed_starts(seed)
    obs = costs.ObservationSet(trial.observations)
    (P_k, V_k), (P_n, V_n) = kernels(lambda: costs.silhouettes(X, obs))
    assert np.array_equal(V_k, V_n) and V_n.any()
    # each vertex stops at its own step below NEWTON_TOL (1e-7 px), the numpy batch when all do
    assert np.abs(P_k - P_n)[V_n].max() < 1e-5
    assert np.array_equal(P_n, batch_silhouettes(X, obs.rotations, obs.centers, obs.intrinsics)[0])


@pytest.mark.parametrize("seed", range(3))
def test_touching_silhouettes_and_their_vertices_velocities_agree(seed):
    # stage 3U's gradient: the silhouettes with their touching points, and the vertices' velocities from
    # them, compiled and numpy; with a negative half-axis and exponents at and outside their range
    from sqfit.geometry.silhouette import (E_RANGE, MAX_NEWTON, NEWTON_TOL, ZNEAR, batch_silhouettes,
                                           rotation_stack, vertex_velocities)

    k, moving = _silhouette_kernels(), backend.compiled("velocities")
    trial, X = _perturbed_starts(seed, 5)
    X[1, 0] *= -1.0
    X[2, 3:5] = [E_RANGE[0], 2.5]
    X[3, 3:5] = [0.004, E_RANGE[1]]
    obs = costs.ObservationSet(trial.observations)
    cams = (obs.rotations, obs.centers, obs.intrinsics)
    R, dR = rotation_stack(X)
    P_k, V_k, unit_k, points_k = k.touching_silhouettes(X, R, *cams, 48, NEWTON_TOL, MAX_NEWTON, ZNEAR, *E_RANGE)
    P_n, V_n, _, unit_n, points_n = batch_silhouettes(X, *cams, 48, touching=True)
    assert np.array_equal(V_k, V_n) and V_n.all()
    assert np.abs(P_k - P_n).max() < 1e-5 and np.array_equal(P_k, k.silhouettes(X, R, *cams, 48, NEWTON_TOL,
                                                                                 MAX_NEWTON, ZNEAR, *E_RANGE)[0])
    assert np.abs(unit_k - unit_n).max() < 1e-6 and np.abs(points_k - points_n).max() < 1e-6
    fast = moving.vertex_velocities(X, R, dR, unit_n, points_n, obs.rotations, obs.intrinsics, *E_RANGE)
    slow = vertex_velocities(X, unit_n, points_n, obs.rotations, obs.intrinsics)
    assert np.allclose(fast, slow, rtol=1e-10, atol=1e-9 * np.abs(slow).max())
    assert np.all(fast[2, ..., 4] == 0.0) and np.all(fast[3, ..., 3] == 0.0) and np.abs(fast[3, ..., 4]).max() > 0


def test_silhouettes_behind_the_camera_are_invalid(kernels):
    trial, X = _perturbed_starts(0, 2)
    obs = costs.ObservationSet(trial.observations)
    X[1, 5:8] = obs.centers[0]  # the camera centre inside the superquadric: view 0 has no silhouette
    (_, V_k), (_, V_n) = kernels(lambda: costs.silhouettes(X, obs))
    assert np.array_equal(V_k, V_n) and not V_k[1, 0] and V_k[0].all()


@pytest.mark.parametrize("seed", range(6))
def test_r_iou_m_agrees(kernels, seed):
    trial, X = _perturbed_starts(seed)

    def score():
        obs = costs.ObservationSet(trial.observations)  # fresh: targets (hulls) from each path
        return costs.visible_iou(*costs.silhouettes(X, obs), obs)

    iou_k, iou_n = kernels(score)
    assert np.abs(iou_k - iou_n).max() < 1e-9 and iou_n.max() > 0.3


@pytest.mark.parametrize("seed", range(4))
def test_r_iou_m_of_partly_seen_views_agrees(kernels, seed):
    # views cut by the image border (the silhouette clipped to the image) and a view with occluding
    # pixels (left out of intersection and union): the compiled clipping and numpy's
    from dataclasses import replace

    trial, X = _truncated_starts(seed)
    view = trial.observations[2]
    grid = np.stack(np.meshgrid(np.arange(-20.0, 21.0, 2.0), np.arange(-20.0, 21.0, 2.0)), -1).reshape(-1, 2)
    hidden = grid + np.floor(view.samples.mean(axis=0)) + 0.5  # pixel centres about the mask
    observations = list(trial.observations[:2]) + [replace(view, hidden=hidden)]

    def score():
        obs = costs.ObservationSet(observations)
        assert obs.border_views[:2].all() and obs.occluded_views[2] and not obs.border_views[2]
        return costs.visible_iou(*costs.silhouettes(X, obs), obs)

    iou_k, iou_n = kernels(score)
    assert np.abs(iou_k - iou_n).max() < 1e-9 and iou_n.min() > 0.1


def _silhouette_kernels():
    """The compiled R-IOU-M kernels, or skip the test (numba not selected)."""
    from sqfit.kernels.backend import compiled

    k = compiled("silhouettes")
    if k is None:
        pytest.skip("numba kernels not selected")
    return k


def test_convex_iou_kernel_on_known_overlaps():
    from sqfit.geometry.polygon import MIN_EDGE, half_planes

    k = _silhouette_kernels()
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    target = np.vstack([square, square[-1:]])[None].repeat(3, 0)  # padded by repeating a vertex

    def iou(polys):
        return k.convex_iou(np.ascontiguousarray(polys[None]), np.ones((1, 3), dtype=bool), target,
                            *half_planes(target), MIN_EDGE)[0]

    # half overlapping (2 / 6), identical (shared edges counted once), disjoint
    assert np.allclose(iou(np.stack([square + [1.0, 0.0], square, square + [5.0, 5.0]])), [1.0 / 3.0, 1.0, 0.0],
                       atol=1e-12)
    # a duplicate vertex (zero-length edge), a sliver inside, a square around the target
    inner = np.array([[0.5, 0.5], [1.5, 0.5], [1.5, 0.5], [0.5, 1.5], [0.5, 1.5]])
    around = np.array([[-1.0, -1.0], [3.0, -1.0], [3.0, 3.0], [-1.0, 3.0], [-1.0, 3.0]])
    assert np.allclose(iou(np.stack([np.vstack([square, square[:1]]), inner, around])), [1.0, 0.125, 0.25],
                       atol=1e-12)


def test_clipped_iou_kernel_on_known_overlaps():
    # clipped to a 4 x 4 image or not, with hidden pixels, and an invalid silhouette
    from sqfit.geometry.polygon import MIN_EDGE, half_planes
    from sqfit.geometry.visible_iou import image_rectangles

    k = _silhouette_kernels()
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    half = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [0.0, 2.0]])  # inside the image, area 2
    targets = np.stack([half, half, square, square])
    frames = image_rectangles(np.full((4, 2), 4.0))
    nr, cross_r, _ = half_planes(frames)
    S = np.stack([square - [1.0, 0.0], square - [1.0, 0.0], square, square])[None]  # the first two half outside

    def iou(clip, hidden_inter, hidden_union, valid=(True, True, True, False)):
        return k.clipped_iou(np.ascontiguousarray(S), np.array([valid]), targets, *half_planes(targets), frames, nr,
                             cross_r, np.array(clip), np.array([hidden_inter], dtype=float),
                             np.array([hidden_union], dtype=float), MIN_EDGE)[0]

    # clipped: S n R is the target (1); not clipped: 2 / 4; hidden 1 px in both: 3 / 3; in the
    # intersection only: 3 / 4; not valid: 0
    assert np.allclose(iou([True, False, False, False], [0, 0, 1, 0], [0, 0, 1, 0]), [1.0, 0.5, 1.0, 0.0], atol=1e-12)
    assert np.allclose(iou([True, False, False, False], [0, 0, 1, 0], [0, 0, 0, 0]), [1.0, 0.5, 0.75, 0.0], atol=1e-12)


def test_convex_hull_kernel():
    from scipy.spatial import ConvexHull

    k = _silhouette_kernels()
    rng = np.random.default_rng(4)
    for n in (3, 10, 100, 1000):
        points = rng.normal(size=(n, 2)) * [30.0, 5.0]
        points[: n // 3] = np.round(points[: n // 3])  # ties in x and y
        index = k.convex_hull(np.ascontiguousarray(points))
        reference = ConvexHull(points).vertices
        assert sorted(index) == sorted(reference)
        hull = points[index]
        edges = np.roll(hull, -1, axis=0) - hull
        assert np.all(edges[:, 0] * np.roll(edges[:, 1], -1) - edges[:, 1] * np.roll(edges[:, 0], -1) > 0)  # CCW
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.0], [0.5, 0.5], [0.0, 0.0]])
    assert sorted(k.convex_hull(square)) == [0, 1, 2, 3]  # collinear and repeated points dropped
    assert len(k.convex_hull(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]))) == 0  # collinear: no hull


def test_hidden_counts_kernel_agrees():
    # the occluding pixels inside each silhouette: the same counts as the numpy edge tests, also for
    # points on a silhouette's edges and vertices, outside its bounding box, and a non-finite vertex
    from sqfit.geometry.visible_iou import hidden_counts

    k = _silhouette_kernels()
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    S = np.stack([np.stack([100.0 + 50.0 * s * np.cos(t), 80.0 + 30.0 * s * np.sin(t)], -1)
                  for s in rng.uniform(0.3, 1.5, 6)])
    square = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]])
    S = np.concatenate([S, np.repeat(np.vstack([square, square[-1:].repeat(44, 0)])[None], 1, 0)])
    S[2, 7] = np.nan
    points = np.vstack([rng.uniform(0.0, 200.0, (2000, 2)), S[0, :10], [[2.0, 0.0], [4.0, 2.0], [4.0, 4.0],
                                                                         [4.0 + 1e-12, 2.0], [-1e-300, 1.0]]])
    in_q = rng.random(len(points)) < 0.4
    inter, union = k.hidden_counts(S, points, in_q)
    ref_inter, ref_union = hidden_counts(S, points, in_q)
    assert np.array_equal(inter, ref_inter) and np.array_equal(union, ref_union)
    assert inter[2] == 0 and union[2] == in_q.sum() and inter[0] > 0 and inter[-1] > 0


def test_points_in_convex_kernel_agrees():
    # the occluding pixels inside an observation polygon: the numpy edge tests' answers bit for bit,
    # for points on edges and vertices, just outside, a padded polygon (repeated last vertex, as
    # ObservationSet.targets pads) and a NaN vertex or point
    from sqfit.geometry.visible_iou import points_in_convex

    k = _silhouette_kernels()
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 2.0 * np.pi, 37, endpoint=False)
    hull = np.stack([120.0 + 55.0 * np.cos(t), 70.0 + 33.0 * np.sin(t)], -1)
    padded = np.vstack([hull, hull[-1:].repeat(9, 0)])
    points = np.vstack([rng.uniform(0.0, 240.0, (3000, 2)) // 1 + 0.5, hull, 0.5 * (hull + np.roll(hull, -1, 0)),
                        hull * (1 + 1e-15), [[np.nan, 70.0]]])
    for polygon in (hull, padded):
        got = k.points_in_convex(np.ascontiguousarray(polygon), np.ascontiguousarray(points))
        assert got.dtype == bool and np.array_equal(got, points_in_convex(polygon, points))
        assert 0 < got.sum() < len(points) and not got[-1]
    broken = hull.copy()
    broken[3] = np.nan
    assert not k.points_in_convex(broken, np.ascontiguousarray(points)).any()
    assert not points_in_convex(broken, points).any()


def test_contour_overlaps_kernel_on_known_overlaps():
    # silhouettes against a non-convex (L-shaped) contour: exact areas, clipped to the image or not,
    # either orientation, a zero-length edge; a silhouette that is not convex or not finite is left
    # to shapely (ok False)
    k = _silhouette_kernels()
    ell = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 1.0], [1.0, 1.0], [1.0, 4.0], [0.0, 4.0]])  # area 7
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    frame = np.array([[[0.0, 0.0], [1.5, 0.0], [1.5, 10.0], [0.0, 10.0]]])
    polys = [square, square[::-1], np.vstack([square[:2], square[1:]]), square + [-1.0, -1.0],
             np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.5], [2.0, 2.0]]),
             np.array([[0.0, 0.0], [2.0, 0.0], [np.nan, 2.0], [0.0, 2.0]])]
    # five vertices each: a repeated last vertex (a zero-length edge) where there are four
    polys = np.ascontiguousarray(np.stack([np.vstack([p, p[-1:]]) if len(p) == 4 else p for p in polys])[:, None])
    pairs = np.stack([np.arange(len(polys)), np.zeros(len(polys), dtype=np.int64)], axis=1)
    starts = np.array([0, len(ell)])
    for clip, inter, area in ((False, [3.0, 3.0, 3.0, 1.0], [4.0, 4.0, 4.0, 4.0]),
                              (True, [2.5, 2.5, 2.5, 1.0], [3.0, 3.0, 3.0, 1.0])):
        got_inter, got_area, ok = k.contour_overlaps(polys, pairs, ell, starts, frame, np.array([clip]), 1e-9)
        assert ok.tolist() == [True, True, True, True, False, False]
        assert np.allclose(got_inter[:4], inter, atol=1e-12) and np.allclose(got_area[:4], area, atol=1e-12)
        assert not got_inter[4:].any() and not got_area[4:].any()


def test_contour_overlaps_kernel_agrees_with_shapely():
    import shapely

    k = _silhouette_kernels()
    rng = np.random.default_rng(8)
    worst = 0.0
    for _ in range(200):
        # a star-shaped, non-convex contour and a superellipse silhouette over part of it
        angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, rng.integers(8, 200)))
        contour = 100.0 + rng.uniform(20.0, 60.0, len(angles))[:, None] * np.stack([np.cos(angles), np.sin(angles)], 1)
        t = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
        e = rng.uniform(0.2, 1.9)
        x, y = np.sign(np.cos(t)) * np.abs(np.cos(t)) ** e, np.sign(np.sin(t)) * np.abs(np.sin(t)) ** e
        sil = rng.uniform(60.0, 140.0, 2) + rng.uniform(10.0, 80.0) * np.stack([x, rng.uniform(0.3, 1.0) * y], 1)
        if rng.random() < 0.5:
            sil = sil[::-1]
        frame = np.array([[0.0, 0.0], [120.0, 0.0], [120.0, 200.0], [0.0, 200.0]])
        clip = bool(rng.random() < 0.5)
        inter, area, ok = k.contour_overlaps(np.ascontiguousarray(sil[None, None]), np.zeros((1, 2), dtype=np.int64),
                                             np.ascontiguousarray(contour), np.array([0, len(contour)]), frame[None],
                                             np.array([clip]), 1e-9)
        shape = shapely.Polygon(sil)
        if clip:
            shape = shapely.intersection(shape, shapely.Polygon(frame))
        reference = shapely.area(shapely.intersection(shape, shapely.Polygon(contour)))
        assert ok[0]
        worst = max(worst, abs(inter[0] - reference), abs(area[0] - shapely.area(shape)))
    assert worst < 1e-8


@pytest.mark.parametrize("seed", range(4))
def test_contour_r_iou_agrees(kernels, seed):
    # stage 3T's R-IOU against the mask contours: the compiled overlaps and shapely's, whole views
    # and views cut by the image border
    trial, X = _truncated_starts(seed)

    def score():
        obs = costs.ObservationSet(trial.observations)
        assert obs.border_views.sum() == 2
        return costs.visible_iou(*costs.silhouettes(X, obs), obs, "contour")

    iou_k, iou_n = kernels(score)
    assert np.abs(iou_k - iou_n).max() < 1e-9 and iou_n.max() > 0.3


def test_compiled_parts_load_lazily():
    code = ("import sys, sqfit.kernels.backend as b; b.compiled(); print('silhouette_kernels' in str(sys.modules)); "
            "b.compiled('silhouettes'); print('sqfit.kernels.silhouette_kernels' in sys.modules)")
    env = dict(os.environ, SQFIT_KERNELS="numba")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True"]
    with pytest.raises(ValueError, match="part must be one of"):
        backend.compiled("fortran")
