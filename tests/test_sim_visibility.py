"""Simulated partial visibility: truncated objects, visible fractions, scenes of issue 12."""

from pathlib import Path

import numpy as np
import pytest

from sqsim.world.objects import ZNEAR, geometry_visible, make_object
from sqsim.world.scene import load_scene, parse_scene
from sqsim.imaging.trial import observations, sample_trial, simulate_trial
from sqsim.world.objects import cut_fractions

from _datasets import small_parsed_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
def small(**sections):
    """A small scene rendered with polygons (no OpenGL)."""
    return small_parsed_scene(**{**sections, "masks": {"renderer": "polygon", **sections.get("masks", {})}})


def test_cut_fractions_and_geometry_with_truncation():
    cams = parse_scene({}).cameras()
    centre = make_object(1, "superquadric", (0.5, 0.5, 0.5), (1, 1), (0, 0, 0), (0, 0, 0))
    # 10 m away with fx = 400, the image's half width is 8 m: a 1 m sphere at y = 8 m is cut in half
    # in the camera on +x.
    edge = make_object(1, "superquadric", (1.0, 1.0, 1.0), (1, 1), (0, 8.0, 0), (0, 0, 0))
    cut = cut_fractions([centre, edge], cams, ZNEAR)
    assert cut.shape == (2, 3) and np.all(cut[0] == 0.0)
    assert cut[1, 0] == pytest.approx(0.5, abs=0.05)
    assert not geometry_visible([edge], cams[:1])
    assert geometry_visible([edge], cams[:1], max_cut_fraction=0.6)
    assert not geometry_visible([edge], cams[:1], max_cut_fraction=0.3)
    around_camera = make_object(1, "superquadric", (0.5, 0.5, 0.5), (1, 1), (10, 0, 0), (0, 0, 0))
    assert np.isinf(cut_fractions([around_camera], cams, ZNEAR)).any()
    assert not geometry_visible([around_camera], cams, max_cut_fraction=0.9)


def test_truncated_trials_touch_the_border_and_keep_min_area():
    s = small(masks={"max_cut_fraction": 0.6}, objects={"position": [-7.0, 7.0]})
    touched = 0
    for i in range(6):
        objects, cams, images, _ = sample_trial(s, i)
        mask = images == 1
        assert np.all(mask.sum(axis=(1, 2)) >= s.masks.min_area_px)
        touched += sum(m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any() for m in mask)
    assert touched > 0


def test_simulated_visibility_records():
    s = small(objects={"count": 4, "position": [-1.0, 1.0]}, masks={"max_cut_fraction": 0.3})
    sim = simulate_trial(s, 1)
    assert sim.visible_fraction.shape == (4, 3) == sim.cut_fraction.shape == sim.border_cut.shape
    assert np.all((sim.visible_fraction >= 0) & (sim.visible_fraction <= 1))
    assert sim.visible_fraction.min() < 1.0  # four objects in a 2 m cube hide each other
    for k, obj in enumerate(sim.objects):
        for v, image in enumerate(sim.clean_images):
            m = image == obj.id
            assert sim.border_cut[k, v] == bool(m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
    # Observations carry instance labels where another object borders the mask.
    labelled = [observations(sim, o.id, s) for o in sim.objects]
    assert any(ob.partial for obs in labelled for ob in obs)


def test_experiment_records_visibility(tmp_path):
    import json

    from sqsim.runs.experiment import run_experiment

    s = small(objects={"count": 2}, experiment={"trials": 1, "chains": ["1-2-3G"]})
    run_experiment(s, tmp_path / "run", progress=False)
    records = [json.loads(line) for line in (tmp_path / "run" / "trials.jsonl").read_text().splitlines()]
    assert len(records) == 2
    for r in records:
        assert len(r["visible_fraction"]) == 3 and len(r["cut_fraction"]) == 3 and len(r["border_cut"]) == 3


@pytest.mark.parametrize("name", ["occlusion", "occlusion-single", "truncation", "occlusion-sweep",
                                  "truncation-sweep"])
def test_issue_scenes_load(name):
    from sqsim.runs.sweep import load_sweep

    if name.endswith("sweep"):
        scene, axes = load_sweep(ROOT / "scenes" / f"{name}.toml")
        assert len(axes) == 2
        for key, values in axes:
            for v in values:
                scene.with_overrides({key: v})
    else:
        scene = load_scene(ROOT / "scenes" / f"{name}.toml")
        assert scene.objects.count == {"occlusion": 4, "occlusion-single": 1, "truncation": 1}[name]
