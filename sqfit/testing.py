"""Synthetic problems with known answers, without OpenGL (tests, benchmarks, examples).

:func:`paper_trial` reproduces the paper's permutation experiment (Table I): a random superquadric
with ``a`` in [0.1, 5] m, ``p`` in [-5, 5] m, Euler angles in [-pi, pi], ``e`` in [0.1, 1.9]; three
cameras on a horizontal circle of radius 10 m at height 0 looking at the origin, 640 x 480 px,
``fx = 400``, ``fy = 300``, ``cx = 320``, ``cy = 240``. Masks are the exact silhouette polygon
(:func:`sqfit.geometry.silhouette.silhouette` with 256 vertices) rasterised by pixel centre: pixel
``(i, j)`` is inside iff ``(j + 0.5, i + 0.5)`` is in the polygon. Draws whose mask touches the
border, that are behind or around a camera, or smaller than ``min_area_px`` are re-sampled.

:func:`truncated_trial` cuts such a trial by the image border: in the first ``cut_views`` views
the principal point is shifted along ``u`` (towards the side chosen by the seed) until the
fraction ``cut_fraction`` of the silhouette's area lies outside the image (bisection on the exact
silhouette polygon), and the masks and observations are made in the shifted cameras.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .geometry.camera import Camera, Intrinsics, look_at
from .views.observation import Observation
from .geometry.raster import fill_convex_polygon
from .geometry.polygon import polygon_area
from .geometry.silhouette import silhouette
from .geometry.superquadric import Superquadric

__all__ = ["PAPER_INTRINSICS", "paper_cameras", "random_superquadric", "polygon_mask", "Trial", "paper_trial",
           "truncated_trial"]

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



def truncated_trial(seed, cut_fraction=0.3, cut_views=1, n_samples=100, sampling="uniform", min_area_px=200,
                    views=3):
    """A :func:`paper_trial` with ``cut_fraction`` of the object's area outside the image in the first
    ``cut_views`` views (see the module docstring).

    Returns
    -------
    trial : Trial
        ``cameras`` are the shifted cameras the masks were made in.
    """
    if not 0.0 <= cut_fraction < 1.0:
        raise ValueError(f"cut_fraction must be in [0, 1), got {cut_fraction}")
    if int(cut_views) != cut_views or not 0 <= cut_views <= views:
        raise ValueError(f"cut_views must be an integer in [0, {views}], got {cut_views}")
    rng = np.random.default_rng(seed)
    base = paper_trial(rng, n_samples, sampling, min_area_px, views)
    cams = list(base.cameras)
    for i in range(int(cut_views)):
        cams[i] = _cut_camera(base.gt, cams[i], cut_fraction, rng.random() < 0.5)
    masks = [polygon_mask(base.gt, cam) for cam in cams]
    obs = [Observation.from_mask(cam, m, n_samples, sampling, rng) for cam, m in zip(cams, masks)]
    return Trial(base.gt, cams, masks, obs, base.resampled)


def _cut_camera(sq, camera, fraction, left):
    """``camera`` with ``cx`` shifted so that ``fraction`` of the silhouette area leaves the image."""
    k = camera.intrinsics
    poly = silhouette(sq, camera, 256)
    total = polygon_area(poly)
    edge = 0.0 if left else float(k.width)
    sign = -1.0 if left else 1.0

    def outside(shift):  # area beyond the edge after moving the polygon by sign * shift
        u = sign * (poly[:, 0] + sign * shift - edge)  # > 0 beyond the edge
        clipped = _clip_halfplane(np.column_stack([u, poly[:, 1]]))
        return abs(polygon_area(clipped)) / total if len(clipped) >= 3 else 0.0

    lo, hi = 0.0, float(k.width + np.ptp(poly[:, 0]))
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if outside(mid) < fraction else (lo, mid)
    intr = replace(k, cx=k.cx + sign * 0.5 * (lo + hi))
    return Camera(intr, camera.pose)


def _clip_halfplane(poly):
    """The part ``u >= 0`` of a polygon (Sutherland-Hodgman against one line)."""
    out = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        if p[0] >= 0:
            out.append(p)
        if (p[0] >= 0) != (q[0] >= 0):
            t = p[0] / (p[0] - q[0])
            out.append(p + t * (q - p))
    return np.array(out).reshape(-1, 2)
