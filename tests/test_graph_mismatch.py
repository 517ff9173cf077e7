"""Landmarks whose outline one superquadric cannot graze: bounded ray residuals and the 3T test
(sqfit.graph.landmark.bounded_residuals, left_grazing; GraphOptions.mismatch_ray_k)."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit.fitting.pipeline import FitResult, StageRecord  # noqa: E402
from sqfit.graph import factors, growth, landmark, refit, solve  # noqa: E402
from sqfit.graph.testing import synthetic_sequence  # noqa: E402
from sqfit.testing import polygon_mask  # noqa: E402
from _numeric import central_difference  # noqa: E402

from gtsam.symbol_shorthand import L, S, X  # noqa: E402

K_INTR = sqfit.Intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
SQ = sqfit.Superquadric((0.5, 0.3, 0.4), (0.6, 1.3), (0.2, -0.1, 0.4), (0.3, -0.2, 0.5))
T_CAM = sqfit.look_at([4.0, 1.5, 1.5], [0.0, 0.0, 0.4])


def test_bounded_residuals_are_bounded_and_unchanged_without_a_bound():
    r = np.array([[-3.0, -0.5, 0.0, 1e-4, 0.7, 40.0], [-2.0, 0.1, 0.3, 5.0, -9.0, 1.0]])
    J = np.arange(r.size * 2, dtype=float).reshape(2, 6, 2)
    same, (J_same,) = landmark.bounded_residuals(r, [J], np.array([np.inf, np.inf]))
    np.testing.assert_array_equal(same, r)
    np.testing.assert_array_equal(J_same, J)
    out, _ = landmark.bounded_residuals(r, [J], np.array([0.5, np.inf]))
    assert np.all(np.abs(out[0]) < 0.5) and np.all(np.sign(out[0]) == np.sign(r[0]))
    np.testing.assert_array_equal(out[1], r[1])
    assert out[0, 3] == pytest.approx(1e-4, rel=1e-6)  # small residuals unchanged


def test_bounded_residual_slope_matches_central_differences():
    r = np.linspace(-4.0, 4.0, 17)[None, :]
    _, (slope,) = landmark.bounded_residuals(r, [np.ones_like(r)], np.array([0.8]))
    f = lambda x: landmark.bounded_residuals(x[None, :], [], np.array([0.8]))[0][0]  # noqa: E731
    np.testing.assert_allclose(slope[0], np.diag(central_difference(f, r[0].copy())), atol=1e-8)


def test_bounded_silhouette_factor_linearizes_as_central_differences():
    cam = sqfit.Camera(K_INTR, T_CAM)
    rays = landmark.camera_rays(sqfit.Observation.from_mask(cam, polygon_mask(SQ, cam), rng=0), 24)
    T, s = landmark.superquadric_to_landmark(SQ)
    Tl = gtsam.Pose3(T).retract(np.array([0.05, -0.03, 0.02, 0.04, 0.02, -0.03]))
    s = s * np.array([1.3, 0.8, 1.05, 1.1, 0.95])
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(T_CAM))
    values.insert(L(1), Tl)
    values.insert(S(1), s)
    keys = [X(0), L(1), S(1)]
    plain = factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), *keys, rays)
    r = plain.unwhitenedError(values)
    bound = 0.3 * np.abs(r).max()
    f = factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), *keys, rays, ray_bound=bound)
    rb = f.unwhitenedError(values)
    assert np.abs(rb).max() < bound and np.sum(np.abs(rb) < 0.9 * np.abs(r)) >= 3  # the bound acts
    linear = f.linearize(values)
    A = linear.jacobian()[0]
    col = 0
    for key, dim in zip(keys, (6, 6, 5)):
        def err(x, key=key):
            moved = gtsam.Values(values)
            if key == S(1):
                moved.update(key, s + x)
            else:
                moved.update(key, values.atPose3(key).retract(x))
            return f.unwhitenedError(moved)
        numeric = central_difference(err, np.zeros(dim))
        np.testing.assert_allclose(A[:, col:col + dim], numeric, atol=1e-5 * max(1.0, np.abs(numeric).max()))
        col += dim
    with pytest.raises(ValueError, match="ray_bound"):
        factors.silhouette_factor(gtsam.noiseModel.Unit.Create(len(rays)), *keys, rays, ray_bound=0.0)


def _record(name, sq):
    return StageRecord(name, sq, 0.0, None, "ok", "", None, 0)


def test_left_grazing_only_when_3t_moved_the_fit():
    other = sqfit.Superquadric((0.4, 0.3, 0.2), (1.0, 1.0), (0.2, -0.1, 0.4), (0.3, -0.2, 0.5))
    assert landmark.left_grazing(FitResult(other, [_record("3H", SQ), _record("3T", other)]))
    assert not landmark.left_grazing(FitResult(SQ, [_record("3H", SQ), _record("3T", SQ)]))
    assert not landmark.left_grazing(FitResult(SQ, [_record("2M", other), _record("3H", SQ)]))
    assert not landmark.left_grazing(FitResult(SQ, [_record("3T", SQ)]))


@pytest.mark.parametrize("k, bounded", [(2.0, True), (0.0, False)])
def test_landmarks_whose_fit_left_grazing_get_bounded_factors(monkeypatch, k, bounded):
    # the plumbing: a landmark whose initial fit 3T moved has its silhouette factors (and the
    # re-fit's misfit) bounded at mismatch_ray_k whitened; the others and k = 0 are not
    seq = synthetic_sequence(0, n_frames=6, n_objects=2)
    monkeypatch.setattr(growth, "left_grazing", lambda res: True)
    made = []
    real = factors.SilhouetteFactors.factor

    def factor(self, *args, **kw):
        made.append((args[7] if len(args) > 7 else kw.get("ray_bound", np.inf), len(args[4])))
        return real(self, *args, **kw)

    monkeypatch.setattr(factors.SilhouetteFactors, "factor", factor)
    result = solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"],
                       {"mismatch_ray_k": k})["graph"]
    assert result.status == "ok" and made
    bounds, rays = np.array(made).T
    # every landmark left the grazing cost here: the last solves keep their 32 rays (final_n_contour
    # applies to the landmarks that fit their masks)
    assert set(rays) == {32}
    if bounded:
        np.testing.assert_allclose(bounds, k * 0.03 / np.sqrt(rays))  # a ray's row sigma
    else:
        assert np.all(np.isinf(bounds))


def test_mismatch_ray_k_is_checked():
    with pytest.raises(ValueError, match="mismatch_ray_k"):
        solve.GraphOptions(mismatch_ray_k=-1.0)


def _grown(options, monkeypatch=None):
    # the initial fits all leave the grazing cost with a monkeypatch: every landmark bounded
    seq = synthetic_sequence(0, n_frames=6, n_objects=2)
    problem = solve.check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    if monkeypatch is not None:
        monkeypatch.setattr(growth, "left_grazing", lambda res: True)
    grown = growth.Growth(problem, solve.GraphOptions.coerce(options), solve.SlamResult("graph", problem.odometry_poses.copy()))
    g, values = grown.add(list(range(problem.n_frames)))
    return grown, g, values


def _floors(g):
    return sorted(gtsam.Symbol(g.at(k).keys()[0]).index() for k in range(g.size())
                  if len(g.at(k).keys()) == 2 and gtsam.Symbol(g.at(k).keys()[0]).chr() == ord("l")
                  and gtsam.Symbol(g.at(k).keys()[1]).chr() == ord("s"))


def _rows(grown, g, values, oid):
    # the landmark made poor, so that a bound acts on its rays
    moved = gtsam.Values(values)
    moved.update(S(oid), values.atVector(S(oid)) * np.array([1.6, 0.6, 1.4, 1.0, 1.0]))
    return [g.at(k).unwhitenedError(moved) for k in range(g.size())
            if grown.batch.holds(g.at(k)) and gtsam.Symbol(g.at(k).keys()[1]).index() == oid]


def test_a_bounded_landmark_refitted_to_graze_is_unbounded_and_floored(monkeypatch):
    options = {"floor_z": 0.0, "mismatch_ray_k": 0.5}
    plain, g_plain, values_plain = _grown(options)
    oid, other = sorted(plain.added)
    assert _floors(g_plain) == [oid, other] and not plain.bounded
    grown, g, values = _grown(options, monkeypatch)
    assert grown.bounded == {oid, other} and _floors(g) == [] and g.size() == g_plain.size() - 2
    bound = 0.5 * grown.options.silhouette_sigma  # mismatch_ray_k whitened, per ray of a view
    rows = _rows(grown, g, values, oid)
    assert all(np.abs(r).max() <= bound / np.sqrt(len(r)) for r in rows)
    expected = _rows(plain, g_plain, values_plain, oid)
    assert any(np.abs(r).max() > bound / np.sqrt(len(r)) for r in expected)  # the bound acts
    # a re-fit that left the grazing cost, and one of a landmark not bounded: nothing changes
    assert grown.refitted(g, {other: True}) is g and grown.bounded == {oid, other}
    out = grown.refitted(g, {oid: False})
    assert grown.bounded == {other} and _floors(out) == [oid] and out.size() == g.size() + 1
    assert grown.refitted(out, {oid: False}) is out
    # its factors, the same objects, now give the rows of a landmark never bounded
    rows = _rows(grown, g, values, oid)
    assert len(rows) == len(expected) > 0
    for r, e in zip(rows, expected):
        np.testing.assert_array_equal(r, e)
    assert all(np.abs(r).max() <= bound / np.sqrt(len(r)) for r in _rows(grown, g, values, other))


def test_refit_landmarks_says_which_refits_left_grazing(monkeypatch):
    grown, g, values = _grown({})
    oid = sorted(grown.added)[0]
    far = gtsam.Values(values)  # moved far off its masks: re-fitted for its overlap
    far.update(L(oid), gtsam.Pose3(gtsam.Rot3(), values.atPose3(L(oid)).translation() + np.array([0.0, 0.0, 40.0])))
    for left in (True, False):
        monkeypatch.setattr(growth, "left_grazing", lambda res, left=left: left)
        moved = gtsam.Values(far)
        out = refit.refit_landmarks(grown.problem, moved, grown.added, grown.options, grown.result, overlap_only=True)
        assert out == {oid: left}
    assert refit.refit_landmarks(grown.problem, values, grown.added, grown.options, grown.result, overlap_only=True) == {}
