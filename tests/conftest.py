"""Shared fixtures."""

import tomllib
from pathlib import Path

import pytest

SCENES = Path(__file__).resolve().parents[1] / "scenes"


@pytest.fixture
def household():
    """``household(kind, seed, index, **noise)``: trial ``index`` of ``scenes/household.toml`` restricted to
    one kind (no limit search), with the ``[noise]`` keys ``noise`` given (e.g. ``pose_rotation_deg=1.0``):
    the object and its observations."""
    from sqsim.imaging.trial import observations, simulate_trial
    from sqsim.world.scene import parse_scene

    def trial(kind, seed, index, **noise):
        with open(SCENES / "household.toml", "rb") as f:
            d = tomllib.load(f)
        d["objects"]["catalogue"] = [kind]
        d["experiment"].update(seed=seed, limit=False)
        d["noise"].update(noise)
        scene = parse_scene(d, source=f"household {kind}")
        sim = simulate_trial(scene, index)
        return sim.objects[0], observations(sim, sim.objects[0].id, scene)

    return trial


@pytest.fixture
def paper_noisy(scene_trial):
    """``paper_noisy(index)``: trial ``index`` of ``scenes/paper-noisy.toml`` (seed 0, its renderer): the
    object and its observations."""
    return lambda index: scene_trial("paper-noisy", index)


@pytest.fixture
def scene_trial():
    """``scene_trial(name, index)``: trial ``index`` of ``scenes/NAME.toml`` as it is (its seed and
    renderer): the object and its observations."""
    from sqsim.imaging.render import get_renderer
    from sqsim.imaging.trial import observations, simulate_trial
    from sqsim.world.scene import load_scene

    def trial(name, index):
        scene = load_scene(SCENES / f"{name}.toml")
        sim = simulate_trial(scene, index, get_renderer(scene.masks.renderer, scene.intrinsics))
        return sim.objects[0], observations(sim, sim.objects[0].id, scene)

    return trial
