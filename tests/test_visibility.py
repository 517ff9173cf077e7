"""Boundary labels (sqfit.views.visibility) and the costs and stages that read them."""

import numpy as np
import pytest

import sqfit
from sqfit import Observation
from sqfit.views.dataset import observations_from_images
from sqfit.metrics import iou_3d
from sqfit.fitting.raycost import ray_residuals
from sqfit.views.rays import CONTOUR, OUTSIDE, RaySet, contour_rays
from sqfit.testing import paper_trial, truncated_trial
from sqfit.views.visibility import (BACKGROUND, BORDER, INSTANCE, INTERIOR, OCCLUDER_REACH_PX, hiding_pixels,
                              outline_labels, point_labels, silhouette_fraction)
from sqfit.geometry.polygon import polygon_iou
from sqfit.geometry.visible_iou import clipped_convex_iou, clipped_convex_iou_jacobian, image_rectangles, points_in_convex
from _numeric import central_difference

from _helpers import CAM, rect_mask as rect  # noqa: E402


def side_labels(obs):
    """Labels of the vertices on each side of a rectangle's outline (corners excluded)."""
    u, v = obs.contour[:, 0], obs.contour[:, 1]
    lab = obs.contour_labels
    lo_u, hi_u, lo_v, hi_v = u.min(), u.max(), v.min(), v.max()
    return {"left": set(lab[np.isclose(u, lo_u)]), "right": set(lab[np.isclose(u, hi_u)]),
            "top": set(lab[np.isclose(v, lo_v)]), "bottom": set(lab[np.isclose(v, hi_v)])}


def test_rule_1_background_border_and_instance():
    # Object touches the left border; an occluder sits right next to its right side.
    mask = rect(c0=0)
    occluder = rect(c0=30, c1=40)
    obs = Observation.from_mask(CAM, mask, rng=0, occluder=occluder)
    sides = side_labels(obs)
    assert sides["left"] == {BORDER}
    assert sides["right"] == {INSTANCE}
    # Top and bottom: background, except the vertices next to the border / the occluder.
    inner_top = obs.contour_labels[np.isclose(obs.contour[:, 1], 10.0) & (obs.contour[:, 0] > 1)
                                   & (obs.contour[:, 0] < 28)]
    assert set(inner_top) == {BACKGROUND}
    assert obs.touches_border and obs.partial


def test_rule_2_occluder_reach():
    near = Observation.from_mask(CAM, rect(), rng=0, occluder=rect(c0=30 + OCCLUDER_REACH_PX, c1=40))
    far = Observation.from_mask(CAM, rect(), rng=0, occluder=rect(c0=31 + OCCLUDER_REACH_PX, c1=40))
    assert side_labels(near)["right"] == {INSTANCE}
    assert side_labels(far)["right"] == {BACKGROUND}
    assert not far.partial and far.silhouette_fraction == 1.0


def test_rule_3_points_between_vertices_take_the_larger_label():
    np.testing.assert_array_equal(point_labels([BACKGROUND, INSTANCE, BORDER], [0, 1, 2]),
                                  [INSTANCE, BORDER, BORDER])


def test_silhouette_fraction_of_a_half_occluded_square():
    contour = np.array([[0.0, 0.0], [1, 0], [2, 0], [2, 1], [2, 2], [1, 2], [0, 2], [0, 1]])
    labels = np.array([BACKGROUND] * 8)
    assert silhouette_fraction(contour, labels) == 1.0
    labels[2:5] = INSTANCE  # the right side and the edges into it
    assert silhouette_fraction(contour, labels) == pytest.approx(4 / 8)


def test_outline_labels_directly_match_observation():
    mask = rect(c0=0)
    obs = Observation.from_mask(CAM, mask, rng=0)
    np.testing.assert_array_equal(outline_labels(obs.contour, mask), obs.contour_labels)


