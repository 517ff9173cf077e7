"""The silhouette stages' size floor ``FitOptions.size_min_m`` (default the paper's 0.1 m)."""
import numpy as np
import pytest

import sqfit
from sqfit import constants as C
from sqfit.fitting.raycost import RAY_BOUNDS, ray_bounds
from sqfit.metrics import iou_3d
from sqfit.testing import paper_cameras, polygon_mask

# A book-like slab: half-thickness 0.07 m, below the paper's floor, seen by four elevated views.
SLAB = sqfit.Superquadric((0.07, 0.7, 1.0), (0.1, 0.1), (0.3, -0.2, 0.1), (0.3, -0.4, 0.8))


@pytest.fixture(scope="module")
def slab_observations():
    rng = np.random.default_rng(0)
    cams = paper_cameras(4, height=4.0)
    return [sqfit.Observation.from_mask(cam, polygon_mask(SLAB, cam), 100, "uniform", rng) for cam in cams]


def test_ray_bounds_sets_the_size_floor_only():
    lower, upper = ray_bounds(0.01)
    np.testing.assert_array_equal(lower[C.SIZE], 0.01)
    np.testing.assert_array_equal(lower[3:], RAY_BOUNDS[0][3:])
    assert upper is RAY_BOUNDS[1]
    assert ray_bounds(C.SIZE_MIN) is RAY_BOUNDS


def test_ray_bounds_sets_the_shape_floor_on_request():
    lower, upper = ray_bounds(C.SIZE_MIN, shape_min=0.011)
    np.testing.assert_array_equal(lower[C.SHAPE], 0.011)
    np.testing.assert_array_equal(np.delete(lower, [3, 4]), np.delete(RAY_BOUNDS[0], [3, 4]))
    assert RAY_BOUNDS[0][3] == C.SILHOUETTE_SHAPE_BOUNDS[0]  # a copy
    lower, _ = ray_bounds(0.01, shape_min=0.011)
    np.testing.assert_array_equal(lower[C.SIZE], 0.01)
    assert ray_bounds(C.SIZE_MIN, shape_min=C.SILHOUETTE_SHAPE_BOUNDS[0]) is RAY_BOUNDS


@pytest.mark.parametrize("value", [0.0, -0.1, np.nan, np.inf])
def test_size_floor_must_be_positive(value):
    with pytest.raises(ValueError, match="size_min_m must be a finite number > 0"):
        sqfit.FitOptions(size_min_m=value)
    with pytest.raises(ValueError, match="size_min must be a finite number > 0"):
        ray_bounds(value)


def test_a_thin_box_goes_below_the_default_floor_and_a_lower_floor_fits_it_closer(slab_observations, monkeypatch):
    from sqfit.fitting import plain_run

    default = sqfit.fit(slab_observations, "default")
    free = sqfit.fit(slab_observations, "default", options={"size_min_m": 0.01})
    monkeypatch.setattr(plain_run, "below_floor_fit", lambda rays, xi, options: None)
    held = sqfit.fit(slab_observations, "default")
    assert min(held.superquadric.size) > 0.095  # without 3H's box below the floor: held, rounded (IoU 0.74)
    assert min(default.superquadric.size) < 0.085  # 3H's plain run: a box below the floor (IoU 0.89)
    assert abs(min(free.superquadric.size) - 0.07) < 0.01  # every stage under a 0.01 m floor (IoU 0.96)
    assert iou_3d(default.superquadric, SLAB) > iou_3d(held.superquadric, SLAB) + 0.1
    assert iou_3d(free.superquadric, SLAB) > iou_3d(default.superquadric, SLAB) + 0.03


def test_scene_key_defaults_to_the_option_and_reaches_the_fit(monkeypatch):
    from pathlib import Path

    from sqfit.fitting import plain_run

    from sqsim.runs.experiment import fit_trial
    from sqsim.world.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "paper.toml")
    assert scene.fit.size_min_m == sqfit.FitOptions().size_min_m == C.SIZE_MIN
    with pytest.raises(ValueError, match=r"fit.size_min_m must be > 0"):
        scene.with_overrides({"fit.size_min_m": 0.0})
    # household books, seed 0, trial 18: half-thickness 0.061 m
    books = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "household.toml").with_overrides(
        {"experiment.limit": False, "experiment.seed": 0, "objects.catalogue": ["book"]})
    def thinnest(floor):
        return min(fit_trial(books.with_overrides({"fit.size_min_m": floor}).to_dict(), 18, ["default"])[0]["params"][:3])

    assert thinnest(C.SIZE_MIN) < 0.075  # a box: 3H's plain run goes below the floor
    monkeypatch.setattr(plain_run, "below_floor_fit", lambda rays, xi, options: None)
    assert thinnest(C.SIZE_MIN) > 0.095 and thinnest(0.01) < 0.075  # the key sets the floor of every stage


def test_stage_3s_scores_its_candidates_under_the_same_floor(slab_observations):
    # 3S compares misfits whose penalty rows must be those its 3G fits ran under: the true slab
    # pays the 0.1 m floor's penalty at the default bounds, none at a 0.01 m floor
    from sqfit.fitting.costs import ObservationSet
    from sqfit.fitting.restarts import misfit, screen_rays

    rays = screen_rays(ObservationSet(slab_observations))
    xi = SLAB.to_vector()
    assert misfit(xi, rays, bounds=ray_bounds(0.01)) < 0.2 * misfit(xi, rays)
    assert misfit(xi, rays, bounds=RAY_BOUNDS) == misfit(xi, rays)
