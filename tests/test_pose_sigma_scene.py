"""The scene key ``fit.pose_sigma_deg`` (stage 3G pose refinement) and its link to FitOptions."""

from pathlib import Path

import pytest

import sqfit
from sqsim.world.scene import load_scene

PAPER = Path(__file__).resolve().parents[1] / "scenes" / "paper.toml"


def test_scene_default_is_the_fit_option_default():
    assert load_scene(PAPER).fit.pose_sigma_deg == sqfit.FitOptions().pose_sigma_deg > 0


def test_scene_key_overrides():
    assert load_scene(PAPER).with_overrides({"fit.pose_sigma_deg": 0.0}).fit.pose_sigma_deg == 0.0


def test_scene_key_validation():
    with pytest.raises(ValueError, match=r"fit.pose_sigma_deg must be >= 0, got -1.0"):
        load_scene(PAPER).with_overrides({"fit.pose_sigma_deg": -1.0})
