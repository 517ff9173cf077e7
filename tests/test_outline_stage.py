"""Stage 3T (sqfit.fitting.outline): G2 on the mask contours where no superquadric grazes the outline."""

import numpy as np

import sqfit
from sqfit import Observation, Superquadric
from sqfit.fitting import outline
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.stages import r_iou_m
from sqfit.geometry.polygon import batch_iou
from sqfit.metrics import iou_3d
from sqfit.testing import paper_cameras, paper_trial, polygon_mask


def _table_observations(seed=0):
    """A table: a thin top and four thin legs, seen by four elevated cameras (masks = union of the parts)."""
    top = Superquadric([1.2, 0.7, 0.04], [0.1, 0.1], [0.0, 0.0, 0.8], [0.0, 0.0, 0.3])
    R = top.rotation_matrix
    legs = [Superquadric([0.04, 0.04, 0.38], [0.5, 1.0], R @ [sx * 1.05, sy * 0.6, 0.0] + [0.0, 0.0, 0.38],
                         [0.0, 0.0, 0.3]) for sx in (-1, 1) for sy in (-1, 1)]
    rng = np.random.default_rng(seed)
    out = []
    for cam in paper_cameras(views=4, radius=8.0, height=4.0):
        mask = np.zeros((cam.intrinsics.height, cam.intrinsics.width), dtype=bool)
        for part in [top] + legs:
            mask |= polygon_mask(part, cam)
        out.append(Observation.from_mask(cam, mask, rng=rng))
    return top, out


def test_clean_superquadrics_pass_unchanged():
    for seed in range(3):
        obs = paper_trial(seed).observations
        plain, tolerant = sqfit.fit(obs), sqfit.fit(obs, "1-2M-3H-3T")
        np.testing.assert_array_equal(plain.superquadric.to_vector(), tolerant.superquadric.to_vector())
        assert "kept the input" in tolerant.stages[-1].message and "3G cost" in tolerant.stages[-1].message


def test_a_table_lets_its_legs_go():
    top, obs = _table_observations()
    plain, tolerant = sqfit.fit(obs, "1-2M-3H-3R"), sqfit.fit(obs, "tolerant")
    # the legs are a part seen in every view: the default's 3TP keeps 3T's fit too (3RH does not act above 3T's trigger)
    np.testing.assert_array_equal(sqfit.fit(obs, "1-2M-3H-3R-3V").superquadric.to_vector(),
                                  tolerant.superquadric.to_vector())
    assert tolerant.chain == sqfit.fitting.pipeline.TOLERANT_CHAIN == "1-2M-3H-3RH-3T" and [s.name for s in tolerant.stages][-1] == "3T"
    assert plain.stages[-1].cost > outline.TRIGGER_COST  # no superquadric grazes top and legs
    assert "G2 on the contours" in tolerant.stages[-1].message and "->" in tolerant.stages[-1].message
    s = ObservationSet(obs)
    before, after = r_iou_m([plain.superquadric, tolerant.superquadric], s, "contour")
    assert after > before + 0.1
    # the legs no longer pull it down towards the floor: it is the top (the best single superquadric
    # of a table whose legs are thin), where the default fit straddles top and legs
    assert iou_3d(tolerant.superquadric, top) > 0.7 > iou_3d(plain.superquadric, top) + 0.3
    assert abs(tolerant.superquadric.position[2] - top.position[2]) < 0.05


def test_an_input_without_a_cost_is_kept():
    obs = paper_trial(0).observations
    result = sqfit.fit(obs, "3T", initial=paper_trial(0).gt)
    assert "no 3G cost" in result.stages[-1].message
    np.testing.assert_allclose(result.superquadric.to_vector(), paper_trial(0).gt.to_vector())


def test_contour_iou_survives_a_self_intersecting_polygon():
    # GEOS rejects a self-intersecting silhouette (a far-off, degenerate solve) with a
    # TopologyException; batch_iou then scores its valid repair instead of raising
    bow = np.array([[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]])
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    iou = batch_iou(bow[None, None], np.ones((1, 1), dtype=bool), [square], convex=False)
    assert iou.shape == (1, 1) and abs(iou[0, 0] - 0.5) < 1e-12  # the two triangles: area 2 of 4
