"""Synthetic problems with known answers, without OpenGL (tests, benchmarks, examples).

:func:`paper_trial` reproduces the paper's permutation experiment (Table I): a random superquadric
with ``a`` in [0.1, 5] m, ``p`` in [-5, 5] m, Euler angles in [-pi, pi], ``e`` in [0.1, 1.9]; three
cameras on a horizontal circle of radius 10 m at height 0 looking at the origin, 640 x 480 px,
``fx = 400``, ``fy = 300``, ``cx = 320``, ``cy = 240``. Masks are the exact silhouette polygon
(:func:`sqfit.silhouette.silhouette` with 256 vertices) rasterised by pixel centre: pixel
``(i, j)`` is inside iff ``(j + 0.5, i + 0.5)`` is in the polygon. Draws whose mask touches the
border, that are behind or around a camera, or smaller than ``min_area_px`` are re-sampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera, Intrinsics, look_at
from .observation import Observation
from .raster import fill_convex_polygon
from .silhouette import silhouette
from .superquadric import Superquadric

__all__ = ["PAPER_INTRINSICS", "paper_cameras", "random_superquadric", "polygon_mask", "Trial", "paper_trial"]

PAPER_INTRINSICS = Intrinsics(640, 480, 400.0, 300.0, 320.0, 240.0)


def paper_cameras(views=3, radius=10.0, height=0.0, intrinsics=PAPER_INTRINSICS):
    """``views`` cameras evenly spread on a horizontal circle, looking at the origin."""
    angles = 2.0 * np.pi * np.arange(views) / views
    return [Camera(intrinsics, look_at([radius * np.cos(t), radius * np.sin(t), height], [0.0, 0.0, 0.0]))
            for t in angles]


def random_superquadric(rng):
    """A superquadric drawn from the paper's ranges (Table I)."""
    rng = np.random.default_rng(rng)
    return Superquadric(rng.uniform(0.1, 5.0, 3), rng.uniform(0.1, 1.9, 2), rng.uniform(-5.0, 5.0, 3),
                        rng.uniform(-np.pi, np.pi, 3))


def polygon_mask(sq, camera, n_directions=256):
    """``(h, w) bool`` mask of the superquadric's silhouette, by pixel centre; None if behind the camera."""
    poly = silhouette(sq, camera, n_directions)
    if len(poly) == 0:
        return None
    k = camera.intrinsics
    return fill_convex_polygon(poly, (k.height, k.width))


@dataclass
class Trial:
    """A ground truth, its cameras and observations."""

    gt: Superquadric
    cameras: list
    masks: list
    observations: list
    resampled: int


def paper_trial(seed, n_samples=100, sampling="uniform", min_area_px=200, views=3):
    """A seeded trial of the paper's permutation experiment (see the module docstring)."""
    rng = np.random.default_rng(seed)
    cams = paper_cameras(views)
    resampled = 0
    while True:
        sq = random_superquadric(rng)
        masks = [polygon_mask(sq, cam) for cam in cams]
        if all(m is not None and _observable(m, min_area_px) for m in masks):
            break
        resampled += 1
    obs = [Observation.from_mask(cam, m, n_samples, sampling, rng) for cam, m in zip(cams, masks)]
    return Trial(sq, cams, masks, obs, resampled)


def _observable(mask, min_area_px):
    if mask.sum() < min_area_px:
        return False
    return not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())

