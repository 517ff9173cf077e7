"""Synthetic sequences with known answers for the factor graph, without OpenGL (tests, benchmarks).

:func:`synthetic_sequence`: a camera on a horizontal arc of radius ``radius`` m at height
``height`` m, looking at a point ``LOOK_AT_HEIGHT`` m above the origin, ``n_frames`` frames evenly
over ``arc_deg`` degrees; ``n_objects`` superquadrics standing on the floor (``z = 0``) within
``spread`` m of the origin, at least ``MIN_GAP`` m apart (bounding spheres), size ``a`` in
``SIZE_RANGE`` m, shape ``e`` in ``SHAPE_RANGE``, yaw uniform. Each object's mask in each frame is
its exact silhouette polygon rasterised by pixel centre (:func:`sqfit.testing.polygon_mask`) at the
true pose; objects do not hide each other (each mask is the whole silhouette) and views whose mask
touches the image border or is smaller than ``min_area_px`` are left out (truncation is the
partial-visibility issue's). Odometry: the true frame-to-frame motions, each composed with a
seeded random perturbation ``Exp([omega, v])`` (``omega ~ N(0, odometry_sigma_deg)`` per axis,
``v ~ N(0, odometry_sigma_m)``), integrated from the true first pose.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import Camera, Intrinsics, look_at
from ..metrics import iou_3d
from ..views.observation import Observation
from ..geometry.superquadric import Superquadric
from ..testing import polygon_mask

__all__ = ["SEQUENCE_INTRINSICS", "Sequence", "synthetic_sequence", "position_rmse", "scale_free_rmse",
           "trajectory_scale", "scaled_objects", "scale_aligned_objects", "odometry_scale", "odometry_scale_rmse",
           "odometry_scale_ious", "object_ious"]

SEQUENCE_INTRINSICS = Intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
LOOK_AT_HEIGHT = 0.4  #: metres
SIZE_RANGE = (0.2, 0.6)  #: metres
SHAPE_RANGE = (0.3, 1.6)
MIN_GAP = 0.2  #: metres between bounding spheres


@dataclass
class Sequence:
    """A synthetic sequence: what a sequence reader gives, plus the truth."""

    intrinsics: Intrinsics
    true_poses: np.ndarray
    odometry_poses: np.ndarray
    objects: dict
    observations: dict


def _objects(rng, n_objects, spread):
    objects, spheres = {}, []
    while len(objects) < n_objects:
        a = rng.uniform(*SIZE_RANGE, 3)
        centre = np.array([*rng.uniform(-spread, spread, 2), a[2]])
        radius = np.linalg.norm(a)
        if any(np.linalg.norm(centre - c) < radius + r + MIN_GAP for c, r in spheres):
            continue
        spheres.append((centre, radius))
        objects[len(objects) + 1] = Superquadric(a, rng.uniform(*SHAPE_RANGE, 2), centre,
                                                 (0.0, 0.0, rng.uniform(-np.pi, np.pi)))
    return objects


def _perturb(rng, sigma_deg, sigma_m):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, np.radians(sigma_deg), 3)).as_matrix()
    T[:3, 3] = rng.normal(0.0, sigma_m, 3)
    return T


def synthetic_sequence(seed, n_frames=40, n_objects=6, *, arc_deg=120.0, radius=5.0, height=1.6, spread=1.6,
                       odometry_sigma_deg=0.5, odometry_sigma_m=0.005, intrinsics=SEQUENCE_INTRINSICS,
                       min_area_px=150, n_samples=100):
    """A seeded synthetic sequence (module docstring); returns a :class:`Sequence`."""
    rng = np.random.default_rng(seed)
    objects = _objects(rng, n_objects, spread)
    angles = np.radians(np.linspace(0.0, arc_deg, n_frames)) + rng.uniform(0, 2 * np.pi)
    true = np.stack([look_at([radius * np.cos(t), radius * np.sin(t), height], [0.0, 0.0, LOOK_AT_HEIGHT])
                     for t in angles])
    odo = [true[0]]
    for i in range(1, n_frames):
        step = np.linalg.inv(true[i - 1]) @ true[i] @ _perturb(rng, odometry_sigma_deg, odometry_sigma_m)
        odo.append(odo[-1] @ step)
    observations = {}
    for i, T in enumerate(true):
        cam = Camera(intrinsics, T)
        for oid, sq in objects.items():
            mask = polygon_mask(sq, cam)
            if mask is None or mask.sum() < min_area_px or _touches_border(mask):
                continue
            observations[i, oid] = Observation.from_mask(Camera(intrinsics, odo[i]), mask, n_samples, rng=rng)
    return Sequence(intrinsics, true, np.stack(odo), objects, observations)


def _touches_border(mask):
    return bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def position_rmse(poses, true_poses):
    """RMS of the camera-centre errors, metres, without alignment (both trajectories share frame 0)."""
    return float(np.sqrt(np.mean(np.sum((poses[:, :3, 3] - true_poses[:, :3, 3]) ** 2, axis=1))))


def _scaled_about_first(poses, s):
    out = np.array(poses, dtype=np.float64)
    out[:, :3, 3] = out[0, :3, 3] + s * (out[:, :3, 3] - out[0, :3, 3])
    return out


def trajectory_scale(poses, true_poses):
    """The least-squares factor ``s`` that scales ``poses``' camera centres about their first one
    onto ``true_poses``' (both trajectories start at the same pose): ``s > 1`` when ``poses`` is
    too small."""
    p, q = poses[:, :3, 3] - poses[0, :3, 3], true_poses[:, :3, 3] - true_poses[0, :3, 3]
    return float(np.sum(p * q) / max(np.sum(p * p), 1e-300))


def scale_free_rmse(poses, true_poses):
    """:func:`position_rmse` after the least-squares scale of ``poses`` about their first camera
    centre (:func:`trajectory_scale`): the error of the trajectory's shape (silhouettes are
    scale-free; the scale comes from the odometry alone)."""
    return position_rmse(_scaled_about_first(poses, trajectory_scale(poses, true_poses)), true_poses)


def scaled_objects(objects, centre, s):
    """``objects`` (``{id: Superquadric}``) with positions scaled by ``s`` about ``centre`` ``(3,)``
    and sizes by ``s`` (rotations and shapes unchanged): a map moved along the scale direction."""
    centre = np.asarray(centre, dtype=np.float64)
    return {oid: replace(sq, size=tuple(s * np.asarray(sq.size)),
                         position=tuple(centre + s * (np.asarray(sq.position) - centre)))
            for oid, sq in objects.items()}


def scale_aligned_objects(objects, poses, true_poses):
    """``objects`` scaled about ``poses``' first camera centre by :func:`trajectory_scale`: the map
    as it would be had the trajectory the true scale. Their IoU against the truth is what the map
    loses to everything but the scale, which no silhouette measures."""
    return scaled_objects(objects, poses[0, :3, 3], trajectory_scale(poses, true_poses))


def odometry_scale(odometry_poses, true_poses):
    """The odometry's own scale error: the least-squares factor of the measured steps' translations
    along the true ones, each in its first frame (> 1: the steps are too long)."""
    true_poses, odometry_poses = np.asarray(true_poses, dtype=np.float64), np.asarray(odometry_poses, dtype=np.float64)
    steps = np.array([(np.linalg.inv(a) @ b)[:3, 3] for a, b in zip(true_poses[:-1], true_poses[1:])])
    measured = np.array([(np.linalg.inv(a) @ b)[:3, 3] for a, b in zip(odometry_poses[:-1], odometry_poses[1:])])
    return float(np.sum(steps * measured) / max(np.sum(steps * steps), 1e-300))


def odometry_scale_rmse(odometry_poses, true_poses):
    """:func:`position_rmse` of the true trajectory scaled about its first camera centre by the
    odometry's own scale error (:func:`odometry_scale`): what a method that gets all but the scale
    right, and takes the scale from the odometry (nothing else in the graph measures it), scores."""
    true_poses = np.asarray(true_poses, dtype=np.float64)
    return position_rmse(_scaled_about_first(true_poses, odometry_scale(odometry_poses, true_poses)), true_poses)


def odometry_scale_ious(odometry_poses, true_poses, true_objects):
    """``{id: 3D IoU}`` of the true objects scaled about the first true camera centre by the
    odometry's scale error (:func:`odometry_scale`) against themselves: the object IoU of a method
    whose map is perfect but for the scale, which it takes from the odometry."""
    true_poses = np.asarray(true_poses, dtype=np.float64)
    moved = scaled_objects(true_objects, true_poses[0, :3, 3], odometry_scale(odometry_poses, true_poses))
    return object_ious(moved, true_objects)


def object_ious(objects, true_objects):
    """``{id: 3D IoU}`` of the fitted objects against the truth (0 for a missing object)."""
    return {oid: (iou_3d(objects[oid], sq) if oid in objects else 0.0) for oid, sq in true_objects.items()}
