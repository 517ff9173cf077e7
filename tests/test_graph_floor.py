"""A known floor under the landmarks (sqfit.graph.floor): the lowest point, its Jacobians, and the
scale it gives a graph whose odometry has the wrong one."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit import graph  # noqa: E402
from sqfit.geometry.superquadric import sample_surface_parametric  # noqa: E402
from sqfit.graph import factors, floor, landmark  # noqa: E402
from sqfit.graph.testing import object_ious, synthetic_sequence, trajectory_scale  # noqa: E402
from _numeric import central_difference  # noqa: E402

from gtsam.symbol_shorthand import L, S  # noqa: E402

TILTED = sqfit.Superquadric((0.5, 0.3, 0.4), (0.6, 1.3), (0.2, -0.1, 0.9), (0.3, -0.2, 0.5))


def _retract(T, delta):
    return gtsam.Pose3(T).retract(delta).matrix()


@pytest.mark.parametrize("shape", [(0.2, 0.2), (1.0, 1.0), (1.8, 0.4), (0.6, 1.3)])
def test_lowest_point_is_the_lowest_surface_point(shape):
    sq = sqfit.Superquadric((0.5, 0.3, 0.4), shape, (0.2, -0.1, 0.9), (0.3, -0.2, 0.5))
    T, s = landmark.superquadric_to_landmark(sq)
    lowest = sample_surface_parametric(sq, 200_000, rng=0)[:, 2].min()
    assert floor.lowest_point_height(T, s) == pytest.approx(lowest, abs=2e-3)
    assert floor.lowest_point_height(T, s) <= lowest + 1e-9


def test_an_upright_superquadric_standing_on_the_floor_has_zero_residual():
    sq = sqfit.Superquadric((0.5, 0.3, 0.4), (0.3, 1.4), (1.0, 2.0, 0.4), (0.0, 0.0, 0.7))
    T, s = landmark.superquadric_to_landmark(sq)
    assert floor.floor_residual(T, s, 0.0)[0] == pytest.approx([0.0], abs=1e-12)
    assert floor.floor_residual(T, s, -0.1)[0] == pytest.approx([0.1], abs=1e-12)


def test_floor_jacobians_match_central_differences():
    T, s = landmark.superquadric_to_landmark(TILTED)
    r, J_pose, J_shape = floor.floor_residual(T, s, 0.0)
    f_pose = lambda x: floor.floor_residual(_retract(T, x), s, 0.0)[0]  # noqa: E731
    f_shape = lambda x: floor.floor_residual(T, x, 0.0)[0]  # noqa: E731
    assert np.abs(J_pose[0, :3]).max() > 0.05  # the tilt moves the lowest point
    np.testing.assert_allclose(J_pose, central_difference(f_pose, np.zeros(6)), atol=1e-6)
    np.testing.assert_allclose(J_shape, central_difference(f_shape, s), atol=1e-6)


def test_floor_factor_linearises_as_its_residual():
    T, s = landmark.superquadric_to_landmark(TILTED)
    values = gtsam.Values()
    values.insert(L(1), gtsam.Pose3(T))
    values.insert(S(1), s)
    f = factors.floor_factor(gtsam.noiseModel.Unit.Create(1), L(1), S(1), 0.25)
    r, J_pose, J_shape = floor.floor_residual(T, s, 0.25)
    np.testing.assert_allclose(f.unwhitenedError(values), r)
    A = f.linearize(values).jacobian()[0]
    np.testing.assert_allclose(A, np.hstack([J_pose, J_shape]), atol=1e-12)


def _long_odometry(seq, factor):
    """``seq``'s odometry with every step's translation ``factor`` times as long."""
    odo = [seq.odometry_poses[0]]
    for a, b in zip(seq.odometry_poses[:-1], seq.odometry_poses[1:]):
        step = np.linalg.inv(a) @ b
        step[:3, 3] *= factor
        odo.append(odo[-1] @ step)
    return np.stack(odo)


def test_a_known_floor_gives_the_graph_the_scale_the_odometry_gets_wrong():
    seq = synthetic_sequence(0, n_frames=16, n_objects=3)  # objects stand on z = 0
    odometry = _long_odometry(seq, 1.04)  # steps of ~0.7 m, each ~3 cm too long: sigma to match
    scales, ious = {}, {}
    for name, options in (("odometry's scale", {"odometry_sigma_m": 0.03}),
                          ("floor", {"odometry_sigma_m": 0.03, "floor_z": 0.0})):
        r = graph.run(seq.intrinsics, odometry, seq.observations, ["graph"], options)["graph"]
        scales[name] = trajectory_scale(r.poses, seq.true_poses)
        ious[name] = np.median(list(object_ious(r.objects, seq.objects).values()))
    assert scales["odometry's scale"] < 0.975, scales  # the graph keeps most of the odometry's 4 %
    assert abs(scales["floor"] - 1.0) < 0.01, scales
    assert ious["floor"] > ious["odometry's scale"] + 0.03, ious


def test_floor_factors_are_replaced_and_nothing_else():
    T, s = landmark.superquadric_to_landmark(TILTED)
    values, g = gtsam.Values(), gtsam.NonlinearFactorGraph()
    for oid in (1, 2):
        values.insert(L(oid), gtsam.Pose3(T))
        values.insert(S(oid), s)
        g.add(gtsam.PriorFactorPose3(L(oid), gtsam.Pose3(T), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
        g.add(factors.floor_factor(gtsam.noiseModel.Isotropic.Sigma(1, 0.01), L(oid), S(oid), 0.25))
        g.add(factors.bounds_factor(S(oid), 1.0))
    tight = factors.with_floor_factors(g, [1], gtsam.noiseModel.Isotropic.Sigma(1, 0.002), 0.25)
    assert g.size() == tight.size() == 6
    floors = [tight.at(k) for k in range(tight.size()) if tuple(tight.at(k).keys()) == (L(1), S(1))]
    assert len(floors) == 1
    r = floor.floor_residual(T, s, 0.25)[0][0]
    assert floors[0].error(values) == pytest.approx(0.5 * (r / 0.002) ** 2)
    # landmark 2's floor factor and every other factor unchanged
    assert tight.error(values) - floors[0].error(values) == pytest.approx(g.error(values) - 0.5 * (r / 0.01) ** 2)


def test_a_tighter_floor_in_the_last_solves_only(monkeypatch):
    from sqfit.graph import solve

    seq = synthetic_sequence(0, n_frames=12, n_objects=2)
    seen = []
    real = solve._lm

    def lm(g, values, options, max_lambda=None):
        seen.append(g)
        return real(g, values, options, max_lambda)

    monkeypatch.setattr(solve, "_lm", lm)
    base = {"odometry_sigma_m": 0.03, "floor_z": 0.0}
    runs = {sigma: graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"],
                             {**base, "final_floor_sigma_m": sigma})["graph"] for sigma in (None, 0.002)}
    assert all(r.ok for r in runs.values())
    assert np.abs(runs[None].poses - runs[0.002].poses).max() > 1e-6
    # the last solves replace the floor factors (as many factors as before)
    assert len(seen) >= 2 and seen[-1].size() == seen[0].size()
    lowest = {sigma: [abs(floor.lowest_point_height(*landmark.superquadric_to_landmark(sq))) for sq in r.objects.values()]
              for sigma, r in runs.items()}
    assert max(lowest[0.002]) < 0.005, lowest


def _floor_sigmas(g, oids):
    """``{oid: sigma}`` of the floor factors of landmarks ``oids`` in ``g`` (robust noise models)."""
    out = {}
    for k in range(g.size()):
        f = g.at(k)
        for oid in oids:
            if tuple(f.keys()) == (L(oid), S(oid)):
                out[oid] = float(f.noiseModel().noise().sigmas()[0])
    return out


def test_only_landmarks_that_fit_their_masks_get_the_tighter_floor(monkeypatch):
    from sqfit.graph import solve

    seq = synthetic_sequence(0, n_frames=12, n_objects=3)
    seen = []
    real_lm, real_misfits = solve._lm, solve.object_misfits

    def lm(g, values, options, max_lambda=None):
        seen.append(g)
        return real_lm(g, values, options, max_lambda)

    asked = []

    def misfits(problem, values, oids, options, *args, **kwargs):
        out = real_misfits(problem, values, oids, options, *args, **kwargs)
        asked.append(dict(out))
        # the first landmark as if no superquadric followed its masks
        return {oid: (5.0 if oid == min(out) else m) for oid, m in out.items()}

    monkeypatch.setattr(solve, "_lm", lm)
    monkeypatch.setattr(solve, "object_misfits", misfits)
    options = {"odometry_sigma_m": 0.03, "floor_z": 0.0, "final_floor_sigma_m": 0.002}
    r = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], options)["graph"]
    assert r.ok and len(r.objects) == 3 and asked
    assert max(asked[-1].values()) < 1.0, asked  # the synthetic landmarks fit their masks
    sigmas = _floor_sigmas(seen[-1], sorted(r.objects))
    first = min(r.objects)
    assert sigmas[first] == pytest.approx(0.01)  # floor_sigma_m kept
    assert all(sigmas[oid] == pytest.approx(0.002) for oid in r.objects if oid != first), sigmas


def test_no_tighter_floor_when_no_landmark_fits_well_enough():
    seq = synthetic_sequence(0, n_frames=12, n_objects=2)
    base = {"odometry_sigma_m": 0.03, "floor_z": 0.0}
    none = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"],
                     {**base, "final_floor_sigma_m": None})["graph"]
    zero = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"],
                     {**base, "final_floor_sigma_m": 0.002, "final_floor_misfit": 0.0})["graph"]
    np.testing.assert_array_equal(none.poses, zero.poses)


def test_the_last_solves_hold_frame_0_at_its_tighter_prior():
    # frame 0 defines the world frame the floor is given in: in the last solves it is held at
    # final_prior_sigma_* (0.1 mm, 0.001 deg by default), so the map cannot slide along its scale
    # about a point on the floor
    seq = synthetic_sequence(0, n_frames=12, n_objects=2)
    base = {"odometry_sigma_m": 0.03, "floor_z": 0.0}
    runs = {key: graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {**base, **given})["graph"]
            for key, given in (("default", {}), ("loose", {"final_prior_sigma_m": None, "final_prior_sigma_deg": None}))}
    assert all(r.ok for r in runs.values())
    moved = {key: np.abs(r.poses[0][:3, 3] - seq.odometry_poses[0][:3, 3]).max() for key, r in runs.items()}
    assert moved["default"] < 1e-6 < moved["loose"], moved


def test_first_pose_prior_is_replaced_and_the_other_factors_shared():
    from gtsam.symbol_shorthand import X

    from sqfit.graph.growth import noise_models, with_first_pose_prior

    noise = noise_models(graph.GraphOptions())
    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise["prior"]))
    g.add(gtsam.PriorFactorPose3(L(0), gtsam.Pose3(), noise["prior"]))  # a landmark's prior stays
    g.add(gtsam.BetweenFactorPose3(X(0), X(1), gtsam.Pose3(), noise["odometry"]))
    T = np.eye(4)
    T[:3, 3] = (0.1, -0.2, 1.5)
    out = with_first_pose_prior(g, T, noise["final_prior"])
    assert out.size() == 3
    priors = [out.at(k) for k in range(out.size())
              if isinstance(out.at(k), gtsam.PriorFactorPose3) and tuple(out.at(k).keys()) == (X(0),)]
    assert len(priors) == 1
    np.testing.assert_allclose(priors[0].prior().matrix(), T)
    np.testing.assert_allclose(priors[0].noiseModel().sigmas(), np.r_[[np.radians(0.001)] * 3, [1e-4] * 3])
    assert any(tuple(out.at(k).keys()) == (L(0),) for k in range(out.size()))


@pytest.mark.parametrize("options, match", [
    ({"final_first_view_sigma_scale": 0.0}, "final_first_view_sigma_scale"),
    ({"final_prior_sigma_m": 0.0}, "final_prior_sigma_m must be a positive number or None"),
    ({"final_prior_sigma_deg": float("nan")}, "final_prior_sigma_deg must be a positive number or None"),
    ({"final_prior_sigma_m": "1"}, "final_prior_sigma_m must be a positive number or None"),
    ({"final_floor_misfit": -1.0}, "final_floor_misfit"),
    ({"floor_z": float("nan")}, "floor_z must be a finite height or None"),
    ({"floor_sigma_m": 0.0}, "floor_sigma_m must be a finite number > 0"),
    ({"final_floor_sigma_m": 0.0}, "final_floor_sigma_m must be a positive number or None"),
    ({"final_floor_sigma_m": float("inf")}, "final_floor_sigma_m must be a positive number or None"),
])
def test_floor_options_are_checked(options, match):
    with pytest.raises(ValueError, match=match):
        graph.GraphOptions.coerce(options)


def test_no_floor_under_a_landmark_whose_fit_left_the_grazing_cost(monkeypatch):
    """A landmark 3T moved (a table fitted as its top, a lamp as its shade) need not touch the floor:
    it gets no floor factor (household sequences, both --floor and --scene-odometry-noise: graph median
    IoU 0.081 / 0.099 with a floor under every landmark, 0.195 / 0.373 without one under those)."""
    from sqfit.graph import growth

    seq = synthetic_sequence(0, n_frames=12, n_objects=2)
    monkeypatch.setattr(growth, "left_grazing", lambda result: True)  # every initial fit "mismatched"
    runs = [graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], options)["graph"]
            for options in ({"odometry_sigma_m": 0.03}, {"odometry_sigma_m": 0.03, "floor_z": 0.0})]
    np.testing.assert_array_equal(runs[0].poses, runs[1].poses)
    monkeypatch.undo()
    grazing = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"],
                        {"odometry_sigma_m": 0.03, "floor_z": 0.0})["graph"]
    assert np.abs(grazing.poses - runs[1].poses).max() > 1e-6  # with grazing fits the floor acts


def test_isam2_keeps_the_last_solves_floor_throughout(monkeypatch):
    # graph-isam2 has no last solve: its floor factors are final_floor_sigma_m's from the first
    # frame (None: floor_sigma_m); the batch's iSAM2 start keeps floor_sigma_m
    from sqfit.graph import solve

    seq = synthetic_sequence(0, n_frames=8, n_objects=2)
    graphs = []
    real = solve._isam2_rescaled

    def rebuilt(isam, factors, *args, **kwargs):
        graphs.append(factors)
        return real(isam, factors, *args, **kwargs)

    monkeypatch.setattr(solve, "_isam2_rescaled", rebuilt)
    base = {"odometry_sigma_m": 0.03, "floor_z": 0.0, "floor_sigma_m": 0.02, "isam2_rescale_every": 4,
            "isam2_rescale_parallax_deg": 0.0}
    for method, final, expected in (("graph-isam2", 0.004, 0.004), ("graph-isam2", None, 0.02), ("graph", 0.004, 0.02)):
        graphs.clear()
        r = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method],
                      {**base, "final_floor_sigma_m": final})[method]
        assert r.ok and len(r.objects) == 2 and graphs, method
        sigmas = _floor_sigmas(graphs[-1], sorted(r.objects))
        assert sorted(sigmas) == sorted(r.objects)
        assert all(v == pytest.approx(expected) for v in sigmas.values()), (method, final, sigmas)


def test_resampled_weighs_frame_0s_views_of_the_landmarks_that_fit():
    # frame 0's view ties the known first pose to the landmarks the floor holds: in the last
    # solves its silhouettes of the landmarks that fit their masks get final_first_view_sigma_scale
    from sqfit.graph.growth import Growth
    from sqfit.graph.problem import SlamResult, check_inputs

    seq = synthetic_sequence(0, n_frames=6, n_objects=2)
    options = graph.GraphOptions.coerce({"floor_z": 0.0})
    problem = check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    growth = Growth(problem, options, SlamResult("graph", problem.odometry_poses.copy()))
    g = gtsam.NonlinearFactorGraph()
    for i in range(problem.n_frames):
        new, _ = growth.add([i])
        g.push_back(new)
    assert len(growth.added) == 2
    first, other = sorted(growth.added)
    growth.bounded.add(other)  # as if its initial fit had left the grazing cost: keeps its weight

    def sigmas(graph_):
        out = {}
        for k in range(graph_.size()):
            f = graph_.at(k)
            keys = f.keys()
            if len(keys) >= 3 and keys[1] in (L(first), L(other)) and gtsam.Symbol(keys[0]).chr() == ord("x"):
                out[gtsam.Symbol(keys[0]).index(), gtsam.Symbol(keys[1]).index()] = \
                    float(f.noiseModel().noise().sigmas()[0])
        return out

    same, _ = growth.resampled(g, options.final_n_contour, 1.0)
    scaled, _ = growth.resampled(g, options.final_n_contour, 0.5)
    a, b = sigmas(same), sigmas(scaled)
    assert (0, first) in a and (0, other) in a and any(f > 0 and oid == first for f, oid in a)
    assert b[0, first] == pytest.approx(0.5 * a[0, first])
    assert b[0, other] == pytest.approx(a[0, other])
    assert all(b[key] == pytest.approx(a[key]) for key in a if key[0] > 0)