def test_from_mask_without_occluder_is_unchanged_and_labels_only_the_border():
    obs = Observation.from_mask(CAM, rect(), rng=7)
    assert set(obs.contour_labels) == {BACKGROUND} and set(obs.sample_labels) == {INTERIOR}
    assert not obs.partial and obs.without_labels() is obs
    cut = Observation.from_mask(CAM, rect(r0=0), rng=7)
    assert side_labels(cut)["top"] == {BORDER} and side_labels(cut)["left"] == {BACKGROUND}
    assert set(cut.without_labels().contour_labels) == {BACKGROUND}


def test_contour_samples_carry_outline_labels():
    obs = Observation.from_mask(CAM, rect(c0=0), n_samples=200, sampling="mixed", rng=1)
    area, outline = obs.sample_labels[:100], obs.sample_labels[100:]
    assert set(area) == {INTERIOR}
    on_left = np.isclose(obs.samples[100:, 0], 0.0)
    assert on_left.any() and set(outline[on_left]) == {BORDER}


def test_occluder_validation():
    with pytest.raises(ValueError, match=r"occluder must have shape \(height, width\) = \(48, 64\)"):
        Observation.from_mask(CAM, rect(), occluder=np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="occluder must be boolean or numeric"):
        Observation.from_mask(CAM, rect(), occluder=np.full((48, 64), "x"))


def test_label_array_validation():
    obs = Observation.from_mask(CAM, rect(), rng=0)
    with pytest.raises(ValueError, match=r"contour_labels must have shape"):
        Observation(obs.camera, obs.samples, obs.contour, obs.centroid, obs.area_px, False, np.zeros(3))


def instance_images(trial):
    """Instance images of a paper trial (object id 1) with an occluder (id 2) over view 0's right third."""
    images = np.stack([m.astype(np.uint16) for m in trial.masks])
    cols = np.flatnonzero(trial.masks[0].any(axis=0))
    cut = cols[0] + 2 * len(cols) // 3
    images[0][:, cut:][images[0][:, cut:] == 1] = 2
    return images


def test_observations_from_images_labels_other_instances():
    t = paper_trial(4)
    images = instance_images(t)
    obs = observations_from_images(t.cameras, images, 1, rng=0)
    assert len(obs) == 3 and obs.warnings == []
    assert INSTANCE in obs[0].contour_labels and 0.3 < obs[0].silhouette_fraction < 0.95
    assert not obs[1].partial and not obs[2].partial


def test_hidden_view_is_flagged_in_fit_warnings():
    t = paper_trial(4)
    images = instance_images(t)
    images[1][images[1] == 1] = 2  # view 1: object 1 entirely hidden by object 2
    obs = observations_from_images(t.cameras, images, 1, rng=0)
    assert len(obs) == 2
    assert obs.warnings == ["view 1: object 1 is not visible (entirely hidden by other objects or outside "
                            "the image); view skipped"]
    result = sqfit.fit(obs, "1-2-3G")
    assert result.ok and result.warnings[0] == obs.warnings[0]


def test_fully_occluded_outline_is_flagged_not_a_crash():
    t = paper_trial(4)
    ring = np.zeros_like(t.masks[0])
    from scipy import ndimage
    ring = ndimage.binary_dilation(t.masks[0], iterations=3) & ~t.masks[0]
    obs = [Observation.from_mask(t.cameras[0], t.masks[0], rng=0, occluder=ring)] + t.observations[1:]
    assert obs[0].silhouette_fraction == 0.0
    result = sqfit.fit(obs, "1-2-3G")
    assert result.ok
    assert any(w.startswith("view 0: all of the outline is labelled occluded or truncated") for w in result.warnings)
    # Every view fully occluded: the chain still ends with a result and flags each view.
    obs = [Observation.from_mask(c, m, rng=0, occluder=ndimage.binary_dilation(m, iterations=3) & ~m)
           for c, m in zip(t.cameras, t.masks)]
    result = sqfit.fit(obs, "1-2-3G")
    assert result.superquadric is not None
    assert sum("all of the outline" in w for w in result.warnings) == 3


