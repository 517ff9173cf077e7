"""The batch's fixed past (sqfit.graph.fixedlag) and its use in the window solves (sqfit.graph.solve)."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from sqfit import graph  # noqa: E402
from sqfit.graph import fixedlag  # noqa: E402
from sqfit.graph.testing import object_ious, position_rmse, synthetic_sequence  # noqa: E402

KEYS = [gtsam.symbol("v", i) for i in range(5)]


def _linear(keys, coefficients, target, noise=None):
    """A linear residual ``sum_i c_i x_i - target`` on vector variables of dimension 2 (default: unit
    noise)."""
    def error(this, values, jacobians):
        if jacobians is not None:
            for i, c in enumerate(coefficients):
                jacobians[i] = c * np.eye(2)
        return sum(c * values.atVector(k) for k, c in zip(keys, coefficients)) - target

    return gtsam.CustomFactor(noise or gtsam.noiseModel.Unit.Create(2), keys, error)


def _chain():
    """A chain v0 - v1 - ... - v4 of linear factors, priors at both ends, and its values."""
    g, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(_linear([KEYS[0]], [1.0], np.array([0.0, 0.0])))
    g.add(_linear([KEYS[4]], [1.0], np.array([4.0, -1.0])))
    for i in range(4):
        g.add(_linear([KEYS[i + 1], KEYS[i]], [1.0, -1.0], np.array([1.2, -0.1 * i])))
    g.add(_linear([KEYS[1], KEYS[3]], [1.0, -0.5], np.array([0.3, 0.3])))  # a factor across the cut
    for i, k in enumerate(KEYS):
        values.insert(k, np.array([0.9 * i, 0.2 * i]))
    return g, values


def _solve(g, values):
    return gtsam.LevenbergMarquardtOptimizer(g, values, gtsam.LevenbergMarquardtParams()).optimize()


def test_conditioned_graph_solves_the_active_variables_with_the_rest_fixed():
    g, values = _chain()
    active = {KEYS[3], KEYS[4]}
    sub, sub_values = fixedlag.condition_on_past(g, values, active)
    assert set(sub_values.keys()) == active
    assert all(set(sub.at(k).keys()) <= active for k in range(sub.size()))
    # the same problem with v0..v2 held by (practically) hard priors at their values
    held = gtsam.NonlinearFactorGraph(g)
    for k in KEYS[:3]:
        held.add(gtsam.PriorFactorVector(k, values.atVector(k), gtsam.noiseModel.Isotropic.Sigma(2, 1e-9)))
    expected, got = _solve(held, values), _solve(sub, sub_values)
    for k in active:
        np.testing.assert_allclose(got.atVector(k), expected.atVector(k), atol=1e-6)
    # linear factors: the conditioned graph's error is that of the factors touching an active variable
    touching = [g.at(k) for k in range(g.size()) if set(g.at(k).keys()) & active]
    assert sub.error(sub_values) == pytest.approx(sum(f.error(values) for f in touching))


def test_all_active_is_the_graph_itself():
    g, values = _chain()
    sub, sub_values = fixedlag.condition_on_past(g, values, set(KEYS))
    assert sub.size() == g.size() and sub.error(sub_values) == pytest.approx(g.error(values))


def test_conditioning_names_what_it_cannot_keep():
    g, values = _chain()
    wide = gtsam.NonlinearFactorGraph()
    wide.add(_linear(KEYS, [1.0] * 5, np.zeros(2)))
    with pytest.raises(ValueError, match="1 to 3 active variables, got 4"):
        fixedlag.condition_on_past(wide, values, set(KEYS[1:]))
    hard = gtsam.NonlinearFactorGraph()
    hard.add(_linear(KEYS[:2], [1.0, -1.0], np.zeros(2), gtsam.noiseModel.Constrained.All(2)))
    with pytest.raises(ValueError, match="constrained"):
        fixedlag.condition_on_past(hard, values, {KEYS[1]})


@pytest.mark.parametrize("n, most, expected", [
    (10, 0, list(range(10))), (5, 12, list(range(5))), (10, 4, [0, 3, 6, 9]), (30, 12, None)])
def test_spread_keeps_the_ends_and_at_most_what_is_asked(n, most, expected):
    frames = list(range(100, 100 + n))
    got = fixedlag.evenly_spread(frames, most)
    if expected is not None:
        assert got == [100 + i for i in expected]
    assert got[0] == frames[0] and got[-1] == frames[-1] and len(got) <= (most or n) and got == sorted(set(got))


@pytest.mark.parametrize("past_views", [0, 2])
def test_windows_with_a_fixed_past_match_the_full_resolve(past_views):
    # 4-frame windows, 6 free frames: from the third window on, the past is held fixed (with
    # past_views 2, each landmark's older views sampled down to 2)
    seq = synthetic_sequence(1, n_frames=16, n_objects=3)
    res = {free: graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations,
                                          {"batch_start": "windows", "batch_window": 4, "batch_free_frames": free,
                                           "batch_past_views": past_views})
           for free in (0, 6)}
    ate = {free: position_rmse(r.poses, seq.true_poses) for free, r in res.items()}
    iou = {free: np.median(list(object_ious(r.objects, seq.objects).values())) for free, r in res.items()}
    assert all(r.ok for r in res.values())
    assert ate[6] < 0.5 * position_rmse(seq.odometry_poses, seq.true_poses), ate
    assert ate[6] < ate[0] + 0.02 and iou[6] > iou[0] - 0.05, (ate, iou)


def test_many_mixed_factors_keep_their_residuals():
    # each mixed factor is linearised into a temporary JacobianFactor; its rows must be copied out
    # before the next one replaces it (views into freed memory gave residuals ~1e270 and an infinite
    # error, so Levenberg-Marquardt left every fixed-past window solve where it started)
    g, values = _chain()
    rng = np.random.default_rng(0)
    for _ in range(200):
        g.add(_linear([KEYS[3], KEYS[1]], [1.0, rng.uniform(-1, 1)], rng.normal(size=2)))
    active = {KEYS[3], KEYS[4]}
    sub, sub_values = fixedlag.condition_on_past(g, values, active)
    touching = [g.at(k) for k in range(g.size()) if set(g.at(k).keys()) & active]
    assert sub.error(sub_values) == pytest.approx(sum(f.error(values) for f in touching))


def test_a_sampled_history_keeps_its_weight():
    # 40 identical views of the fixed v0 on the active v4: 4 of them, weighted 40 / 4, are the same
    # quadratic as all 40 (the same error and the same solution)
    g, values = _chain()
    for _ in range(40):
        g.add(_linear([KEYS[4], KEYS[0]], [1.0, -0.5], np.array([0.7, 0.1])))
    active = {KEYS[3], KEYS[4]}
    full, full_values = fixedlag.condition_on_past(g, values, active)
    sampled, sampled_values = fixedlag.condition_on_past(g, values, active, most=4)
    assert sampled.error(sampled_values) == pytest.approx(full.error(full_values))
    a, b = _solve(full, full_values), _solve(sampled, sampled_values)
    for k in active:
        np.testing.assert_allclose(b.atVector(k), a.atVector(k), atol=1e-9)
    # a list of the factors touching the active variables conditions as the whole graph does
    touching = [g.at(k) for k in range(g.size()) if set(g.at(k).keys()) & active]
    listed, listed_values = fixedlag.condition_on_past(touching, values, active, most=4)
    assert listed.error(listed_values) == pytest.approx(sampled.error(sampled_values))
    with pytest.raises(ValueError, match="most must be >= 0"):
        fixedlag.condition_on_past(g, values, active, most=-1)

