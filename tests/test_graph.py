"""The factor graph (sqfit.graph): factors' Jacobians, conventions, a small sequence, bad input."""

import dataclasses
import json

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit import graph  # noqa: E402
from sqfit.graph import factors, landmark, quadric  # noqa: E402
from sqfit.graph.testing import object_ious, position_rmse, synthetic_sequence  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402
from sqfit.testing import polygon_mask  # noqa: E402
from _numeric import central_difference  # noqa: E402
from _helpers import graph_values  # noqa: E402

from gtsam.symbol_shorthand import L, Q, S, X  # noqa: E402

K_INTR = sqfit.Intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
SQ = sqfit.Superquadric((0.5, 0.3, 0.4), (0.6, 1.3), (0.2, -0.1, 0.4), (0.3, -0.2, 0.5))
T_CAM = sqfit.look_at([4.0, 1.5, 1.5], [0.0, 0.0, 0.4])


def _retract(T, delta):
    return gtsam.Pose3(T).retract(delta).matrix()


def _rays(sq=SQ, T=T_CAM, n=24):
    cam = sqfit.Camera(K_INTR, T)
    obs = sqfit.Observation.from_mask(cam, polygon_mask(sq, cam), rng=0)
    return landmark.camera_rays(obs, n)


def _perturbed_landmark():
    T, s = landmark.superquadric_to_landmark(SQ)
    return _retract(T, np.array([0.05, -0.03, 0.02, 0.04, 0.02, -0.03])), s * np.array([1.1, 0.9, 1.05, 1.1, 0.95])


# --- conventions ----------------------------------------------------------------------------------

def test_camera_rays_are_pixel_bearings_whatever_the_observation_pose():
    cam = sqfit.Camera(K_INTR, T_CAM)
    mask = polygon_mask(SQ, cam)
    moved = sqfit.Camera(K_INTR, sqfit.look_at([-3.0, 2.0, 1.0], [1.0, 0.0, 0.0]))
    a = landmark.camera_rays(sqfit.Observation.from_mask(cam, mask, rng=0), 16)
    b = landmark.camera_rays(sqfit.Observation.from_mask(moved, mask, rng=0), 16)
    np.testing.assert_allclose(a.directions, b.directions, atol=1e-12)
    np.testing.assert_allclose(a.directions[:, 2], 1.0)  # unit depth
    np.testing.assert_array_equal(a.origins, 0.0)
    # made without a second validation: the same as a checked RaySet of the same arrays
    checked = dataclasses.replace(a)
    for name in ("origins", "directions", "offsets", "modes", "weights", "two_sided", "radii", "_hinge_in", "_hinge_out"):
        np.testing.assert_array_equal(getattr(a, name), getattr(checked, name))


def test_moving_rays_keeps_every_per_ray_array():
    # e.g. the partial-visibility work's per-ray flags: the factor must hand them to raycost unchanged
    rays = _rays()
    object.__setattr__(rays, "two_sided", np.arange(len(rays)) % 2 == 0)
    moved = landmark._moved(rays, np.ones((len(rays), 3)), 2 * rays.directions)
    np.testing.assert_array_equal(moved.two_sided, rays.two_sided)
    np.testing.assert_array_equal(moved.modes, rays.modes)
    np.testing.assert_array_equal(moved.origins, 1.0)
    np.testing.assert_array_equal(rays.origins, 0.0)  # the camera-frame rays are untouched


def test_silhouette_residual_is_small_at_the_truth_and_grows_away_from_it():
    rays = _rays()
    T, s = landmark.superquadric_to_landmark(SQ)
    r_true = landmark.silhouette_residuals(T_CAM, T, s, rays)[0]
    r_off = landmark.silhouette_residuals(T_CAM, T, s * 1.2, rays)[0]
    assert np.sqrt(np.mean(r_true ** 2 * len(r_true))) < 0.02  # pixelisation only
    assert np.all(r_off * np.sqrt(len(r_off)) < 0)  # too large: every ray passes through
    assert np.linalg.norm(r_off) > 5 * np.linalg.norm(r_true)


def test_landmark_round_trip_and_pose_is_superquadric_to_world():
    T, s = landmark.superquadric_to_landmark(SQ)
    np.testing.assert_allclose(T[:3, 3], SQ.position)
    np.testing.assert_allclose(landmark.landmark_to_superquadric(T, s).to_vector(), SQ.to_vector(), atol=1e-12)


# --- Jacobians vs central differences -------------------------------------------------------------

def test_silhouette_jacobians_match_central_differences():
    rays = _rays()
    Tl, s = _perturbed_landmark()
    r, Jc, Jl, Js, d = landmark.silhouette_residuals(T_CAM, Tl, s, rays)
    assert np.abs(Jc).max() > 0.1 and np.abs(Jl).max() > 0.1
    f_cam = lambda x: landmark.silhouette_residuals(_retract(T_CAM, x), Tl, s, rays)[0]  # noqa: E731
    f_lm = lambda x: landmark.silhouette_residuals(T_CAM, _retract(Tl, x), s, rays)[0]  # noqa: E731
    f_s = lambda x: landmark.silhouette_residuals(T_CAM, Tl, x, rays)[0]  # noqa: E731
    np.testing.assert_allclose(Jc, central_difference(f_cam, np.zeros(6)), atol=1e-6)
    np.testing.assert_allclose(Jl, central_difference(f_lm, np.zeros(6)), atol=1e-6)
    np.testing.assert_allclose(Js, central_difference(f_s, s), atol=1e-6)