def test_rayset_two_sided_validation():
    o, d = np.zeros((2, 3)), np.ones((2, 3))
    with pytest.raises(ValueError, match=r"two_sided must be a boolean array of shape \(2,\)"):
        RaySet(o, d, [0, 0], [1.0, 1.0], [0, 0], np.ones(2))
    assert RaySet(o, d, [0, 0], [1.0, 1.0], [0, 0]).two_sided.all()


def test_one_sided_rays_keep_only_the_hit_constraint():
    t = truncated_trial(2, 0.3)
    rays = contour_rays(t.observations, 32)
    one_sided = ~rays.two_sided
    assert one_sided.any() and np.all(rays.view[one_sided] == 0)
    unlabelled = RaySet(rays.origins, rays.directions, rays.modes, rays.weights, rays.view)
    big = t.gt.to_vector()
    big[0:3] *= 1.5  # too large: every contour ray passes through it
    r = ray_residuals(big, rays)[0][:len(rays)]
    assert np.all(r[one_sided] == 0.0)  # the object may reach past an occluded or truncated point
    assert np.all(r[rays.two_sided] < 0.0)
    for scale in (0.5, 0.9, 1.1):
        xi = t.gt.to_vector()
        xi[0:3] *= scale
        r = ray_residuals(xi, rays)[0][:len(rays)]
        two = ray_residuals(xi, unlabelled)[0][:len(rays)]
        np.testing.assert_array_equal(r[one_sided], np.maximum(two[one_sided], 0.0))  # "the ray hits it" only
        np.testing.assert_array_equal(r[rays.two_sided], two[rays.two_sided])


@pytest.mark.parametrize("band_px", [0.0, 2.0])
def test_labelled_ray_jacobian_matches_central_differences(band_px):
    t = truncated_trial(2, 0.3)
    rays = contour_rays(t.observations, 16, band_px)
    assert (~rays.two_sided).any() and (rays.modes == (CONTOUR if band_px == 0 else OUTSIDE)).any()
    xi = t.gt.to_vector()
    xi[3:5] = (0.8, 1.2)
    xi[0:3] *= 1.1
    r, J, _ = ray_residuals(xi, rays)
    numeric = central_difference(lambda x: ray_residuals(x, rays)[0], xi)
    np.testing.assert_allclose(J, numeric, atol=1e-5, rtol=1e-4)


def test_truncated_view_fit_beats_unaware_fit():
    aware, unaware = [], []
    for seed in range(5):
        t = truncated_trial(seed, 0.3)
        aware.append(iou_3d(sqfit.fit(t.observations).superquadric, t.gt))
        unaware.append(iou_3d(sqfit.fit(t.observations, options={"occlusion_aware": False}).superquadric, t.gt))
    assert np.median(aware) > 0.85
    assert np.median(aware) > np.median(unaware) + 0.1


def test_truncated_trial_cuts_the_requested_fraction():
    t = truncated_trial(1, 0.3)
    whole = sqfit.testing.polygon_mask(t.gt, sqfit.testing.paper_cameras()[0]).sum()
    assert 1 - t.masks[0].sum() / whole == pytest.approx(0.3, abs=0.02)
    assert t.observations[0].touches_border and not t.observations[1].touches_border
    with pytest.raises(ValueError, match=r"cut_fraction must be in \[0, 1\)"):
        truncated_trial(1, 1.0)


def test_occlusion_aware_option_validation():
    with pytest.raises(ValueError, match="occlusion_aware must be True or False"):
        sqfit.FitOptions(occlusion_aware="yes")


def _polygon(n, centre, radius, phase=0.3):
    t = phase + 2 * np.pi * np.arange(n) / n
    return np.stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t)], axis=1)


def test_clipped_iou_is_the_iou_of_the_clipped_silhouette():
    import shapely

    R = image_rectangles([(64, 48)])[0]
    S = _polygon(9, (5.0, 20.0), 15.0)  # sticks out of the left border
    Q = _polygon(7, (12.0, 21.0), 8.0)
    clipped = shapely.Polygon(S).intersection(shapely.Polygon(R))
    q = shapely.Polygon(Q)
    expected = clipped.intersection(q).area / clipped.union(q).area
    assert clipped_convex_iou(S, Q, R) == pytest.approx(expected, rel=1e-12)
    inside = _polygon(9, (30.0, 20.0), 10.0)  # inside the image: the plain IoU
    assert clipped_convex_iou(inside, Q, R) == pytest.approx(polygon_iou(inside, Q), rel=1e-12)


