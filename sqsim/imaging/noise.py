"""Seeded, composable corruptions of instance masks and camera poses.

Mask models act on one binary mask ``(h, w) bool`` and take a ``numpy.random.Generator``:

- :func:`erode` / :func:`dilate` by ``k`` px: remove / add every pixel whose centre is within
  Euclidean distance ``k`` (pixel units, centre to centre) of the background / the mask, i.e. a
  ``k``-pixel band.
- :func:`jitter_boundary` by ``sigma`` px: displaces the contour along its normal by a smooth
  random field (Gaussian-filtered white noise, correlation length ``JITTER_SCALE_PX``) whose
  standard deviation is ``sigma`` pixels.
- :func:`drop_out` a fraction ``f`` of the area: removes the ``f``-quantile of a smooth random
  field over the mask, i.e. random blobs totalling ``f`` of the mask's pixels (up to rounding).
- :func:`add_false_blobs` ``n``: adds ``n`` filled discs of radius ``BLOB_RADIUS_FRACTION *
  sqrt(area)`` (clipped to ``BLOB_RADIUS_PX``) on background pixels away from the object.

:func:`corrupt_image` applies them to every instance of an id image in the fixed order
segmenter-like models (:mod:`sqsim.imaging.mask_models`: thin-part loss, smooth error, boundary bias,
holes), erosion, dilation, jitter, dropout, false blobs; pixels claimed by several corrupted
masks keep their original id if it is one of the claimants, else the lowest id. :func:`perturb_pose` models pose
noise: a rotation by an isotropic Gaussian rotation vector (per-axis std ``rotation_deg``),
applied in the camera frame, and a Gaussian shift of the camera centre (per-axis std
``translation_m``, world frame). Masks stay rendered from the true poses; the fitter sees the
perturbed ones.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

import sqfit
from sqfit._checks import check_number, check_shape

from .mask_ops import as_mask, mask_box

__all__ = ["erode", "dilate", "jitter_boundary", "drop_out", "add_false_blobs", "corrupt_image",
           "corrupts_masks", "perturb_pose", "perturb_cameras", "JITTER_SCALE_PX", "DROPOUT_SCALE_PX"]

#: Correlation length (Gaussian sigma, px) of the boundary-jitter field.
JITTER_SCALE_PX = 8.0
#: Correlation length (Gaussian sigma, px) of the dropout field: the size of removed blobs.
DROPOUT_SCALE_PX = 6.0
#: False-blob radius as a fraction of sqrt(object area), clipped to this range (px).
BLOB_RADIUS_FRACTION = 0.15
BLOB_RADIUS_PX = (2.0, 25.0)


def _signed_distance(mask):
    """Signed distance of pixel centres to the pixel-edge boundary, px: > 0 inside."""
    inside = ndimage.distance_transform_edt(mask)
    outside = ndimage.distance_transform_edt(~mask)
    return np.where(mask, inside - 0.5, 0.5 - outside)


def erode(mask, k):
    """Remove a ``k``-px band: pixels within distance ``k`` of the background.

    Parameters
    ----------
    mask : (h, w) bool
    k : int
        Pixels, >= 0.

    Returns
    -------
    eroded : (h, w) bool
    """
    mask = as_mask(mask)
    k = _check_px(k, "erosion")
    if k == 0 or not mask.any():
        return mask.copy()
    # Pad with background so the image border counts as background too (consistent with dilation).
    padded = np.pad(mask, 1)
    return ndimage.distance_transform_edt(padded)[1:-1, 1:-1] > k


def dilate(mask, k):
    """Add a ``k``-px band: background pixels within distance ``k`` of the mask.

    Parameters
    ----------
    mask : (h, w) bool
    k : int
        Pixels, >= 0.

    Returns
    -------
    dilated : (h, w) bool
    """
    mask = as_mask(mask)
    k = _check_px(k, "dilation")
    if k == 0 or not mask.any():
        return mask.copy()
    out = mask.copy()
    box = mask_box(mask, k + 1)
    out[box] = ndimage.distance_transform_edt(~mask[box]) <= k
    return out


def _check_px(k, name):
    if isinstance(k, bool) or int(k) != k or k < 0:
        raise ValueError(f"{name} must be an integer number of pixels >= 0, got {k}")
    return int(k)


def _smooth_field(shape, scale, rng):
    """Zero-mean, unit-std Gaussian random field with correlation length ``scale`` px."""
    field = ndimage.gaussian_filter(rng.standard_normal(shape), scale, mode="wrap")
    return (field - field.mean()) / max(field.std(), 1e-12)


def jitter_boundary(mask, sigma, rng=None, scale=JITTER_SCALE_PX):
    """Displace the boundary along its normal by a smooth random field of std ``sigma`` px.

    Parameters
    ----------
    mask : (h, w) bool
    sigma : float
        Standard deviation of the normal displacement, pixels, >= 0.
    rng : None, int or numpy.random.Generator
    scale : float
        Correlation length of the displacement along the boundary, pixels.

    Returns
    -------
    jittered : (h, w) bool
    """
    mask = as_mask(mask)
    sigma = check_number(sigma, "boundary jitter", lo=0)
    rng = np.random.default_rng(rng)
    if sigma == 0 or not mask.any():
        return mask.copy()
    margin = int(np.ceil(4 * sigma + 2))
    box = mask_box(mask, margin)
    sub = mask[box]
    field = _smooth_field(sub.shape, scale, rng) * sigma
    out = np.zeros_like(mask)
    out[box] = _signed_distance(sub) + field > 0
    return out


def drop_out(mask, fraction, rng=None, scale=DROPOUT_SCALE_PX):
    """Remove random smooth blobs totalling ``fraction`` of the mask area.

    Parameters
    ----------
    mask : (h, w) bool
    fraction : float
        In ``[0, 1)``.
    rng : None, int or numpy.random.Generator
    scale : float
        Blob size (correlation length), pixels.

    Returns
    -------
    kept : (h, w) bool
        ``round(fraction * area)`` pixels fewer than ``mask``.
    """
    mask = as_mask(mask)
    fraction = float(fraction)
    if not 0 <= fraction < 1:
        raise ValueError(f"dropout fraction must be in [0, 1), got {fraction}")
    rng = np.random.default_rng(rng)
    n_drop = int(round(fraction * mask.sum()))
    if n_drop == 0:
        return mask.copy()
    box = mask_box(mask, 0)
    sub = mask[box]
    values = _smooth_field(sub.shape, scale, rng)[sub]
    order = np.argsort(values, kind="stable")
    keep = np.ones(len(values), dtype=bool)
    keep[order[:n_drop]] = False
    out = np.zeros_like(mask)
    rows, cols = np.nonzero(sub)
    out[box][rows[keep], cols[keep]] = True
    return out


def add_false_blobs(mask, n, rng=None, forbidden=None):
    """Add ``n`` spurious filled discs on the background.

    Parameters
    ----------
    mask : (h, w) bool
    n : int
        Number of blobs, >= 0.
    rng : None, int or numpy.random.Generator
    forbidden : (h, w) bool, optional
        Pixels blobs must not cover (default: the mask itself); blobs also keep 2 px from the
        image border.

    Returns
    -------
    out : (h, w) bool
        ``mask`` with up to ``n`` added discs (fewer only if no free place is found).
    """
    mask = as_mask(mask)
    n = _check_px(n, "false_blobs")
    rng = np.random.default_rng(rng)
    out = mask.copy()
    if n == 0:
        return out
    h, w = mask.shape
    lo, hi = BLOB_RADIUS_PX
    radius = float(np.clip(BLOB_RADIUS_FRACTION * np.sqrt(max(mask.sum(), 1)), lo, hi))
    taken = (mask if forbidden is None else as_mask(forbidden) | mask).copy()
    yy, xx = np.mgrid[0:h, 0:w]
    placed, attempts = 0, 0
    while placed < n and attempts < 100 * n:
        attempts += 1
        ci = rng.uniform(radius + 2, h - radius - 2)
        cj = rng.uniform(radius + 2, w - radius - 2)
        r0, r1 = int(max(ci - radius - 1, 0)), int(min(ci + radius + 2, h))
        c0, c1 = int(max(cj - radius - 1, 0)), int(min(cj + radius + 2, w))
        disc = (yy[r0:r1, c0:c1] + 0.5 - ci) ** 2 + (xx[r0:r1, c0:c1] + 0.5 - cj) ** 2 <= radius ** 2
        # Keep a 1 px gap so the blob is a separate component.
        if (ndimage.binary_dilation(disc) & taken[r0:r1, c0:c1]).any():
            continue
        out[r0:r1, c0:c1] |= disc
        taken[r0:r1, c0:c1] |= disc
        placed += 1
    return out


def corrupt_image(image, noise, rng=None):
    """Apply the mask noise of a scene to every instance of an id image.

    Parameters
    ----------
    image : (h, w) uint16
        Instance ids, 0 = background.
    noise : sqsim.world.scene.NoiseConfig
    rng : None, int or numpy.random.Generator

    Returns
    -------
    corrupted : (h, w) uint16
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"image must have shape (h, w), got {image.shape}")
    from .mask_models import apply_mask_models

    rng = np.random.default_rng(rng)
    ids = [int(i) for i in np.unique(image) if i != 0]
    claimed = {}
    for oid in ids:
        m = image == oid
        m = apply_mask_models(m, noise, rng)
        m = erode(m, noise.erosion_px)
        m = dilate(m, noise.dilation_px)
        m = jitter_boundary(m, noise.boundary_jitter_px, rng)
        m = drop_out(m, noise.dropout, rng)
        m = add_false_blobs(m, noise.false_blobs, rng, forbidden=image != 0)
        claimed[oid] = m
    out = np.zeros_like(image)
    for oid in sorted(ids, reverse=True):  # lowest id wins contested pixels...
        out[claimed[oid]] = oid
    for oid in ids:  # ...unless the pixel originally belonged to one of the claimants
        keep = claimed[oid] & (image == oid)
        out[keep] = oid
    return out