@pytest.mark.parametrize("batch", [False, True])
def test_silhouette_jacobians_of_a_diamond_section_match_central_differences(batch):
    """A landmark whose section is diamond-like (``e2 = 1.8``): its outline rays have their minimisers
    on its coordinate planes, where the pose Jacobians carry the minimiser's motion with the plane
    (:func:`sqfit.fitting.raycost.crossing_correction`; without it they were off by up to ~40 %, and
    Levenberg-Marquardt and iSAM2 stopped in the graph's flat directions). Central differences of
    such cusps carry ~1e-4, hence the tolerance."""
    sq = sqfit.Superquadric((0.5, 0.3, 0.4), (1.0, 1.8), (0.2, -0.1, 0.4), (0.3, -0.2, 0.5))
    rays = _rays(sq, n=32)
    T, s = landmark.superquadric_to_landmark(sq)
    Tl = _retract(T, np.array([0.01, -0.01, 0.005, 0.004, 0.002, -0.003]))

    def evaluate(Tc, Tl_, s_):
        if not batch:
            return landmark.silhouette_residuals(Tc, Tl_, s_, rays)
        return [a[0] for a in landmark.batch_silhouette_residuals(Tc[None], Tl_[None], s_[None],
                                                                  landmark.stack_rays([rays]))]

    r, Jc, Jl, Js, d = evaluate(T_CAM, Tl, s)
    f_cam = lambda x: evaluate(_retract(T_CAM, x), Tl, s)[0]  # noqa: E731
    f_lm = lambda x: evaluate(T_CAM, _retract(Tl, x), s)[0]  # noqa: E731
    scale = max(np.abs(Jc).max(), np.abs(Jl).max())
    np.testing.assert_allclose(Jc, central_difference(f_cam, np.zeros(6), h=1e-7), atol=1e-3 * scale)
    np.testing.assert_allclose(Jl, central_difference(f_lm, np.zeros(6), h=1e-7), atol=1e-3 * scale)


def test_silhouette_shape_outside_the_domain_is_clipped_with_zero_columns():
    rays = _rays()
    T, s = landmark.superquadric_to_landmark(SQ)
    bad = s.copy()
    bad[3] = -0.2
    r, _, _, Js, _ = landmark.silhouette_residuals(T_CAM, T, bad, rays)
    assert np.all(np.isfinite(r))
    np.testing.assert_array_equal(Js[:, 3], 0.0)
    pen, Jp = landmark.bounds_residuals(bad, 100.0)
    assert pen[3] == pytest.approx(100.0 * (0.1 + 0.2)) and Jp[3, 3] == -100.0
    assert np.all(landmark.bounds_residuals(s, 100.0)[0] == 0)


# --- the graph's factors evaluated together -------------------------------------------------------

def _factor_cases(n=5, seed=0):
    """``n`` (camera, landmark, shape, rays) cases around the test view: one shape outside the domain
    (clipped), one-sided rays in one, two ray sets."""
    rng = np.random.default_rng(seed)
    Tl, s = _perturbed_landmark()
    rays = [_rays(), _rays(T=sqfit.look_at([-3.0, 2.5, 1.0], [0.0, 0.0, 0.4]))]
    one_sided = _rays()
    object.__setattr__(one_sided, "two_sided", np.arange(len(one_sided)) % 3 != 0)
    object.__setattr__(one_sided, "_hinge_in", np.flatnonzero(~one_sided.two_sided))
    cases = []
    for i in range(n):
        shape = s * rng.uniform(0.9, 1.1, 5)
        if i == 2:
            shape[3] = 2.4  # clipped to EVAL_UPPER
        ray_set = one_sided if i == 3 else rays[i % 2]
        T_cam = T_CAM if ray_set is not rays[1] else sqfit.look_at([-3.0, 2.5, 1.0], [0.0, 0.0, 0.4])
        cases.append((_retract(T_cam, rng.normal(0, 0.02, 6)), _retract(Tl, rng.normal(0, 0.02, 6)), shape, ray_set))
    return cases


def test_batched_silhouette_residuals_equal_one_factor_at_a_time():
    cases = _factor_cases()
    Tc, Tl, shapes, rays = (list(c) for c in zip(*cases))
    stacked = landmark.stack_rays(rays)
    out = landmark.batch_silhouette_residuals(np.array(Tc), np.array(Tl), np.array(shapes), stacked)
    for i, case in enumerate(cases):
        ref = landmark.silhouette_residuals(*case)
        assert np.abs(ref[0]).max() > 1e-3
        for got, want in zip(out, ref):
            np.testing.assert_allclose(got[i], want, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(want).max()))
    # warm start (NaN: none) gives the same minimisers and residuals
    d0 = out[4].copy()
    d0[1] = np.nan
    warm = landmark.batch_silhouette_residuals(np.array(Tc), np.array(Tl), np.array(shapes), stacked, d0)
    for got, want in zip(warm, out):
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("start", ["nearest", "grid"])
def test_batched_silhouette_residuals_compiled_and_numpy_agree(start):
    pytest.importorskip("numba")
    from sqfit.kernels import backend

    cases = _factor_cases(8, seed=3)
    Tc, Tl, shapes = (np.array(c) for c in list(zip(*cases))[:3])
    rays = landmark.stack_rays([c[3] for c in cases])
    shapes[5, 0] = 0.001  # a size below the evaluated domain (clipped, zero Jacobian column)
    previous = backend.set_kernels(None)
    try:
        out = {}
        for name in ("numba", "numpy"):
            backend.set_kernels(name)
            out[name] = landmark.batch_silhouette_residuals(Tc, Tl, shapes, rays, start=start)
    finally:
        backend.set_kernels(previous)
    assert np.abs(out["numpy"][0]).max() > 1e-3 and np.any(out["numpy"][0] == 0)  # active and hinged rays
    for got, want in zip(out["numba"], out["numpy"]):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(want).max()))
    assert np.all(out["numba"][3][5, :, 0] == 0)