def test_clipped_iou_gradient_matches_central_differences():
    R = image_rectangles([(64, 48)])[0]
    S = _polygon(9, (5.0, 20.0), 15.0)
    Q = _polygon(7, (12.0, 21.0), 8.0)
    _, weights = clipped_convex_iou_jacobian(S, Q, R)
    numeric = central_difference(lambda x: np.atleast_1d(clipped_convex_iou(x.reshape(-1, 2), Q, R)), S.ravel())
    np.testing.assert_allclose(weights().ravel(), numeric[0], atol=1e-8)


def test_riou_counts_only_the_image_in_cut_views():
    from sqfit.fitting.costs import ObservationSet, riou_residuals

    t = truncated_trial(2, 0.3)
    obs = ObservationSet(t.observations)
    assert obs.border_views.tolist() == [True, False, False]
    xi = t.gt.to_vector()[None]
    r_vis = riou_residuals(xi, obs)[0][0, :3]
    plain = ObservationSet([o.without_labels() for o in t.observations])
    r_plain = riou_residuals(xi, plain)[0][0, :3]
    # At the truth the hull sees only the visible part: clipping removes the unseen area from the union.
    assert r_vis[0] < r_plain[0] - 0.1
    np.testing.assert_array_equal(r_vis[1:], r_plain[1:])
    # The analytic Jacobian of the cut view matches finite differences of the residual.
    x = xi[0].copy()
    x[0:3] *= 1.1
    _, _, d_views = riou_residuals(x[None], obs, jacobian=True, tol=1e-9)
    numeric = central_difference(lambda z: riou_residuals(z[None], obs, tol=1e-9)[0][0, :3], x, h=1e-5)
    np.testing.assert_allclose(d_views()[0][0], numeric[0], rtol=0.05, atol=2e-3)


def test_rule_5_hiding_pixels_are_the_touching_occluder_components():
    occluder = rect(c0=30, c1=40) | rect(r0=30, r1=40, c0=50, c1=60)  # one touches, one is far away
    obs = Observation.from_mask(CAM, rect(), rng=0, occluder=occluder)
    assert obs.hidden.shape == (100, 2)
    assert np.all((obs.hidden[:, 0] > 30) & (obs.hidden[:, 0] < 40))
    assert Observation.from_mask(CAM, rect(), rng=0).hidden.shape == (0, 2)
    assert len(obs.without_labels().hidden) == 0
    assert hiding_pixels(rect(), None).shape == (0, 2)


def test_points_in_convex():
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    pts = np.array([[1.0, 1.0], [3.0, 1.0], [0.0, 0.0], [-0.1, 1.0]])
    np.testing.assert_array_equal(points_in_convex(square, pts), [True, False, True, False])
    np.testing.assert_array_equal(points_in_convex(np.stack([square, square + 2.5]), pts),
                                  [[True, False, True, False], [False, False, False, False]])


def test_occluded_iou_leaves_hidden_pixels_out_and_its_gradient_is_analytic():
    R = image_rectangles([(64, 48)])[0]
    S = _polygon(9, (25.0, 20.0), 12.0)
    Q = _polygon(7, (22.0, 21.0), 8.0)
    plain = clipped_convex_iou(S, Q, R)
    hidden = clipped_convex_iou_jacobian(S, Q, R, clip=False, hidden_inter=0.0, hidden_union=60.0)
    assert hidden[0] > plain  # hidden pixels in S outside Q no longer count against the fit
    # counts held constant: the vertex gradient matches central differences
    numeric = central_difference(lambda x: np.atleast_1d(clipped_convex_iou_jacobian(
        x.reshape(-1, 2), Q, R, clip=False, hidden_inter=5.0, hidden_union=60.0)[0]), S.ravel())
    W = clipped_convex_iou_jacobian(S, Q, R, clip=False, hidden_inter=5.0, hidden_union=60.0)[1]()
    np.testing.assert_allclose(W.ravel(), numeric[0], atol=1e-8)


