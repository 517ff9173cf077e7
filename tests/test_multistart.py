import numpy as np
import pytest

import sqfit
from sqfit.fitting import restarts as M
from sqfit.fitting.costs import ObservationSet
from sqfit.metrics import iou_3d
from sqfit.fitting.pipeline import FitOptions
from sqfit.fitting.stages import to_superquadric
from sqfit.fitting.stages import STAGES, FitState
from sqfit.geometry.superquadric import Superquadric, contains, euler_to_matrix, implicit
from sqfit.testing import paper_cameras, paper_trial, polygon_mask

OPT = FitOptions()
POSE = ((0.1, 0.2, 0.3), (0.3, -0.2, 0.5))


def same_solid(x, y, rng=0):
    """Whether two parameter vectors describe the same superquadric (implicit function at points)."""
    a, b = to_superquadric(x), to_superquadric(y)
    pts = np.asarray(a.position) + np.random.default_rng(rng).normal(size=(500, 3)) * np.max(a.size)
    return np.allclose(implicit(a, pts), implicit(b, pts), rtol=1e-6, atol=1e-9)


def candidate(xi, name):
    return M.symmetric_candidates(xi)[M.CANDIDATES.index(name)]


def test_candidates_are_valid_starts():
    xi = Superquadric((2.0, 0.8, 1.3), (0.4, 1.6), *POSE).to_vector()
    c = M.symmetric_candidates(xi)
    assert c.shape == (len(M.CANDIDATES), 11)
    np.testing.assert_allclose(c[:, 5:8], np.tile(xi[5:8], (len(c), 1)))
    assert np.all(c[:, 0:3] > 0)
    assert np.all((c[:, 3:5] >= 0.1) & (c[:, 3:5] <= 1.9))
    np.testing.assert_allclose(np.linalg.det(euler_to_matrix(c[:, 8:11])), 1.0)
    # No candidate is the input itself.
    assert not any(same_solid(xi, row) for row in c)


@pytest.mark.parametrize("e", [0.2, 1.0, 1.7])
def test_axis_permutations_are_exact_when_e1_equals_e2(e):
    xi = Superquadric((2.0, 0.8, 1.3), (e, e), *POSE).to_vector()
    assert same_solid(xi, candidate(xi, "P1"))
    assert same_solid(xi, candidate(xi, "P2"))


@pytest.mark.parametrize("shape", [(0.3, 1.6), (1.5, 0.2)])
def test_axis_permutations_compose_to_the_input(shape):
    xi = Superquadric((2.0, 0.8, 1.3), shape, *POSE).to_vector()
    assert not same_solid(xi, candidate(xi, "P1"))  # e1 != e2: a different solid ...
    assert same_solid(xi, candidate(candidate(xi, "P1"), "P2"))  # ... but P2 undoes P1


@pytest.mark.parametrize("name", ["P1", "P2"])
def test_axis_permutation_keeps_the_section_that_becomes_the_xy_section(name):
    # The new xy section is an old section of exponent e1, so e2' = e1 keeps it exactly.
    gt = Superquadric((2.0, 0.8, 1.3), (0.3, 1.6), *POSE)
    turned = to_superquadric(candidate(gt.to_vector(), name))
    R = turned.rotation_matrix
    uv = np.random.default_rng(1).uniform(-2.5, 2.5, size=(2000, 2))
    pts = np.asarray(gt.position) + uv @ R[:, :2].T  # the plane of the new local x and y axes
    np.testing.assert_array_equal(contains(turned, pts), contains(gt, pts))


@pytest.mark.parametrize("e2", [0.1, 0.5, 1.0, 1.5, 1.9])
def test_45_degree_turn_of_a_square_section(e2):
    xi = Superquadric((1.0, 1.0, 0.7), (0.6, e2), *POSE).to_vector()
    turned = candidate(xi, "R45")
    np.testing.assert_allclose(turned[3:5], [0.6, 2.0 - e2])
    # Two 45-degree turns make a right angle, a symmetry of the square section: the same solid.
    assert same_solid(xi, candidate(turned, "R45"))
    # One is an approximation of the same solid (exact for the circle, e2 = 1).
    assert iou_3d(to_superquadric(xi), to_superquadric(turned)) > (0.999 if e2 == 1.0 else 0.95)