@pytest.mark.parametrize("kernels", ["numba", "numpy"])
def test_batched_silhouette_residuals_read_their_rows_of_a_larger_stack(kernels):
    # a graph's factors keep their rays stacked once; an evaluation names its factors' rows there
    if kernels == "numba":
        pytest.importorskip("numba")
    from sqfit.kernels import backend

    cases = _factor_cases(8, seed=5)
    Tc, Tl, shapes = (np.array(c) for c in list(zip(*cases))[:3])
    pool = landmark.stack_rays([c[3] for c in cases])
    rows = np.array([6, 1, 3])
    previous = backend.set_kernels(kernels)
    try:
        got = landmark.batch_silhouette_residuals(Tc[rows], Tl[rows], shapes[rows], pool, rows=rows)
        want = landmark.batch_silhouette_residuals(Tc[rows], Tl[rows], shapes[rows],
                                                   landmark.stack_rays([cases[i][3] for i in rows]))
        with pytest.raises(ValueError, match=r"rows must be 3 indices into the 8 factors of rays, got \[6, 1, 8\]"):
            landmark.batch_silhouette_residuals(Tc[rows], Tl[rows], shapes[rows], pool, rows=[6, 1, 8])
        with pytest.raises(ValueError, match="rows must be 3 indices into the 8 factors"):
            landmark.batch_silhouette_residuals(Tc[rows], Tl[rows], shapes[rows], pool)
    finally:
        backend.set_kernels(previous)
    assert np.abs(want[0]).max() > 1e-3
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_stack_rays_checks_its_input():
    with pytest.raises(ValueError, match="ray_sets must not be empty"):
        landmark.stack_rays([])
    with pytest.raises(ValueError, match=r"same number of rays, got lengths \[16, 24\]"):
        landmark.stack_rays([_rays(), _rays(n=16)])


def _cases_graph(cases, batch):
    values, fs = gtsam.Values(), []
    for i, (Tc, Tl, shape, rays) in enumerate(cases):
        values.insert(X(i), gtsam.Pose3(Tc))
        values.insert(L(i), gtsam.Pose3(Tl))
        values.insert(S(i), shape)
        fs.append(factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), X(i), L(i), S(i), rays, batch))
    return values, fs


def _rows(f, values):
    lin = f.linearize(values)
    return f.unwhitenedError(values), lin.jacobian()[0]


def test_shared_evaluation_serves_every_factor_and_recomputes_only_what_changed():
    cases = _factor_cases()
    batch = factors.SilhouetteFactors()
    values, shared = _cases_graph(cases, batch)
    _, alone = _cases_graph(cases, None)  # each factor with an evaluator of its own
    for f, g in zip(shared, alone):
        for a, b in zip(_rows(f, values), _rows(g, values)):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)
    assert (batch.evaluations, batch.factor_evaluations) == (1, len(cases))  # one call evaluated all
    # move one camera: only its factor is re-evaluated, and every factor still gives fresh rows
    moved = gtsam.Values(values)
    moved.update(X(1), gtsam.Pose3(_retract(cases[1][0], np.full(6, 0.01))))
    for f, g in zip(shared, alone):
        for a, b in zip(_rows(f, moved), _rows(g, moved)):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)
    assert (batch.evaluations, batch.factor_evaluations) == (2, len(cases) + 1)
    np.testing.assert_allclose(shared[1].unwhitenedError(moved), landmark.silhouette_residuals(
        moved.atPose3(X(1)).matrix(), cases[1][1], cases[1][2], cases[1][3])[0], rtol=1e-6, atol=1e-9)
    # back at the first values: re-evaluated, not served from a stale cache
    np.testing.assert_allclose(shared[1].unwhitenedError(values), alone[1].unwhitenedError(values), atol=1e-9)
    # values holding only some factors' variables: the others are left out
    part = gtsam.Values()
    for key in (X(0), L(0), S(0)):
        part.insert(key, values.atPose3(key) if key != S(0) else values.atVector(key))
    np.testing.assert_allclose(shared[0].unwhitenedError(part), alone[0].unwhitenedError(part), atol=1e-9)


def test_a_non_finite_residual_names_the_factor():
    Tc, Tl, shape, rays = _factor_cases(1)[0]
    values, (f,) = _cases_graph([(Tc, Tl, shape, rays)], None)
    values.update(S(0), np.array([np.nan, 0.3, 0.3, 1.0, 1.0]))
    with pytest.raises(FloatingPointError, match=r"silhouette factor \(x0, l0\): non-finite residual"):
        f.unwhitenedError(values)


def _linearized(factor, values, keys, dims):
    """Jacobian blocks of a unit-noise factor as GTSAM linearises it, and central differences of its
    error under GTSAM's own retraction."""
    A = factor.linearize(values).jacobian()[0]
    offsets = np.cumsum([0] + dims)
    blocks = [A[:, offsets[i]:offsets[i + 1]] for i in range(len(keys))]

    def numeric(i):
        def f(x):
            delta = gtsam.VectorValues()
            for j, key in enumerate(keys):
                delta.insert(key, x if j == i else np.zeros(dims[j]))
            return factor.unwhitenedError(values.retract(delta))
        return central_difference(f, np.zeros(dims[i]))

    return blocks, [numeric(i) for i in range(len(keys))]


@pytest.mark.parametrize("kind", ["silhouette", "box"])
def test_gtsam_factor_linearization_matches_central_differences(kind):
    Tl, s = _perturbed_landmark()
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(T_CAM))
    values.insert(L(1), gtsam.Pose3(Tl))
    if kind == "silhouette":
        rays = _rays()
        values.insert(S(1), s)
        keys = [X(0), L(1), S(1)]
        f = factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), *keys, rays)
    else:
        values.insert(Q(1), s[:3])
        keys = [X(0), L(1), Q(1)]
        f = factors.box_factor(gtsam.noiseModel.Unit.Create(4), *keys, K_INTR.K, [200.0, 150.0, 300.0, 260.0])
    blocks, numeric = _linearized(f, values, keys, [6, 6, 5 if kind == "silhouette" else 3])
    for b, n in zip(blocks, numeric):
        scale = max(1.0, np.abs(n).max())
        np.testing.assert_allclose(b, n, atol=1e-5 * scale)


