"""Stage 3R (sqfit.fitting.trimmed): 3G without the outline rays no superquadric grazes (a mug's handle)."""

import numpy as np

import sqfit
from sqfit import Observation, Superquadric
from sqfit.fitting import trimmed
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.grazing import outline_rays
from sqfit.metrics import iou_3d
from sqfit.testing import paper_cameras, paper_trial, polygon_mask


def _mug_observations(seed=0):
    """A mug: an upright cylinder-like body and a handle (a flat ring-like superquadric on its side)."""
    body = Superquadric([0.5, 0.5, 0.6], [0.1, 1.0], [0.0, 0.0, 0.6], [0.0, 0.0, 0.4])
    R = body.rotation_matrix
    handle = Superquadric([0.3, 0.06, 0.35], [0.6, 0.6], R @ [0.6, 0.0, 0.0] + [0.0, 0.0, 0.6], [0.0, 0.0, 0.4])
    rng = np.random.default_rng(seed)
    out = []
    for cam in paper_cameras(views=4, radius=8.0, height=4.0):
        mask = polygon_mask(body, cam) | polygon_mask(handle, cam)
        out.append(Observation.from_mask(cam, mask, rng=rng))
    return body, out


def test_a_mug_lets_its_handle_go():
    body, obs = _mug_observations()
    plain, tolerant = sqfit.fit(obs), sqfit.fit(obs, "tolerant")
    assert [s.name for s in tolerant.stages][-2:] == ["3R", "3T"]
    assert trimmed.MIN_COST < plain.stages[-1].cost <= sqfit.fitting.outline.TRIGGER_COST
    assert "kept it" in tolerant.stages[-2].message, tolerant.stages[-2].message
    assert iou_3d(tolerant.superquadric, body) > iou_3d(plain.superquadric, body) + 0.05


def test_outliers_are_the_rays_that_miss_the_fit():
    body, obs = _mug_observations()
    s = ObservationSet(obs)
    rays = outline_rays(s)
    out, scale = trimmed.outlier_rays(body.to_vector(), rays, sqfit.FitOptions().penalty_analytic)
    phi = trimmed.ray_phi(body.to_vector(), rays, sqfit.FitOptions().penalty_analytic)
    assert 0 < out.sum() < len(rays) // 4 and np.all(phi[out] > trimmed.PHI_MIN) and scale < trimmed.PHI_MIN
    # the truncated cost: a ray beyond PHI_MIN costs the same however far it is
    assert trimmed.truncated_cost(body.to_vector(), rays, 100.0) <= np.sum(rays.weights ** 2) * trimmed.PHI_MIN ** 2


def test_cylinder_starts_keep_centre_and_turn_each_axis_to_z():
    xi = np.array([1.0, 2.0, 3.0, 0.7, 0.4, 0.1, 0.2, 0.3, 0.3, -0.2, 1.0])
    R = Superquadric.from_vector(xi).rotation_matrix
    for axis, start in enumerate(trimmed.cylinder_starts(xi)):
        sq = Superquadric.from_vector(start)
        np.testing.assert_allclose(start[5:8], xi[5:8])
        np.testing.assert_allclose(start[3:5], trimmed.CYLINDER_SHAPE)
        assert abs(abs(sq.rotation_matrix[:, 2] @ R[:, axis]) - 1) < 1e-9 and start[2] == xi[axis]


def test_clean_superquadrics_pass_unchanged():
    for seed in range(3):
        obs = paper_trial(seed).observations
        plain, tolerant = sqfit.fit(obs), sqfit.fit(obs, "1-2M-3H-3R")
        np.testing.assert_array_equal(plain.superquadric.to_vector(), tolerant.superquadric.to_vector())
        assert "kept the input" in tolerant.stages[-1].message
