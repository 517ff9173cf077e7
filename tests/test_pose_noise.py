"""Stage 3G/3H under camera rotation noise: the pose prior scaled to the residual noise once the
rotation corrections say that the cameras disagree (sqfit.fitting.grazing, sqfit.fitting.axis_screen)."""

import numpy as np
import pytest

import sqfit
from sqfit.fitting.costs import ObservationSet
from sqfit.fitting.grazing import (POSE_NOISE_TRIGGER_DEG, pose_noise_estimate, pose_prior_scale, silhouette_fit)
from sqfit.fitting.raycost import ray_residuals
from sqfit.fitting.stages import FitState
from sqfit.metrics import iou_3d
from sqfit.testing import paper_trial
from sqfit.views.rays import contour_rays
from _helpers import stage, turned_pose

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