def test_box_jacobians_match_central_differences():
    Tq, r = landmark.superquadric_to_landmark(SQ)[0], np.array(SQ.size)
    box = np.array([250.0, 200.0, 330.0, 290.0])
    res, Jc, Jq, Jr = quadric.box_residuals(T_CAM, Tq, r, K_INTR.K, box)
    f_cam = lambda x: quadric.box_residuals(_retract(T_CAM, x), Tq, r, K_INTR.K, box)[0]  # noqa: E731
    f_q = lambda x: quadric.box_residuals(T_CAM, _retract(Tq, x), r, K_INTR.K, box)[0]  # noqa: E731
    f_r = lambda x: quadric.box_residuals(T_CAM, Tq, x, K_INTR.K, box)[0]  # noqa: E731
    for J, n in ((Jc, central_difference(f_cam, np.zeros(6))), (Jq, central_difference(f_q, np.zeros(6))),
                 (Jr, central_difference(f_r, r))):
        np.testing.assert_allclose(J, n, atol=1e-5 * np.abs(n).max())


def test_projected_ellipsoid_box_matches_its_silhouette_mask():
    ellipsoid = sqfit.Superquadric(SQ.size, (1.0, 1.0), SQ.position, SQ.rotation)
    cam = sqfit.Camera(K_INTR, T_CAM)
    obs = sqfit.Observation.from_mask(cam, polygon_mask(ellipsoid, cam), rng=0)
    pred = quadric.conic_box(quadric.projected_conic(T_CAM, ellipsoid.pose, ellipsoid.size, K_INTR.K))
    np.testing.assert_allclose(pred, quadric.observation_box(obs), atol=1.0)  # pixel edges


def test_quadric_initialisation_recovers_an_ellipsoid_from_exact_boxes():
    ellipsoid = sqfit.Superquadric(SQ.size, (1.0, 1.0), SQ.position, SQ.rotation)
    poses = [sqfit.look_at([4 * np.cos(t), 4 * np.sin(t), 1.5], [0, 0, 0.4]) for t in np.linspace(0, 1.6, 6)]
    boxes = [quadric.conic_box(quadric.projected_conic(T, ellipsoid.pose, ellipsoid.size, K_INTR.K)) for T in poses]
    Z, radii = quadric.initialise_quadric(poses, K_INTR.K, boxes)
    np.testing.assert_allclose(Z[:3, 3], ellipsoid.position, atol=1e-6)
    Q_est = quadric.dual_quadric(Z, radii)
    np.testing.assert_allclose(Q_est, quadric.dual_quadric(ellipsoid.pose, ellipsoid.size), atol=1e-6)
    assert quadric.initialise_quadric(poses[:2], K_INTR.K, boxes[:2]) == (None, None)


# --- a small sequence -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small():
    seq = synthetic_sequence(1, n_frames=16, n_objects=3)
    return seq, graph.run(seq.intrinsics, seq.odometry_poses, seq.observations)


def test_joint_optimisation_beats_odometry_and_fixed_pose_fits(small):
    seq, res = small
    ate = {m: position_rmse(r.poses, seq.true_poses) for m, r in res.items()}
    iou = {m: np.median(list(object_ious(r.objects, seq.objects).values())) for m, r in res.items() if m != "odometry"}
    assert ate["graph"] < 0.5 * ate["odometry"], ate
    assert ate["graph-isam2"] < 0.5 * ate["odometry"], ate
    assert iou["graph"] > iou["fixed"] + 0.05, iou
    assert iou["graph-isam2"] > iou["fixed"], iou
    assert res["graph"].error_final < res["graph"].error_initial
    np.testing.assert_array_equal(res["fixed"].poses, seq.odometry_poses)
    np.testing.assert_array_equal(res["odometry"].poses, seq.odometry_poses)


def test_results_are_complete_and_serialisable(small):
    seq, res = small
    assert list(res) == list(graph.METHODS)
    for m, r in res.items():
        assert r.ok and r.poses.shape == (len(seq.true_poses), 4, 4) and r.method == m
        assert set(r.objects) == (set() if m == "odometry" else set(seq.objects))
        json.dumps(r.to_dict())
    assert all(o.shape == (1.0, 1.0) for o in res["quadric"].objects.values())
    isam = res["graph-isam2"]
    assert isam.frame_seconds.shape == (len(seq.true_poses),) and np.all(isam.frame_cpu_seconds >= 0)


def test_an_estimate_off_the_odometry_is_flagged(small):
    seq, res = small
    limit = graph.GraphOptions().batch_odometry_chi2
    for m in ("graph", "graph-isam2"):
        # about 6 (the degrees of freedom of a step) where the odometry noise model holds
        assert 1.0 < res[m].odometry_chi2 < limit, (m, res[m].odometry_chi2)
        assert not [w for w in res[m].warnings if "disagrees with the odometry" in w]
        assert res[m].to_dict()["odometry_chi2"] == res[m].odometry_chi2
    assert all(res[m].odometry_chi2 is None for m in ("odometry", "fixed", "quadric"))
    # the same odometry under a noise model ten times tighter than its own noise
    for incremental in (False, True):
        tight = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations,
                                         {"odometry_sigma_m": 0.0005, "odometry_sigma_deg": 0.05}, incremental)
        assert tight.ok and tight.odometry_chi2 > limit
        flags = [w for w in tight.warnings if "disagrees with the odometry" in w]
        assert len(flags) == 1 and f"{tight.odometry_chi2:.1f} per step, above {limit}" in flags[0]


