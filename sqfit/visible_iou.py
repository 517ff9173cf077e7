"""IoU over the part of the image where the object could have been seen (truncated views).

When a mask is cut by the image border (outline labels ``border``, :mod:`sqfit.visibility`), the
part of the projected superquadric ``S`` outside the image can be neither confirmed nor denied by
the mask. The R-IOU costs and R-IOU-M then compare the observation polygon ``Q`` with ``S``
clipped to the image rectangle ``R``:

``IoU_R(S, Q) = |S n Q| / (|S n R| + |Q| - |S n Q|)``,

which is the IoU of ``S n R`` and ``Q`` because ``Q`` lies inside the image. For convex ``S``
and ``Q`` both areas come from the clipping of :func:`sqfit.silhouette.convex_iou`, and the
derivative in the vertices of ``S`` is analytic (the flux of the vertex velocities across the
pieces of ``S``'s edges inside ``Q``, resp. ``R``, as :func:`sqfit.silhouette.convex_iou_jacobian`).
"""

from __future__ import annotations

import numpy as np

from .silhouette import _convex_overlap, half_planes

__all__ = ["image_rectangles", "clipped_convex_iou", "clipped_convex_iou_jacobian"]


def image_rectangles(sizes):
    """Image rectangles as CCW polygons (positive shoelace area with ``v`` down).

    Parameters
    ----------
    sizes : (v, 2) float
        ``(width, height)`` per view, pixels.

    Returns
    -------
    rectangles : (v, 4, 2) float
    """
    sizes = np.asarray(sizes, dtype=np.float64).reshape(-1, 2)
    w, h, z = sizes[:, 0], sizes[:, 1], np.zeros(len(sizes))
    return np.stack([np.stack([z, z], 1), np.stack([w, z], 1), np.stack([w, h], 1), np.stack([z, h], 1)], axis=1)


def clipped_convex_iou(S, Q, R, q_planes=None, r_planes=None):
    """``IoU_R(S, Q)`` (module docstring) of convex CCW polygons, vectorised over leading axes.

    Parameters
    ----------
    S : (..., k, 2) float
    Q : (..., m, 2) float
        Inside ``R``.
    R : (..., 4, 2) float
        The image rectangle (:func:`image_rectangles`).
    q_planes, r_planes : tuple, optional
        :func:`sqfit.silhouette.half_planes` of ``Q`` and ``R``.

    Returns
    -------
    iou : (...,) float
    """
    return clipped_convex_iou_jacobian(S, Q, R, q_planes, r_planes)[0]


def clipped_convex_iou_jacobian(S, Q, R, q_planes=None, r_planes=None):
    """``IoU_R(S, Q)`` and its derivative in the vertices of ``S``.

    Returns
    -------
    iou : (...,) float
    weights : callable
        ``weights()`` gives ``(..., k, 2)``: ``d IoU_R / d S``; 0 where ``S n Q`` is empty.
    """
    _, (d, q_lo, q_hi, inter, _, _, area_q) = _convex_overlap(S, Q, q_planes)
    _, (_, r_lo, r_hi, seen, _, _, _) = _convex_overlap(S, R, half_planes(R) if r_planes is None else r_planes)
    with np.errstate(all="ignore"):
        union = seen + area_q - inter
        iou = np.clip(np.where(union > 0, inter / union, 0.0), 0.0, 1.0)
    ok = (union > 0) & (inter > 0)

    def weights():
        with np.errstate(all="ignore"):
            normal = np.stack([d[..., 1], -d[..., 0]], axis=-1)  # outward for CCW, |N| = edge length
            w_inter = _piece_flux(normal, q_lo, q_hi)
            w_seen = _piece_flux(normal, r_lo, r_hi)
            # d iou = ((seen + area_q) d inter - inter d seen) / union^2
            W = (((seen + area_q) / union ** 2)[..., None, None] * w_inter
                 - (inter / union ** 2)[..., None, None] * w_seen)
        return np.where(ok[..., None, None] & np.isfinite(W), W, 0.0)

    return iou, weights


def _piece_flux(normal, t_lo, t_hi):
    """Per-vertex gradient of the area swept by the pieces ``[t_lo, t_hi]`` of each edge.

    A piece ``[t0, t1]`` of edge ``k`` changes the area by ``(t1 - t0 - h) f0 + h f1`` with
    ``h = (t1^2 - t0^2) / 2``, ``f0 = dS_k . N_k`` and ``f1 = dS_(k+1) . N_k``.
    """
    t0 = np.minimum(t_lo, 1.0)
    t1 = np.maximum(t_hi, t0)
    h = 0.5 * (t1 * t1 - t0 * t0)
    w0 = (t1 - t0 - h)[..., None] * normal
    w1 = h[..., None] * normal
    return w0 + np.roll(w1, 1, axis=-2)