def test_diagonal_radius():
    assert M.diagonal_radius(1.0, 1.0, 1.0) == pytest.approx(1.0)
    assert M.diagonal_radius(1.0, 1.0, 2.0) == pytest.approx(np.sqrt(0.5))  # diamond
    assert M.diagonal_radius(1.0, 1.0, 1e-3) == pytest.approx(np.sqrt(2.0), rel=1e-2)  # square


@pytest.mark.parametrize("xi, match", [
    (np.ones(10), r"xi must have shape \(11,\)"),
    (np.r_[np.nan, np.ones(10)], "xi contains NaN"),
    (np.r_[0.0, 1.0, 1.0, 1.0, 1.0, np.zeros(6)], "sizes must be non-zero"),
    (np.r_[1.0, 1.0, 1.0, 1.0, 2.5, np.zeros(6)], r"shape exponents must be in \[0.01, 2.0\]"),
])
def test_bad_input(xi, match):
    with pytest.raises(ValueError, match=match):
        M.symmetric_candidates(xi)


def observations(gt):
    return ObservationSet([sqfit.Observation.from_mask(cam, polygon_mask(gt, cam), 100, "uniform", 0)
                           for cam in paper_cameras(3)])


# A start on a wrong symmetric re-parametrisation of the truth, in which 3G gets stuck.
STUCK = [
    pytest.param((1.5, 1.5, 0.8), (0.5, 1.8), (1.0, -0.5, 2.0), "P2", "P1", id="wrong-axis"),
    pytest.param((1.0, 1.6, 2.2), (1.6, 0.3), (0.3, 0.2, 0.4), "R45", "R45", id="45-degree-turn"),
]


@pytest.mark.parametrize("size, shape, rotation, start, recovered_by", STUCK)
def test_stage_recovers_from_a_symmetric_local_minimum(size, shape, rotation, start, recovered_by):
    gt = Superquadric(size, shape, (0.5, -0.3, 0.2), rotation)
    obs = observations(gt)
    stuck = STAGES["3G"](FitState(candidate(gt.to_vector(), start)), obs, OPT)
    assert iou_3d(to_superquadric(stuck.xi), gt) < 0.85  # the precondition: 3G alone is stuck
    out = STAGES["3S"](stuck, obs, OPT)
    assert iou_3d(to_superquadric(out.xi), gt) > 0.97
    assert f"from {recovered_by};" in out.message
    assert M.misfit(out.xi, M.screen_rays(obs)) < M.TRIGGER_MISFIT < M.misfit(stuck.xi, M.screen_rays(obs))


def test_gate_keeps_a_fit_below_the_trigger(monkeypatch):
    gt = Superquadric((2.0, 0.8, 1.0), (0.2, 1.0), (0.5, -0.3, 0.2), (1.0, -0.5, 2.0))
    obs = observations(gt)
    stuck = STAGES["3G"](FitState(candidate(gt.to_vector(), "P1")), obs, OPT)
    monkeypatch.setattr(M, "TRIGGER_MISFIT", 1.0)
    out = STAGES["3S"](stuck, obs, OPT)
    np.testing.assert_array_equal(out.xi, stuck.xi)
    assert "<= 1.0: kept" in out.message and out.nfev == 1


def test_good_fit_is_kept_unchanged():
    gt = Superquadric((2.0, 0.8, 1.0), (0.2, 1.0), (0.5, -0.3, 0.2), (0.3, 0.2, 0.4))
    obs = observations(gt)
    good = STAGES["3G"](FitState(gt.to_vector()), obs, OPT)
    out = STAGES["3S"](good, obs, OPT)
    np.testing.assert_array_equal(out.xi, good.xi)
    assert out.cost == good.cost and "kept" in out.message and out.nfev == 1


def test_chain_on_a_paper_trial():
    trial = paper_trial(63)  # 1-2-3G ends with the wrong axis carrying e1
    base = sqfit.fit(trial.observations, "1-2-3G")
    assert iou_3d(base.superquadric, trial.gt) < 0.7
    result = sqfit.fit(trial.observations, "1-2-3G-3S")
    assert result.ok and [s.name for s in result.stages] == ["1", "2", "3G", "3S"]
    assert iou_3d(result.superquadric, trial.gt) > 0.95
    assert result.r_iou_m >= base.r_iou_m