def test_robust_loss_limits_a_wrong_mask(small):
    seq, _ = small
    obs = dict(seq.observations)
    key = sorted(k for k in obs if k[1] == 2)[5]
    big = sqfit.Superquadric(np.array(seq.objects[2].size) * 2.5, (1.0, 1.0), seq.objects[2].position)
    cam = sqfit.Camera(seq.intrinsics, seq.true_poses[key[0]])
    obs[key] = sqfit.Observation.from_mask(cam, polygon_mask(big, cam), rng=0)
    ious = {}
    for k in (1.345, 1e6):  # Huber vs (practically) plain least squares
        res = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, obs, {"huber_k": k})
        ious[k] = object_ious(res.objects, seq.objects)[2]
    assert ious[1.345] > ious[1e6]


# --- bad input ------------------------------------------------------------------------------------

def _tiny():
    seq = synthetic_sequence(2, n_frames=4, n_objects=2)
    return seq.intrinsics, seq.odometry_poses.copy(), dict(seq.observations)


def test_a_frame_without_a_pose_is_an_error():
    intr, poses, obs = _tiny()
    poses[2] = np.nan
    with pytest.raises(ValueError, match="frame 2 has no pose"):
        graph.superquadric_graph(intr, poses, obs)
    intr, poses, obs = _tiny()
    obs[7, 1] = obs[0, 1]
    with pytest.raises(ValueError, match=r"frame 7 has no pose \(odometry_poses has 4 frames\)"):
        graph.run(intr, poses, obs)


def test_an_object_seen_once_is_skipped_with_a_warning():
    intr, poses, obs = _tiny()
    obs[1, 9] = obs[1, 1]
    for method in graph.METHODS:
        res = graph.METHODS[method](intr, poses, obs)
        assert 9 in res.skipped and "seen in 1 frame only (frame 1)" in res.skipped[9]
        assert any("object 9: skipped" in w for w in res.warnings)
        assert 9 not in res.objects


@pytest.mark.parametrize("mutate, error, match", [
    (lambda a: a.update(poses=a["poses"][:, :3]), ValueError, r"odometry_poses must have shape \(n, 4, 4\)"),
    (lambda a: a.update(poses=a["poses"][:0]), ValueError, "at least one frame"),
    (lambda a: a["poses"].__setitem__((1, 0, 0), 2.0), ValueError, r"odometry_poses\[1\] is not a rigid transform"),
    (lambda a: a.update(intr="K"), TypeError, "intrinsics must be a sqfit.Intrinsics"),
    (lambda a: a.update(obs=list(a["obs"].values())), TypeError, "observations must be a dict"),
    (lambda a: a["obs"].__setitem__((0, "a"), a["obs"][0, 1]), TypeError, r"key \(0, 'a'\) must be a tuple"),
    (lambda a: a["obs"].__setitem__((0, 5), "mask"), TypeError, r"observation \(0, 5\): must be a sqfit.Observation"),
    (lambda a: a.update(intr=sqfit.Intrinsics(640, 480, 400.0, 400.0, 320.0, 240.0)), ValueError,
     "intrinsics differ"),
])
def test_bad_input_is_named(mutate, error, match):
    intr, poses, obs = _tiny()
    args = {"intr": intr, "poses": poses, "obs": obs}
    mutate(args)
    with pytest.raises(error, match=match):
        graph.check_inputs(args["intr"], args["poses"], args["obs"])


def test_a_mask_touching_the_border_is_used_with_a_warning():
    intr, poses, obs = _tiny()
    cam = sqfit.Camera(intr, poses[0])
    mask = np.zeros((intr.height, intr.width), bool)
    mask[0:40, 100:160] = True
    obs[0, 1] = sqfit.Observation.from_mask(cam, mask, rng=0)
    problem = graph.check_inputs(intr, poses, obs)
    assert "frame 0, object 1: mask touches the image border" in problem.warnings[0]


def test_bad_options_and_methods_are_named():
    intr, poses, obs = _tiny()
    with pytest.raises(ValueError, match=r"unknown graph option\(s\) \['sigma'\]"):
        graph.superquadric_graph(intr, poses, obs, {"sigma": 1.0})
    with pytest.raises(ValueError, match="init_frames must be an integer >= 2"):
        graph.GraphOptions(init_frames=1)
    with pytest.raises(ValueError, match="silhouette_sigma must be a finite number > 0"):
        graph.GraphOptions(silhouette_sigma=0.0)
    with pytest.raises(ValueError, match="batch_past_views must be an integer >= 0"):
        graph.GraphOptions(batch_past_views=-1)
    with pytest.raises(ValueError, match="batch_pose_noise_refit must be True or False"):
        graph.GraphOptions(batch_pose_noise_refit="no")
    with pytest.raises(TypeError, match="options must be None, a dict or a GraphOptions"):
        graph.GraphOptions.coerce(3)
    with pytest.raises(ValueError, match=r"unknown method\(s\) \['slam'\]"):
        graph.run(intr, poses, obs, methods=["slam"])
    with pytest.raises(TypeError, match="must be a sqfit.Observation"):
        landmark.camera_rays("mask", 8)


def test_an_optimiser_error_is_flagged_in_the_result(monkeypatch):
    from sqfit.graph import solve

    def fail(graph, values, options, max_lambda=None):
        raise RuntimeError("\nIndeterminate linear system detected while working near variable l1")

    monkeypatch.setattr(solve, "_lm", fail)
    intr, poses, obs = _tiny()
    for method in ("graph", "quadric"):
        res = graph.METHODS[method](intr, poses, obs)
        assert not res.ok and res.status == "failed" and res.objects == {}
        assert res.message == "Levenberg-Marquardt: RuntimeError: Indeterminate linear system detected while " \
                              "working near variable l1"
        np.testing.assert_array_equal(res.poses, poses)


