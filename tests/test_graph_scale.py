"""The scale direction of the graph (sqfit.graph.scale): silhouettes do not see it, the odometry does."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit.graph import landmark, scale  # noqa: E402
from sqfit.testing import polygon_mask  # noqa: E402

from gtsam.symbol_shorthand import L, S, X  # noqa: E402

K_INTR = sqfit.Intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
SQ = sqfit.Superquadric((0.5, 0.3, 0.4), (0.6, 1.3), (0.2, -0.1, 0.4), (0.3, -0.2, 0.5))
CAMERAS = [sqfit.look_at([4.0 * np.cos(a), 4.0 * np.sin(a), 1.5], [0.0, 0.0, 0.4]) for a in np.linspace(0.0, 1.2, 6)]


def _values(poses, sq=SQ):
    values = gtsam.Values()
    for i, T in enumerate(poses):
        values.insert(X(i), gtsam.Pose3(T))
    T, s = landmark.superquadric_to_landmark(sq)
    values.insert(L(0), gtsam.Pose3(T))
    values.insert(S(0), np.asarray(s, dtype=np.float64))
    return values


def _keys(n):
    return [X(i) for i in range(n)], [L(0)], [S(0)]


def _odometry(poses, sigma_m=0.005):
    g = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([np.radians(0.5)] * 3 + [sigma_m] * 3))
    g.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(poses[0]), noise))
    for i in range(1, len(poses)):
        g.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), gtsam.Pose3(np.linalg.inv(poses[i - 1]) @ poses[i]), noise))
    return g


def test_silhouette_residuals_do_not_change_with_the_scale():
    cam = sqfit.Camera(K_INTR, CAMERAS[0])
    rays = landmark.camera_rays(sqfit.Observation.from_mask(cam, polygon_mask(SQ, cam), rng=0), 24)
    values = _values(CAMERAS)
    before = landmark.silhouette_residuals(CAMERAS[0], values.atPose3(L(0)).matrix(), values.atVector(S(0)), rays)[0]
    centre = np.array([1.0, -2.0, 0.5])
    moved = scale.rescaled(values, centre, 1.07, *_keys(len(CAMERAS)))
    after = landmark.silhouette_residuals(moved.atPose3(X(0)).matrix(), moved.atPose3(L(0)).matrix(),
                                          moved.atVector(S(0)), rays)[0]
    assert np.abs(before).max() > 1e-3  # a landmark off the mask's outline: residuals to compare
    np.testing.assert_allclose(after, before, atol=1e-9)
    # rotations and shapes unchanged, positions and sizes scaled about the centre
    np.testing.assert_allclose(moved.atPose3(X(3)).rotation().matrix(), CAMERAS[3][:3, :3])
    np.testing.assert_allclose(moved.atPose3(X(3)).translation(), centre + 1.07 * (CAMERAS[3][:3, 3] - centre))
    np.testing.assert_allclose(moved.atVector(S(0)), np.r_[1.07 * np.array(SQ.size), SQ.shape])


def test_best_scale_undoes_a_scaled_trajectory_from_the_odometry():
    odometry = _odometry(CAMERAS)
    keys = _keys(len(CAMERAS))
    centre = CAMERAS[0][:3, 3]
    scaled = scale.rescaled(_values(CAMERAS), centre, 1.04, *keys)
    s = scale.best_scale(odometry, scaled, centre, *keys)
    assert s == pytest.approx(1.0 / 1.04, abs=1e-6)
    back = scale.rescaled(scaled, centre, s, *keys)
    assert odometry.error(back) < 1e-6 < odometry.error(scaled)
    # at the odometry's own scale nothing moves
    assert scale.best_scale(odometry, _values(CAMERAS), centre, *keys) == pytest.approx(1.0, abs=1e-9)


def test_scale_dependent_factors_leave_out_the_invariant_ones():
    g = _odometry(CAMERAS)
    kept = scale.scale_dependent_factors(g, lambda factor: len(factor.keys()) == 1)
    assert kept.size() == g.size() - 1


def test_silhouette_factors_are_told_apart_by_their_evaluator():
    from sqfit.graph import factors

    batch, other = factors.SilhouetteFactors(), factors.SilhouetteFactors()
    cam = sqfit.Camera(K_INTR, CAMERAS[0])
    rays = landmark.camera_rays(sqfit.Observation.from_mask(cam, polygon_mask(SQ, cam), rng=0), 24)
    noise = gtsam.noiseModel.Isotropic.Sigma(len(rays), 0.05)
    g = _odometry(CAMERAS)
    g.add(factors.bounds_factor(S(0), 1.0))  # one key, changes with the scale
    g.add(factors.box_factor(gtsam.noiseModel.Isotropic.Sigma(4, 2.0), X(1), L(0), S(0), K_INTR.K,
                             np.array([100.0, 100.0, 200.0, 200.0])))  # three keys, not a silhouette
    g.add(batch.factor(noise, X(0), L(0), S(0), rays))
    g.add(batch.factor(noise, X(2), L(0), S(0), rays, offset_key=1234))
    g.add(other.factor(noise, X(3), L(0), S(0), rays))
    held = [batch.holds(g.at(k)) for k in range(g.size())]
    assert held == [False] * (g.size() - 3) + [True, True, False]
    kept = scale.scale_dependent_factors(g, batch.holds)
    assert kept.size() == g.size() - 2


def test_rescaled_needs_a_positive_factor():
    with pytest.raises(ValueError, match="scale factor must be > 0"):
        scale.rescaled(_values(CAMERAS), np.zeros(3), 0.0, *_keys(len(CAMERAS)))


def test_scale_free_and_odometry_scale_errors():
    from sqfit.graph.testing import odometry_scale_rmse, position_rmse, scale_free_rmse

    true = np.stack(CAMERAS)
    scaled = true.copy()
    scaled[:, :3, 3] = true[0, :3, 3] + 1.02 * (true[:, :3, 3] - true[0, :3, 3])
    assert position_rmse(scaled, true) > 0.01
    assert scale_free_rmse(scaled, true) == pytest.approx(0.0, abs=1e-12)
    # odometry whose steps are all 2 % long: the truth scaled by 2 % is what it allows
    assert odometry_scale_rmse(scaled, true) == pytest.approx(position_rmse(scaled, true), rel=1e-9)
    assert odometry_scale_rmse(true, true) == pytest.approx(0.0, abs=1e-12)


def test_scale_aligned_objects_undo_a_map_scaled_about_the_first_camera():
    from dataclasses import replace

    from sqfit.graph.testing import object_ious, scale_aligned_objects, trajectory_scale

    true = np.stack(CAMERAS)
    small = true.copy()
    small[:, :3, 3] = true[0, :3, 3] + (true[:, :3, 3] - true[0, :3, 3]) / 1.02
    shrunk = replace(SQ, size=tuple(np.asarray(SQ.size) / 1.02),
                     position=tuple(true[0, :3, 3] + (np.asarray(SQ.position) - true[0, :3, 3]) / 1.02))
    assert trajectory_scale(small, true) == pytest.approx(1.02, rel=1e-12)
    assert object_ious({1: shrunk}, {1: SQ})[1] < 0.95
    aligned = scale_aligned_objects({1: shrunk}, small, true)[1]
    np.testing.assert_allclose(aligned.position, SQ.position, atol=1e-12)
    np.testing.assert_allclose(aligned.size, SQ.size, rtol=1e-12)
    assert aligned.rotation == SQ.rotation and aligned.shape == SQ.shape


def test_odometry_scale_ious_score_the_truth_moved_by_the_odometrys_scale():
    from sqfit.graph.testing import odometry_scale, odometry_scale_ious

    true = np.stack(CAMERAS)
    long = true.copy()
    long[:, :3, 3] = true[0, :3, 3] + 1.02 * (true[:, :3, 3] - true[0, :3, 3])
    assert odometry_scale(long, true) == pytest.approx(1.02, rel=1e-9)
    assert odometry_scale_ious(true, true, {1: SQ})[1] == pytest.approx(1.0)
    far = sqfit.Superquadric(SQ.size, SQ.shape, (-3.0, 0.5, 0.4), SQ.rotation)  # 7 m from the first camera
    ious = odometry_scale_ious(long, true, {1: SQ, 2: far})
    assert ious[2] < ious[1] < 0.99  # 2 % of the distance to the first camera, and of the size


def test_isam2_rebuilt_at_the_best_scale_still_solves_the_sequence():
    from sqfit import graph
    from sqfit.graph.testing import position_rmse, synthetic_sequence

    seq = synthetic_sequence(0, n_frames=12, n_objects=2)
    odometry_ate = position_rmse(seq.odometry_poses, seq.true_poses)
    for every in (0, 4):
        res = graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations,
                                       {"isam2_rescale_every": every, "isam2_rescale_parallax_deg": 0})
        assert res.ok and sorted(res.objects) == sorted(seq.objects)
        assert position_rmse(res.poses, seq.true_poses) < 0.5 * odometry_ate


def test_isam2_rescale_every_must_be_a_count():
    from sqfit import graph

    with pytest.raises(ValueError, match="isam2_rescale_every"):
        graph.GraphOptions(isam2_rescale_every=-1)
