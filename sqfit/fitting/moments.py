"""Stage 2M (the default's second stage): stage 2's PCA ellipsoid from the masks' exact moments.

Stage ``2`` (Algorithm 1, :func:`sqfit.fitting.stages.pca_init`) back-projects each view's ``n``
random samples at that view's depth and takes the principal axes and half-extents of the pooled
points. Its answer therefore depends on the sampling seed, and the default chain inherited that:
on the paper scene (100 trials, ``scripts/seed_stability.py``) the stage-2 ellipsoids of seeds 0
and 1 overlapped at 3D IoU 0.76-0.97 on the objects whose final fits disagreed, and the two
seeds' final fits of ``1-2-3H`` overlapped at 3D IoU below 0.98 on 21 of 100 objects (with 2M and
the rescue on deterministic samples, :mod:`sqfit.fitting.axis_screen`: 0 of 100, identical fits). ``2M`` computes what
stage 2 estimates, without samples:

- At one depth ``d_i`` per view (stage 1's), back-projection is affine in the image point:
  ``X = C_i + d_i R_i K_i^-1 (u, v, 1)``. The uniform distribution over the view's region (the
  polygon of ``Observation.contour``) has an exact mean and covariance
  (:func:`sqfit.geometry.polygon.batch_polygon_moments`), so the back-projected points' mean and
  covariance are exact too; the views are pooled with equal weights (stage 2 draws the same
  number of samples in every view): covariance = mean of the views' covariances + covariance of
  their means.
- Orientation: the eigenvectors of that covariance, largest first (stage 2's singular vectors in
  the limit of many samples), made a proper rotation.
- Size: half the extent, along each axis, of the back-projected contour vertices (the limit of
  stage 2's sample extent), floor ``constants.SIZE_MIN``.
- Shape ``e = (1, 1)``, position kept from the input (stage 1), depths per sample on the
  ellipsoid (:func:`sqfit.fitting.stages.ellipsoid_depths`), as stage 2.

Partial visibility as stage 2: only the views :func:`sqfit.fitting.stages.trusted_views` trusts.
Deterministic: the result depends on the masks (through their contours) and the cameras only.
"""

from __future__ import annotations

import numpy as np

from .. import constants as C
from ..geometry.polygon import batch_polygon_moments
from .stages import FitState, ellipsoid_depths, register, rotation_to_euler, trusted_views, view_depths_of

__all__ = ["mask_moments_3d", "moments_init"]


def _back_projection(obs, depths):
    """Per view the affine back-projection at its depth: ``X = offset_i + linear_i @ (u, v)``.

    Returns ``offset (v, 3)`` and ``linear (v, 3, 2)``."""
    k = obs.intrinsics  # fx, fy, cx, cy per view
    scaled = obs.rotations * depths[:, None, None]
    linear = scaled[:, :, :2] / k[:, None, 0:2]
    offset = obs.centers + np.einsum("vij,vj->vi", scaled,
                                     np.stack([-k[:, 2] / k[:, 0], -k[:, 3] / k[:, 1], np.ones(len(k))], axis=1))
    return offset, linear


def mask_moments_3d(obs, depths, views=None):
    """Mean and covariance of the masks' regions back-projected at one depth per view, pooled.

    Parameters
    ----------
    obs : ObservationSet
    depths : (v,) float
        Camera-frame depth of each view, > 0.
    views : (v,) bool, optional
        Views to pool (default all), at least one.

    Returns
    -------
    mean : (3,) float
    covariance : (3, 3) float
        Of the equal-weight mixture of the views' uniform distributions over their contour
        polygons, back-projected (module docstring).
    """
    depths = np.asarray(depths, dtype=np.float64)
    if depths.shape != (len(obs),) or not np.all(np.isfinite(depths) & (depths > 0)):
        raise ValueError(f"depths must be ({len(obs)},) finite and > 0, got {depths}")
    views = np.ones(len(obs), dtype=bool) if views is None else np.asarray(views, dtype=bool)
    if views.shape != (len(obs),) or not views.any():
        raise ValueError(f"views must be ({len(obs)},) bool with at least one True, got {views}")
    offset, linear = _back_projection(obs, depths)
    used = np.flatnonzero(views)
    _, centroid, cov = batch_polygon_moments([obs.observations[i].contour for i in used])
    means = offset[used] + np.einsum("vij,vj->vi", linear[used], centroid)
    covs = np.einsum("vik,vkl,vjl->vij", linear[used], cov, linear[used])
    mean = means.mean(axis=0)
    spread = means - mean
    return mean, covs.mean(axis=0) + spread.T @ spread / len(means)


@register("2M")
def moments_init(state, obs, options):
    """Stage 2M: stage 2's ellipsoid from the masks' exact moments instead of random samples.

    Principal axes of :func:`mask_moments_3d` at the input's depth per view (stage 1's), sizes
    from the back-projected contours, ``e = 1``, position kept (module docstring).
    """
    depths = view_depths_of(state, obs)
    use = trusted_views(obs)
    mean, cov = mask_moments_3d(obs, depths, use)
    values, vectors = np.linalg.eigh(cov)
    R = vectors[:, ::-1].copy()  # largest first (eigh: ascending)
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    offset, linear = _back_projection(obs, depths)
    # Extent along each axis of the back-projected contours: affine, so (m, 2) @ (2, 3) per view.
    local = np.concatenate([obs.observations[i].contour @ (linear[i].T @ R) + (offset[i] - mean) @ R
                            for i in np.flatnonzero(use)])
    size = np.maximum((local.max(axis=0) - local.min(axis=0)) / 2.0, C.SIZE_MIN)
    xi = np.concatenate([size, [1.0, 1.0], state.xi[5:8], rotation_to_euler(R)])
    return FitState(xi, view_depths=None, sample_depths=ellipsoid_depths(xi, obs))