def _object_2_in_a_poor_minimum(seq):
    """The problem of ``seq`` at its true poses, and values with every landmark at the truth but
    object 2's, in a poor minimum (axes swapped, flat, shifted)."""
    from sqfit.graph import problem as gproblem

    prob = gproblem.check_inputs(seq.intrinsics, seq.true_poses, seq.observations)
    sq = seq.objects[2]
    poor = sqfit.Superquadric(np.array(sq.size)[[2, 0, 1]], (1.8, 0.2), np.array(sq.position) + 0.15, sq.rotation)
    return prob, graph_values(seq.true_poses, {**seq.objects, 2: poor})


def test_a_landmark_left_in_a_poor_minimum_is_refitted(small):
    from sqfit.graph import problem as gproblem, refit

    seq, _ = small
    options = graph.GraphOptions()
    prob, values = _object_2_in_a_poor_minimum(seq)
    misfit = refit.object_misfits(prob, values, list(seq.objects), options)
    # evaluated together, as alone
    for oid in seq.objects:
        assert refit.object_misfits(prob, values, [oid], options)[oid] == pytest.approx(misfit[oid], rel=1e-9)
    cache = {}  # the batch solve hands the re-fit the graph's rays: the same misfit from them
    assert refit.object_misfits(prob, values, [2], options, cache)[2] == pytest.approx(misfit[2], rel=1e-9)
    assert sorted(cache) == [(f, 2) for f in prob.frames[2]]
    assert refit.object_misfits(prob, values, [2], options, cache)[2] == pytest.approx(misfit[2], rel=1e-9)
    # at most `most` views, evenly spread: those views' misfit
    frames = prob.frames[2]
    assert refit.object_misfits(prob, values, [2], options, most=len(frames))[2] == pytest.approx(misfit[2], rel=1e-9)
    two = gproblem.check_inputs(seq.intrinsics, seq.true_poses, {(f, 2): seq.observations[f, 2] for f in (frames[0], frames[-1])})
    assert refit.object_misfits(prob, values, [2], options, most=2)[2] == pytest.approx(
        refit.object_misfits(two, values, [2], options)[2], rel=1e-9)
    assert misfit[2] > options.refit_misfit > max(misfit[1], misfit[3]), misfit
    result = graph.SlamResult("graph", seq.true_poses)
    # with the overlap test only (iSAM2's restart) this minimum stays: it overlaps its masks; so it
    # does above misfit_cap (the batch's last check: misfit_sigma, above which the outline is taken
    # for the model's, not a poor minimum's)
    assert not refit.refit_landmarks(prob, values, list(seq.objects), options, result, overlap_only=True)
    assert not refit.refit_landmarks(prob, values, list(seq.objects), options, result, misfit_cap=0.99 * misfit[2])
    # nor below a misfit threshold of its own (the batch's iSAM2 rebuilds: batch_rebuild_refit_misfit),
    # nor with re-fits off, whatever the threshold
    assert not refit.refit_landmarks(prob, values, list(seq.objects), options, result, misfit_threshold=1.01 * misfit[2])
    assert not refit.refit_landmarks(prob, values, list(seq.objects), graph.GraphOptions(refit_misfit=0), result,
                                     misfit_threshold=0.5 * misfit[2])
    assert not result.warnings
    assert refit.refit_landmarks(prob, values, list(seq.objects), options, result, misfit_cap=1.01 * misfit[2],
                                 misfit_threshold=0.99 * misfit[2])
    assert [w.split(":")[0] for w in result.warnings] == ["object 2"]
    refitted = landmark.landmark_to_superquadric(values.atPose3(L(2)).matrix(), values.atVector(S(2)))
    assert refit.object_misfits(prob, values, [2], options)[2] < options.refit_misfit
    assert iou_3d(refitted, seq.objects[2]) > 0.8
    assert not refit.refit_landmarks(prob, values, list(seq.objects), graph.GraphOptions(refit_misfit=0), result)


def test_a_refit_that_leaves_the_masks_is_not_kept(small, monkeypatch):
    # A re-fit with a lower misfit whose silhouettes barely overlap the masks (R-IOU-M below
    # POOR_FIT_R_IOU_M: 3G's far, huge minimum, whose misfit is low) is no gain: the landmark stays.
    from sqfit import constants as C
    from sqfit.graph import refit
    from sqfit.graph.shapevar import PLAIN

    seq, _ = small
    options = graph.GraphOptions()
    prob, values = _object_2_in_a_poor_minimum(seq)
    before = refit.object_misfits(prob, values, [2], options, most=options.refit_max_frames)[2]
    assert before > options.refit_misfit
    real, tried = refit.landmark_overlap, []

    def overlap(v, oid, obs, variable=PLAIN):
        if v is values:
            return real(v, oid, obs, variable)
        tried.append(oid)
        return C.POOR_FIT_R_IOU_M - 0.01  # the re-fit's silhouettes leave the masks

    monkeypatch.setattr(refit, "landmark_overlap", overlap)
    result, rejected = graph.SlamResult("graph", seq.true_poses), {}
    assert not refit.refit_landmarks(prob, values, list(seq.objects), options, result, rejected=rejected)
    assert tried == [2] and result.warnings == []
    assert refit.object_misfits(prob, values, [2], options, most=options.refit_max_frames)[2] == before  # it stayed
    assert rejected[2] == (before, len(prob.frames[2]))  # and is not re-fitted in vain at the next call
    monkeypatch.setattr(refit, "landmark_overlap", real)
    assert refit.refit_landmarks(prob, values, list(seq.objects), options, graph.SlamResult("graph", seq.true_poses))


