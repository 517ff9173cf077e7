"""One simulated trial: sampled ground truth, rendered instance images, mask and pose noise.

Everything in a trial derives from ``trial_seed(scene.experiment.seed, index)`` through fixed
children (:data:`SEED_STREAMS`), so a trial's result depends only on the scene and its index:

- child 0: object sampling (and its re-draws),
- child 1: mask noise,
- child 2: pose noise,
- child 3: observation samples (:func:`observations`, child ``3`` then the object id).

Each trial also records how much of each object is seen (:func:`sqsim.imaging.visibility.visibility`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sqfit.views.dataset import observations_from_images

from .noise import corrupt_image, corrupts_masks, perturb_cameras
from .render import get_renderer
from ..world.objects import draw_objects, geometry_visible, make_objects, surely_not_visible
from ..world.scene import child_seed, trial_seed
from .visibility import pixel_counts, visibility

__all__ = ["SimulatedTrial", "simulate_trial", "sample_trial", "observations", "SEED_STREAMS"]

SEED_STREAMS = {"objects": 0, "mask_noise": 1, "pose_noise": 2, "samples": 3}


@dataclass(frozen=True, eq=False)
class SimulatedTrial:
    """A rendered trial.

    Attributes
    ----------
    index : int
    objects : list of sqsim.world.objects.SceneObject
        Ground truth, ids ``1 .. count``.
    true_cameras : list of sqfit.Camera
        Poses the masks were rendered from.
    cameras : list of sqfit.Camera
        Poses the fitter sees (``true_cameras`` with pose noise).
    clean_images : (v, h, w) uint16
        Rendered instance ids.
    images : (v, h, w) uint16
        After mask noise.
    resampled : int
        Draws rejected as unobservable before this one.
    visible_fraction : (count, v) float
        Per object and view: pixels seen / pixels rendered alone (:mod:`sqsim.imaging.visibility`).
    cut_fraction : (count, v) float
        Per object and view: projected area outside the image.
    border_cut : (count, v) bool
        Per object and view: the clean mask touches the image border.
    """

    index: int
    objects: list
    true_cameras: list
    cameras: list
    clean_images: np.ndarray
    images: np.ndarray
    resampled: int
    visible_fraction: np.ndarray | None = None
    cut_fraction: np.ndarray | None = None
    border_cut: np.ndarray | None = None


def sample_trial(scene, index, renderer=None):
    """Draw an observable set of objects for a trial and render it without noise.

    Returns
    -------
    objects : list of SceneObject
    cameras : list of sqfit.Camera
        True cameras.
    clean_images : (v, h, w) uint16
    resampled : int

    Raises
    ------
    ValueError
        No observable draw in ``objects.max_attempts`` attempts (the scene is impossible).
    """
    if scene.trajectory.kind != "circle":
        raise ValueError(f"{scene.source}: trajectory.kind = {scene.trajectory.kind!r} is an image sequence; "
                         "multi-view trials need kind = \"circle\" (sequences: sqsim.imaging.sequence, sqsim generate)")
    if renderer is None:
        renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    rng = np.random.default_rng(child_seed(trial_seed(scene.experiment.seed, index), SEED_STREAMS["objects"]))
    cameras = scene.cameras()
    min_area = max(scene.masks.min_area_px, 1)
    for attempt in range(scene.objects.max_attempts):
        draws = draw_objects(scene.objects, rng)
        # The anchor pre-check rejects anything reaching past the border: only for uncut scenes.
        if scene.masks.max_cut_fraction == 0 and surely_not_visible(scene.objects, draws, cameras):
            continue  # most re-draws end here, unmeshed
        objects = make_objects(scene.objects, draws)
        if not geometry_visible(objects, cameras, scene.masks.max_cut_fraction):
            continue
        images = renderer.render(objects, cameras)
        ids = np.array([o.id for o in objects])
        areas = pixel_counts(images, ids)
        if areas.min() >= min_area:
            return objects, cameras, images, attempt
    raise ValueError(f"{scene.source}: no observable trial in {scene.objects.max_attempts} draws "
                       "(objects too large or too far out for the cameras?); adjust [objects] or [trajectory]")


def simulate_trial(scene, index, renderer=None):
    """Sample, render and corrupt one trial.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
    index : int
        Trial index, >= 0.
    renderer : sqsim.imaging.render.Renderer, optional
        Default: ``get_renderer(scene.masks.renderer, scene.intrinsics)``.

    Returns
    -------
    trial : SimulatedTrial
    """
    seed = trial_seed(scene.experiment.seed, index)
    if renderer is None:
        renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    objects, true_cameras, clean, resampled = sample_trial(scene, index, renderer)
    visible, cut, border = visibility(objects, true_cameras, clean, renderer)
    noise = scene.noise
    mask_rng = np.random.default_rng(child_seed(seed, SEED_STREAMS["mask_noise"]))
    if corrupts_masks(noise):
        images = np.stack([corrupt_image(im, noise, mask_rng) for im in clean])
    else:
        images = clean  # both read-only below: no copy needed
    pose_rng = np.random.default_rng(child_seed(seed, SEED_STREAMS["pose_noise"]))
    cameras = perturb_cameras(true_cameras, noise.pose_rotation_deg, noise.pose_translation_m, pose_rng)
    for a in (clean, images):
        a.flags.writeable = False
    return SimulatedTrial(int(index), objects, true_cameras, cameras, clean, images, int(resampled),
                          visible, cut, border)


def observations(sim_trial, object_id, scene):
    """Observations of one object for the fitter: noisy masks, noisy cameras.

    Uses ``scene.masks.samples``, ``scene.masks.sampling`` and ``scene.masks.cleanup``, seeded from the trial seed and the
    object id; views where the object's noisy mask is empty are skipped.

    Returns
    -------
    observations : list of sqfit.Observation
        At least two.

    Raises
    ------
    ValueError
        Fewer than two views still show the object (e.g. after heavy erosion or occlusion).
    """
    seed = child_seed(child_seed(trial_seed(scene.experiment.seed, sim_trial.index), SEED_STREAMS["samples"]),
                      int(object_id))
    obs = observations_from_images(sim_trial.cameras, sim_trial.images, int(object_id),
                                   scene.masks.samples, scene.masks.sampling, np.random.default_rng(seed),
                                   cleanup=scene.masks.cleanup)
    if len(obs) < 2:
        raise ValueError(f"object {object_id} of trial {sim_trial.index} is visible in {len(obs)} view(s) "
                         "after mask noise; fitting needs at least 2")
    return obs