def corrupts_masks(noise):
    """True when a scene's ``[noise]`` (``sqsim.world.scene.NoiseConfig``) changes instance masks."""
    from .mask_models import mask_models_active

    return bool(any((noise.erosion_px, noise.dilation_px, noise.boundary_jitter_px, noise.dropout,
                     noise.false_blobs)) or mask_models_active(noise))


def perturb_pose(pose, rotation_deg, translation_m, rng=None):
    """A noisy copy of a camera pose.

    Parameters
    ----------
    pose : (4, 4) float
        ``T_world_camera``.
    rotation_deg : float
        Per-axis standard deviation of the rotation vector, degrees (applied in the camera frame).
    translation_m : float
        Per-axis standard deviation of the camera-centre shift, metres (world frame).
    rng : None, int or numpy.random.Generator

    Returns
    -------
    noisy : (4, 4) float
    """
    from scipy.spatial.transform import Rotation

    pose = check_shape(pose, (4, 4), "pose")
    rotation_deg = check_number(rotation_deg, "pose rotation noise", lo=0)
    translation_m = check_number(translation_m, "pose translation noise", lo=0)
    rng = np.random.default_rng(rng)
    rotvec = rng.normal(0.0, np.radians(rotation_deg), 3)
    shift = rng.normal(0.0, translation_m, 3)
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ Rotation.from_rotvec(rotvec).as_matrix()
    out[:3, 3] = pose[:3, 3] + shift
    return out


def perturb_cameras(cameras, rotation_deg, translation_m, rng=None):
    """:func:`perturb_pose` for each camera; returns the cameras unchanged when both are zero."""
    rng = np.random.default_rng(rng)
    if rotation_deg == 0 and translation_m == 0:
        return list(cameras)
    return [sqfit.Camera(c.intrinsics, perturb_pose(c.pose, rotation_deg, translation_m, rng)) for c in cameras]