def test_the_batch_fits_skip_the_fitters_pose_noise_branch(monkeypatch):
    # the batch's landmark fits (initial and re-fit) run without the fitter's answer to pose noise
    # (GraphOptions.batch_pose_noise_refit, default False); iSAM2's and the fixed baseline's keep it
    from sqfit.fitting import pipeline

    seq, seen = synthetic_sequence(0, n_frames=6, n_objects=1), []
    real = pipeline.fit

    def fit(observations, chain=None, **kw):
        seen.append(sqfit.FitOptions.coerce(kw.get("options")).pose_noise_refit)
        return real(observations, chain, **kw)

    monkeypatch.setattr(pipeline, "fit", fit)
    for methods, options, expected in ((["graph"], None, False), (["graph"], {"batch_pose_noise_refit": True}, True),
                                       (["graph-isam2", "fixed"], None, True)):
        seen.clear()
        graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, methods, options)
        assert seen and set(seen) == {expected}, (methods, options)


def test_observations_from_instance_images_match_the_masks():
    seq = synthetic_sequence(2, n_frames=3, n_objects=2)
    images = np.zeros((3, seq.intrinsics.height, seq.intrinsics.width), np.uint16)
    for f, T in enumerate(seq.true_poses):
        cam = sqfit.Camera(seq.intrinsics, T)
        for oid, sq in seq.objects.items():  # drawn in id order: the later one is on top where they overlap
            images[f][polygon_mask(sq, cam)] = oid
    images[1, :3, :3] = 7  # a 9-pixel speck: below min_area_px
    obs = graph.observations_from_instances(seq.intrinsics, seq.odometry_poses, images, min_area_px=50, rng=0)
    assert set(obs) == {(f, oid) for f in range(3) for oid in seq.objects if (images[f] == oid).sum() >= 50}
    o = obs[0, 1]
    assert o.area_px == (images[0] == 1).sum() and np.allclose(o.camera.pose, seq.odometry_poses[0])
    with pytest.raises(ValueError, match=r"instance_images\[1\] must be an integer \(height, width\)"):
        graph.observations_from_instances(seq.intrinsics, seq.odometry_poses, [images[0], images[1][:, :10], images[2]])
    with pytest.raises(ValueError, match="instance_images has 2 frames, poses 3"):
        graph.observations_from_instances(seq.intrinsics, seq.odometry_poses, images[:2])
    with pytest.raises(ValueError, match="min_area_px must be an integer >= 1"):
        graph.observations_from_instances(seq.intrinsics, seq.odometry_poses, images, min_area_px=0)
    with pytest.raises(ValueError, match=r"instance_images\[0\] must be an integer"):
        graph.observations_from_instances(seq.intrinsics, seq.odometry_poses, images.astype(float))
    with pytest.raises(TypeError, match="intrinsics must be a sqfit.Intrinsics"):
        graph.observations_from_instances(None, seq.odometry_poses, images)


def test_observations_from_instances_are_labelled():
    from sqfit.views.visibility import BACKGROUND, BORDER, INSTANCE

    k = sqfit.Intrinsics(160, 120, 100.0, 100.0, 80.0, 60.0)
    images = np.zeros((2, 120, 160), np.uint16)
    images[:, 40:80, 30:70] = 1
    images[:, 50:70, 60:90] = 2  # in front of object 1's right side
    images[:, 10:40, 140:] = 3  # cut by the right image border
    obs = graph.observations_from_instances(k, np.stack([np.eye(4)] * 2), images, min_area_px=50, rng=0)
    assert set(obs) == {(f, j) for f in range(2) for j in (1, 2, 3)}
    assert INSTANCE in obs[0, 1].contour_labels and BORDER not in obs[0, 1].contour_labels
    assert BORDER in obs[1, 3].contour_labels and obs[1, 3].touches_border and obs[1, 3].partial
    # no depth order in an instance image: any neighbouring instance may hide (object 2 is labelled too)
    assert BACKGROUND in obs[0, 2].contour_labels and BORDER not in obs[0, 2].contour_labels
    problem = graph.check_inputs(k, np.stack([np.eye(4)] * 2), obs)
    assert any("object 3: mask touches the image border" in w and "one-sided" in w for w in problem.warnings)


def test_a_landmark_whose_silhouettes_miss_the_masks_is_refitted(small):
    # 3G's "far, huge" minimum has a low ray misfit: the overlap with the masks (R-IOU-M) catches it.
    # With the misfit test switched off (refit_misfit huge), only the overlap can call the re-fit.
    from sqfit.graph import problem as gproblem, refit

    seq, _ = small
    options = graph.GraphOptions(refit_misfit=1e9)
    prob = gproblem.check_inputs(seq.intrinsics, seq.true_poses, seq.observations)
    sq = seq.objects[2]  # moved 20 m up: its silhouettes leave the masks
    far = sqfit.Superquadric(sq.size, sq.shape, np.array(sq.position) + (0.0, 0.0, 20.0), sq.rotation)
    values = graph_values(seq.true_poses, {**seq.objects, 2: far})
    overlap = {oid: refit.landmark_overlap(values, oid, refit.observation_set(prob, oid, seq.true_poses, prob.frames[oid]))
               for oid in seq.objects}
    assert overlap[2] < sqfit.constants.POOR_FIT_R_IOU_M < min(overlap[1], overlap[3]), overlap
    result = graph.SlamResult("graph", seq.true_poses)
    assert refit.refit_landmarks(prob, values, list(seq.objects), options, result, overlap_only=True)
    assert [w.split(":")[0] for w in result.warnings] == ["object 2"] and "R-IOU-M" in result.warnings[0]
    refitted = landmark.landmark_to_superquadric(values.atPose3(L(2)).matrix(), values.atVector(S(2)))
    assert refit.landmark_overlap(values, 2, refit.observation_set(prob, 2, seq.true_poses, prob.frames[2])) > 0.7
    assert iou_3d(refitted, seq.objects[2]) > 0.8


# --- the outline offset (issue "Masks as real segmenters make them") ------------------------------