def test_riou_m_of_the_truth_is_higher_with_occlusion_labels():
    from sqfit.fitting.stages import r_iou_m
    from sqfit.fitting.costs import ObservationSet

    t = paper_trial(4)
    images = instance_images(t)
    obs = observations_from_images(t.cameras, images, 1, rng=0)
    assert len(obs[0].hidden) > 0
    aware = r_iou_m([t.gt], ObservationSet(obs))[0]
    unaware = r_iou_m([t.gt], ObservationSet([o.without_labels() for o in obs]))[0]
    assert aware > unaware + 0.05
    assert r_iou_m([t.gt], ObservationSet(obs), "contour")[0] > r_iou_m(
        [t.gt], ObservationSet([o.without_labels() for o in obs]), "contour")[0] + 0.05


def test_observations_from_images_validation():
    t = paper_trial(4)
    with pytest.raises(ValueError, match="images must hold integer instance ids"):
        observations_from_images(t.cameras, np.stack(t.masks).astype(float), 1)
    obs = t.observations[0]
    with pytest.raises(ValueError, match=r"hidden must have shape \(k, 2\)"):
        Observation(obs.camera, obs.samples, obs.contour, obs.centroid, obs.area_px, False, hidden=np.zeros(3))


def test_every_paper_chain_runs_on_cut_and_occluded_views():
    t = truncated_trial(3, 0.3)
    images = np.stack([m.astype(np.uint16) for m in t.masks])
    cols = np.flatnonzero(t.masks[1].any(axis=0))
    right = images[1][:, cols[0] + len(cols) // 2:]
    right[right == 1] = 2  # view 1 half hidden by object 2; view 0 cut by the border
    obs = observations_from_images(t.cameras, images, 1, rng=0)
    assert obs[0].touches_border and len(obs[1].hidden) > 0
    for chain in sqfit.PAPER_CHAINS + ("1-2-3G-3S",):
        result = sqfit.fit(obs, chain)
        assert result.ok and 0.0 <= result.r_iou_m <= 1.0, chain


def test_warnings_name_image_views_when_one_is_skipped():
    t = truncated_trial(2, 0.3, cut_views=3)
    images = np.stack([m.astype(np.uint16) for m in t.masks])
    images[0][images[0] == 1] = 2  # view 0 hidden: the observations are views 1 and 2
    obs = observations_from_images(t.cameras, images, 1, rng=0)
    assert obs.views == [1, 2]
    warnings = sqfit.fit(obs, "1-2").warnings
    assert warnings[0].startswith("view 0: object 1 is not visible")
    assert warnings[1].startswith("view 1: mask touches the image border")
    assert warnings[2].startswith("view 2: mask touches the image border")


def test_frozen_hidden_counts_reproduce_the_residuals_at_their_point():
    from sqfit.fitting.costs import ObservationSet, hidden_at, riou_residuals

    t = paper_trial(4)
    obs = ObservationSet(observations_from_images(t.cameras, instance_images(t), 1, rng=0))
    xi = t.gt.to_vector()[None]
    xi[0, 0:3] *= 1.2
    hidden = hidden_at(xi, obs)
    assert hidden[1][0, 0] > 0  # the enlarged silhouette covers hidden pixels in view 0
    np.testing.assert_allclose(riou_residuals(xi, obs, hidden=hidden)[0], riou_residuals(xi, obs)[0], atol=1e-6)
    # The contour-polygon cost keeps hidden pixels (measured better); R-IOU-M leaves them out for both.
    zero = riou_residuals(xi, obs, "contour", hidden=(0.0, 0.0))[0]
    np.testing.assert_allclose(riou_residuals(xi, obs, "contour")[0], zero)
    np.testing.assert_allclose(riou_residuals(xi, obs, "contour", hidden=hidden_at(xi, obs, "contour"))[0], zero)
