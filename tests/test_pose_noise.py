"""Stage 3G/3H under camera rotation noise: the pose prior scaled to the residual noise once the
rotation corrections say that the cameras disagree (sqfit.fitting.grazing, sqfit.fitting.axis_screen),
and those corrections handed on to stage 3R, which re-fits on the turned cameras too
(FitState.camera_corrections, ObservationSet.turned, sqfit.fitting.trimmed)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import sqfit
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.grazing import (POSE_NOISE_TRIGGER_DEG, outline_rays, pose_noise_estimate, pose_prior_scale,
                                   silhouette_fit)
from sqfit.fitting.outline import TRIGGER_COST
from sqfit.fitting.raycost import posed_ray_residuals, ray_residuals
from sqfit.fitting.stages import STAGES, FitState, to_superquadric
from sqfit.fitting.trimmed import TURN_MIN_DEG
from sqfit.metrics import iou_3d, iou_3d_mesh
from sqfit.testing import paper_trial
from sqfit.views.rays import contour_rays
from _helpers import stage, through_3h, turned_pose

#: Per-view camera-frame rotation errors (degrees) of the "noisy" trial below.
TURNS_DEG = [(1.0, -0.5, 0.3), (-0.8, 1.2, -0.4), (0.6, 0.9, 1.0)]


def _turned_observations(trial, turns_deg):
    obs = []
    for o, delta in zip(trial.observations, turns_deg):
        pose = turned_pose(o.camera.pose, np.radians(delta))
        obs.append(sqfit.Observation(sqfit.Camera(o.camera.intrinsics, pose), o.samples, o.contour, o.centroid,
                                     o.area_px, o.touches_border))
    return obs


def test_pose_noise_estimate_is_the_rms_rotation_angle():
    w = np.radians([1.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    assert pose_noise_estimate(w) == pytest.approx(np.sqrt(5.0 / 3.0))
    assert pose_noise_estimate(np.zeros(6)) == 0.0


def test_pose_prior_scale_is_the_residual_noise_over_the_rotation_noise():
    trial = paper_trial(1)
    rays = contour_rays(trial.observations, 16)
    xi = trial.gt.to_vector() * np.r_[1.1, 0.9, 1.0, np.ones(8)]
    options = sqfit.FitOptions()
    r = ray_residuals(xi, rays, options.penalty_analytic)[0][:len(rays)]
    expected = np.sqrt(np.mean(r ** 2)) / np.radians(0.5)
    assert pose_prior_scale(0.5, rays, xi, options) == pytest.approx(expected)
    assert pose_prior_scale(1.0, rays, xi, options) == pytest.approx(expected / 2)


def test_consistent_cameras_keep_the_fixed_prior():
    trial = paper_trial(1)
    fit = silhouette_fit(FitState(trial.gt.to_vector()), ObservationSet(trial.observations), sqfit.FitOptions())
    assert fit.pose_noise_deg < POSE_NOISE_TRIGGER_DEG and fit.pose_scale is None
    assert "pose prior scaled" not in fit.state.message


def test_turned_cameras_get_the_noise_scaled_prior():
    trial = paper_trial(1)
    obs = ObservationSet(_turned_observations(trial, TURNS_DEG))
    options = sqfit.FitOptions()
    fit = silhouette_fit(FitState(trial.gt.to_vector()), obs, options)
    assert fit.pose_noise_deg > POSE_NOISE_TRIGGER_DEG and fit.pose_scale > 0
    assert "pose prior scaled to the residual noise" in fit.state.message
    # a given scale is used as it is, in one run (how 3H compares its candidates)
    again = silhouette_fit(FitState(trial.gt.to_vector()), obs, options, plain_first=False, pose_scale=fit.pose_scale)
    assert again.pose_scale == fit.pose_scale
    assert again.state.nfev < fit.state.nfev


def test_3h_refines_every_candidate_when_the_cameras_disagree():
    trial = paper_trial(1)
    result = sqfit.fit(_turned_observations(trial, TURNS_DEG))
    assert result.ok
    assert "refined all under the pose prior" in stage(result, "3H").message
    assert iou_3d(result.superquadric, trial.gt) > 0.7
    clean = sqfit.fit(trial.observations)
    assert "refined all" not in stage(clean, "3H").message


def test_without_pose_noise_refit_the_fixed_prior_fit_is_kept():
    # FitOptions.pose_noise_refit=False (the factor graph's fits): the corrections are still
    # estimated under the fixed prior, but neither 3G's second run nor 3H's refinement of every
    # candidate follows
    trial = paper_trial(1)
    obs = ObservationSet(_turned_observations(trial, TURNS_DEG))
    options = sqfit.FitOptions(pose_noise_refit=False)
    fit = silhouette_fit(FitState(trial.gt.to_vector()), obs, options)
    assert fit.pose_noise_deg > POSE_NOISE_TRIGGER_DEG and fit.pose_scale is None
    assert "pose prior scaled" not in fit.state.message
    result = sqfit.fit(_turned_observations(trial, TURNS_DEG), options=options)
    assert result.ok and "refined all" not in stage(result, "3H").message
    # a usable fit; whether it stays below the branch's (> 0.7 above) depends on rounding: below 0.7
    # where this test was written, 0.85 with numba 0.67-0.68 on an AMD EPYC (2026-11-27)
    assert iou_3d(result.superquadric, trial.gt) > 0.5
    with pytest.raises(ValueError, match="pose_noise_refit must be True or False"):
        sqfit.FitOptions(pose_noise_refit=1)


def test_turned_observations_turn_each_camera_about_its_centre():
    trial = paper_trial(1)
    obs = ObservationSet(trial.observations)
    w = np.radians([[1.0, -2.0, 0.5], [0.0, 0.0, 0.0], [-0.3, 0.2, 3.0]])
    arc = obs.observations[0].contour_arc
    turned = obs.turned(w)
    assert np.allclose(turned.rotations, Rotation.from_rotvec(w).as_matrix() @ obs.rotations, atol=1e-12)
    assert np.array_equal(turned.centers, obs.centers) and np.array_equal(turned.rotations[1], obs.rotations[1])
    assert turned.observations[0].contour_arc is arc  # the masks' own caches are shared
    assert obs.rotations[0] is not turned.rotations[0] and np.array_equal(obs.rotations[0],
                                                                          trial.observations[0].camera.rotation)
    with pytest.raises(ValueError, match="corrections"):
        obs.turned(w[:2])


def test_corrections_are_handed_on_where_the_cameras_disagree_and_the_fit_grazes():
    trial = paper_trial(1)
    obs = ObservationSet(_turned_observations(trial, TURNS_DEG))
    fit = silhouette_fit(FitState(trial.gt.to_vector()), obs, sqfit.FitOptions())
    w = fit.state.camera_corrections
    assert fit.pose_scale is not None and fit.state.cost <= TRIGGER_COST and w.shape == (3, 3)
    # the turned cameras give the plain rays what the corrections gave the posed ones (to first order)
    rays = outline_rays(obs)
    posed = posed_ray_residuals(np.r_[fit.state.xi, w.ravel()], rays, 1.0)[0][:len(rays)]
    plain = ray_residuals(fit.state.xi, outline_rays(obs.turned(w)))[0][:len(rays)]
    assert np.abs(posed - plain).max() < 1e-3
    given = ray_residuals(fit.state.xi, rays)[0][:len(rays)]
    assert np.sum(plain ** 2) < 0.5 * np.sum(given ** 2)
    # consistent cameras, or the fixed prior: nothing to hand on
    assert silhouette_fit(FitState(trial.gt.to_vector()), ObservationSet(trial.observations),
                          sqfit.FitOptions()).state.camera_corrections is None
    fixed = silhouette_fit(FitState(trial.gt.to_vector()), obs, sqfit.FitOptions(pose_noise_refit=False))
    assert fixed.state.camera_corrections is None


def test_no_corrections_where_no_superquadric_grazes_the_outline(household):
    # a table under 1 degree of pose noise: the cameras disagree, but 3H's fit of the whole table
    # (cost above 3T's trigger) bends the cameras towards itself; its corrections are not handed on
    _, observations = household("table", 0, 0, pose_rotation_deg=1.0)
    obs = ObservationSet(observations)
    state = through_3h(obs, sqfit.FitOptions())
    assert "pose prior scaled" in state.message and state.cost > TRIGGER_COST
    assert state.camera_corrections is None


def test_3r_refits_on_the_pose_corrected_cameras_too(household):
    # a bottle under 1 degree of pose noise: 3H grazes its outline on cameras turned by its
    # corrections, and 3R's trimmed re-fit on those cameras follows the body better than on the given
    # ones, where it fits the views' disagreement too (seed 0, trial 5: 0.77 -> 0.87 in the chain)
    gt, observations = household("bottle", 0, 5, pose_rotation_deg=1.0)
    obs, options = ObservationSet(observations), sqfit.FitOptions()
    state = through_3h(obs, options)
    assert state.camera_corrections is not None
    both = STAGES["3R"](state, obs, options)
    given = STAGES["3R"](replace(state, camera_corrections=None), obs, options)
    assert "on the pose-corrected cameras: kept it; not truncated cost" in both.message
    assert "pose-corrected" not in given.message
    assert np.array_equal(both.camera_corrections, state.camera_corrections)
    gained = iou_3d_mesh(to_superquadric(both.xi), gt.mesh) - iou_3d_mesh(to_superquadric(given.xi), gt.mesh)
    assert gained > 0.05


def test_3r_keeps_the_given_cameras_where_they_explain_the_outline(scene_trial):
    # clean masks of a cylinder: 3H's fit of trial 0 of scenes/cylinders.toml lands in a wrong basin
    # (0.79) whose misfit its corrections absorb (the cameras "disagree", 0.4-0.9 degrees); on the
    # given cameras 3R's re-fit from a cylinder start grazes the outline (0.99), and is kept over
    # the one on the turned cameras (0.84)
    gt, observations = scene_trial("cylinders", 0)
    obs, options = ObservationSet(observations), sqfit.FitOptions()
    state = through_3h(obs, options)
    assert state.camera_corrections is not None
    new = STAGES["3R"](state, obs, options)
    assert ": kept it; not truncated cost" in new.message
    assert "on the pose-corrected cameras: kept it" not in new.message
    assert new.camera_corrections is None
    assert iou_3d_mesh(to_superquadric(new.xi), gt.mesh) > 0.95


def test_3r_leaves_small_corrections_alone(household):
    # a clean mug (seed 0, trial 2): 3H's fit turns a little towards the handle and its corrections
    # (0.2 degrees RMS) absorb that; they are handed on, but below TURN_MIN_DEG 3R does not re-fit on
    # the turned cameras (a second run for nothing on most clean mugs)
    _, observations = household("mug", 0, 2)
    obs, options = ObservationSet(observations), sqfit.FitOptions()
    state = through_3h(obs, options)
    assert state.camera_corrections is not None
    assert pose_noise_estimate(state.camera_corrections.ravel()) < TURN_MIN_DEG
    new = STAGES["3R"](state, obs, options)
    assert "pose-corrected" not in new.message
    same = STAGES["3R"](replace(state, camera_corrections=None), obs, options)
    assert np.array_equal(new.xi, same.xi) and new.message == same.message
