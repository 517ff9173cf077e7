"""sqfit.views.consistency: the masks' epipolar tangents agree under the right cameras, not under a turned one."""

from dataclasses import replace

import numpy as np
import pytest

from sqfit.geometry.camera import Camera
from sqfit.geometry.superquadric import Superquadric
from sqfit.testing import paper_cameras, paper_trial, polygon_mask
from sqfit.views.consistency import tangent_disagreement
from sqfit.views.observation import Observation

from _helpers import turned_pose


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_masks_agree_to_about_half_a_pixel(seed):
    disagreement = tangent_disagreement(paper_trial(seed).observations)
    assert disagreement.shape == (3, 3) and np.isnan(np.diag(disagreement)).all()
    assert np.isfinite(disagreement).sum() >= 2
    assert np.nanmax(disagreement) < 1.0


def test_a_camera_turned_by_one_degree_disagrees_by_pixels():
    trial = paper_trial(0)
    obs = list(trial.observations)
    panned = turned_pose(obs[1].camera.pose, np.radians([0.0, 1.0, 0.0]))  # 1 deg about the camera's y axis
    obs[1] = replace(obs[1], camera=Camera(obs[1].camera.intrinsics, panned))  # the mask stays: the pose is wrong
    disagreement = tangent_disagreement(obs)
    # 1 deg at fx = 400 px is about 7 px
    assert np.nanmax(disagreement[1]) > 3.0 and np.nanmax(disagreement[:, 1]) > 3.0
    if np.isfinite(disagreement[0, 2]):
        assert disagreement[0, 2] < 1.0


def test_a_pair_whose_baseline_passes_through_the_object_is_left_out():
    sq = Superquadric([1.0, 1.0, 1.0], [1.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    cameras = paper_cameras(2)  # facing each other across the object
    obs = [Observation.from_mask(camera, polygon_mask(sq, camera), 50, "uniform", 0) for camera in cameras]
    assert np.isnan(tangent_disagreement(obs)).all()
