"""Simulated image sequences: a camera trajectory, many objects, drifting odometry, in memory.

:func:`simulate_sequence` is the in-memory path (the factor-graph harness calls it without writing
files); ``sqsim generate`` writes the same sequence to disk (``sqsim.data.sequence_dataset``) and
``sqfit.views.load_sequence`` reads it back with the same fields (``sqfit.views.sequence.Sequence``).

A sequence is drawn from ``trial_seed(seed, index)`` through fixed children
(:data:`SEED_STREAMS`; the numbers 0, 1 and 3 mean what they mean for multi-view trials,
``sqsim.imaging.trial``), so it depends only on the scene, the seed and the index:

- child 0: objects (layout, ``sqsim.world.layout``) and their re-draws,
- child 1: mask noise (``noise.erosion_px`` ..., per frame in order),
- child 4: odometry noise (``sqsim.world.odometry``).

Visibility: frame ``k`` observes object ``j`` when ``j`` covers at least ``max(min_area_px, 1)``
pixels of the rendered (noise-free) instance image. Objects cut by the image border or hidden in
part by others are kept; an object outside a frame, behind it or too small simply has no
observation there. A draw is re-done (counted in ``resampled``) when an object is observed in
fewer than :data:`MIN_OBSERVATIONS` frames, or when a camera centre lies inside an object's
bounding sphere (centre, radius ``|a|``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import sqfit
from sqfit.views.sequence import Sequence

from ..world.layout import place_objects
from ..world.odometry import integrate_odometry
from .noise import corrupt_image, corrupts_masks
from .render import get_renderer
from ..world.scene import child_seed, trial_seed
from ..world.trajectory import is_sequence, sequence_poses

__all__ = ["SimulatedSequence", "simulate_sequence", "sample_sequence", "observed_objects", "cameras_clear",
           "SEED_STREAMS", "MIN_OBSERVATIONS"]

SEED_STREAMS = {"objects": 0, "mask_noise": 1, "odometry": 4}
#: Frames that must observe every object of a sequence (else the draw is re-done).
MIN_OBSERVATIONS = 2


@dataclass(frozen=True, eq=False)
class SimulatedSequence(Sequence):
    """A :class:`sqfit.views.sequence.Sequence` plus the simulator's ground truth.

    Extra attributes
    ----------------
    index : int
        Sequence (trial) index.
    seed : int
    scene_objects : list of sqsim.world.objects.SceneObject
        Ground truth with meshes, ids ``1 .. count``.
    clean_images : (n, h, w) uint16
        Rendered instance ids before mask noise (``images`` is after it).
    resampled : int
        Draws rejected before this one.
    """

    index: int = 0
    seed: int = 0
    scene_objects: list = None
    clean_images: np.ndarray = None
    resampled: int = 0


def observed_objects(images, ids, min_area_px):
    """Which objects each frame observes.

    Parameters
    ----------
    images : (n, h, w) uint16
        Instance ids.
    ids : (m,) int
    min_area_px : int
        Fewer visible pixels than ``max(min_area_px, 1)`` is no observation.

    Returns
    -------
    observed : (n, m) bool
    areas : (n, m) int
        Visible pixels per frame and object.
    """
    ids = np.asarray(ids, dtype=np.int64)
    images = np.asarray(images)
    top = int(max(ids.max(initial=0), images.max(initial=0))) + 1
    areas = np.array([np.bincount(image.ravel(), minlength=top)[ids] for image in images],
                     dtype=np.int64).reshape(len(images), len(ids))
    return areas >= max(int(min_area_px), 1), areas


def cameras_clear(objects, poses):
    """Whether every camera centre lies outside every object's bounding sphere (radius ``|a|``).

    Parameters
    ----------
    objects : list of sqsim.world.objects.SceneObject
    poses : (n, 4, 4) float

    Returns
    -------
    ok : bool
    """
    centres = np.asarray(poses)[:, :3, 3]
    for obj in objects:
        if np.linalg.norm(centres - np.asarray(obj.position), axis=1).min() <= np.linalg.norm(obj.size):
            return False
    return True


def sample_sequence(scene, seed=None, index=0, renderer=None):
    """Draw objects every one of which the sequence observes in >= 2 frames, and render them.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
        A sequence scene (``trajectory.kind`` ``"orbit"`` or ``"waypoints"``).
    seed : int, optional
        Default ``scene.experiment.seed``.
    index : int
    renderer : sqsim.imaging.render.Renderer, optional

    Returns
    -------
    objects : list of SceneObject
    timestamps : (n,) float
    true_poses : (n, 4, 4) float
    clean_images : (n, h, w) uint16
    observed : (n, m) bool
    resampled : int

    Raises
    ------
    ValueError
        Not a sequence scene, or no acceptable draw in ``objects.max_attempts`` attempts.
    """
    if not is_sequence(scene):
        raise ValueError(f"{scene.source}: trajectory.kind = {scene.trajectory.kind!r} is not a sequence "
                         "(use \"orbit\" or \"waypoints\"); multi-view trials come from sqsim.imaging.trial")
    seed = scene.experiment.seed if seed is None else seed
    if renderer is None:
        renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    rng = np.random.default_rng(child_seed(trial_seed(seed, index), SEED_STREAMS["objects"]))
    timestamps, poses = sequence_poses(scene.trajectory)
    cameras = [sqfit.Camera(scene.intrinsics, T) for T in poses]
    ids = np.arange(1, scene.objects.count + 1)
    for attempt in range(scene.objects.max_attempts):
        objects = place_objects(scene.objects, rng)
        if objects is None or not cameras_clear(objects, poses):
            continue
        images = renderer.render(objects, cameras)
        observed, _ = observed_objects(images, ids, scene.masks.min_area_px)
        if observed.sum(axis=0).min() >= MIN_OBSERVATIONS:
            return objects, timestamps, poses, images, observed, attempt
    raise ValueError(f"{scene.source}: no draw in {scene.objects.max_attempts} attempts where every object is "
                     f"observed in >= {MIN_OBSERVATIONS} frames (objects outside the trajectory's view, too small "
                     "for masks.min_area_px, or not fitting on the floor?); adjust [objects] or [trajectory]")


def simulate_sequence(scene, seed=None, index=0, renderer=None):
    """Simulate one sequence in memory: objects, true trajectory, images, mask noise, odometry.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
        A sequence scene.
    seed : int, optional
        Default ``scene.experiment.seed``; sequence ``index`` of ``seed`` is trial ``index`` of a
        dataset generated with that seed.
    index : int
    renderer : sqsim.imaging.render.Renderer, optional

    Returns
    -------
    sequence : SimulatedSequence
    """
    seed = scene.experiment.seed if seed is None else int(seed)
    objects, timestamps, true_poses, clean, observed, resampled = sample_sequence(scene, seed, index, renderer)
    root = trial_seed(seed, index)
    noise = scene.noise
    if corrupts_masks(noise):
        mask_rng = np.random.default_rng(child_seed(root, SEED_STREAMS["mask_noise"]))
        images = np.stack([corrupt_image(im, noise, mask_rng) for im in clean])
    else:
        images = clean.copy()
    odometry = integrate_odometry(true_poses, noise.odometry_rotation_deg, noise.odometry_translation_m,
                                  np.random.default_rng(child_seed(root, SEED_STREAMS["odometry"])))
    for a in (clean, images):
        a.flags.writeable = False
    return SimulatedSequence(
        timestamps=timestamps, intrinsics=scene.intrinsics, true_poses=true_poses, odometry_poses=odometry,
        images=images, objects={o.id: o.superquadric for o in objects}, object_ids=[o.id for o in objects],
        observed=observed, object_kinds={o.id: o.kind for o in objects},
        name=f"{scene.experiment.name}/seed{seed}/{int(index):06d}", index=int(index), seed=seed,
        scene_objects=list(objects), clean_images=clean, resampled=int(resampled))