@pytest.mark.parametrize("delta", [0.7, -0.6])
def test_outline_offset_jacobians_match_central_differences(delta):
    cases = _factor_cases(n=4, seed=1)
    Tc, Tl, shapes, rays = (np.array(c) if i < 3 else list(c) for i, c in enumerate(zip(*cases)))
    stacked = landmark.stack_rays(rays)
    offset = np.full(len(cases), delta)
    r, Jc, Jl, Js, d, Jo = landmark.batch_silhouette_residuals(Tc, Tl, shapes, stacked, None, offset)
    assert np.abs(Jo).max() > 1e-3
    for i in range(len(cases)):
        def f_o(x, i=i):
            o = offset.copy()
            o[i] = x[0]
            return landmark.batch_silhouette_residuals(Tc, Tl, shapes, stacked, None, o)[0][i]

        def f_lm(x, i=i):
            T = Tl.copy()
            T[i] = _retract(Tl[i], x)
            return landmark.batch_silhouette_residuals(Tc, T, shapes, stacked, None, offset)[0][i]

        scale = max(1.0, np.abs(Jo[i]).max())
        np.testing.assert_allclose(Jo[i], central_difference(f_o, np.array([delta]))[:, 0], atol=1e-6 * scale)
        np.testing.assert_allclose(Jl[i], central_difference(f_lm, np.zeros(6)), atol=1e-6)
    # no offset and a zero offset are the same residual
    plain = landmark.batch_silhouette_residuals(Tc, Tl, shapes, stacked)
    zero = landmark.batch_silhouette_residuals(Tc, Tl, shapes, stacked, None, np.zeros(len(cases)))
    for a, b in zip(plain, zero):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_outline_offset_moves_the_silhouette_as_a_grown_mask_does():
    # masks grown by 2 px: the true landmark with an offset of +1.5 px misfits them far less than without
    from scipy import ndimage

    T, s = landmark.superquadric_to_landmark(SQ)
    cam = sqfit.Camera(K_INTR, T_CAM)
    mask = polygon_mask(SQ, cam)
    grown = landmark.camera_rays(sqfit.Observation.from_mask(cam, ndimage.binary_dilation(mask, iterations=2), rng=0), 32)
    stacked = landmark.stack_rays([grown])
    args = (T_CAM[None], T[None], s[None], stacked, None)
    rms = [float(np.linalg.norm(landmark.batch_silhouette_residuals(*args, np.array([o]))[0])) for o in (0.0, 1.5)]
    assert rms[1] < 0.5 * rms[0], rms


@pytest.mark.parametrize("grow", [1, -1])
def test_graph_estimates_the_outline_offset_of_biased_masks(grow):
    from scipy import ndimage

    seq = synthetic_sequence(1, n_frames=20, n_objects=3, arc_deg=180.0)
    biased = {}
    for (i, oid), obs in seq.observations.items():  # the same views, every mask grown or shrunk by a pixel
        mask = polygon_mask(seq.objects[oid], sqfit.Camera(seq.intrinsics, seq.true_poses[i]))
        mask = ndimage.binary_dilation(mask) if grow > 0 else ndimage.binary_erosion(mask)
        biased[i, oid] = sqfit.Observation.from_mask(obs.camera, mask, rng=0)
    on = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, biased,
                                  graph.GraphOptions(outline_offset_sigma_px=0.5))
    off = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, biased)
    assert on.ok and off.ok and off.outline_offsets == {}
    assert set(on.outline_offsets) == set(on.objects)
    assert all(0.2 < grow * v < 1.5 for v in on.outline_offsets.values()), on.outline_offsets
    iou_on = np.median(list(object_ious(on.objects, seq.objects).values()))
    iou_off = np.median(list(object_ious(off.objects, seq.objects).values()))
    assert iou_on > iou_off + 0.01, (iou_on, iou_off)
    assert json.loads(json.dumps(on.to_dict()))["outline_offsets"].keys() == {str(k) for k in on.objects}


@pytest.mark.parametrize("delta_units", [0.02, -0.03])
def test_silhouette_factor_with_outline_offset_linearizes_as_central_differences(delta_units):
    from gtsam.symbol_shorthand import O

    Tl, s = _perturbed_landmark()
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(T_CAM))
    values.insert(L(1), gtsam.Pose3(Tl))
    values.insert(S(1), s)
    values.insert(O(1), np.array([delta_units]))  # in units of 30 px: +0.6 / -0.9 px
    rays = _rays()
    keys = [X(0), L(1), S(1), O(1)]
    f = factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), *keys[:3], rays, None, O(1), 30.0)
    blocks, numeric = _linearized(f, values, keys, [6, 6, 5, 1])
    assert np.abs(blocks[3]).max() > 1e-3
    for b, n in zip(blocks, numeric):
        np.testing.assert_allclose(b, n, atol=1e-5 * max(1.0, np.abs(n).max()))
    with pytest.raises(ValueError, match="offset_unit_px"):
        factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), *keys[:3], rays, None, O(1), 0.0)


def test_a_lower_final_max_lambda_keeps_the_result():
    # the last solves' rejected trials change nothing: giving up at 1e-3 instead of GTSAM's 1e5
    # ends the same solves sooner, at the same poses and objects
    seq = synthetic_sequence(0, n_frames=12, n_objects=2)
    res = {bound: graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations,
                                           {"final_max_lambda": bound}) for bound in (1e5, 1e-3)}
    assert all(r.ok for r in res.values())
    np.testing.assert_allclose(res[1e-3].poses, res[1e5].poses, atol=1e-9)
    assert res[1e-3].iterations == res[1e5].iterations
    for oid, sq in res[1e5].objects.items():
        np.testing.assert_allclose(res[1e-3].objects[oid].to_vector(), sq.to_vector(), atol=1e-9)
    with pytest.raises(ValueError, match="final_max_lambda must be a finite number > 0"):
        graph.GraphOptions(final_max_lambda=0.0)
