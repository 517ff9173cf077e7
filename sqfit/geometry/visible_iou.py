"""IoU over the part of the image where the object could have been seen (truncated, occluded views).

When a mask is cut by the image border (outline labels ``border``, :mod:`sqfit.views.visibility`), the
part of the projected superquadric ``S`` outside the image can be neither confirmed nor denied by
the mask. The R-IOU costs and R-IOU-M then compare the observation polygon ``Q`` with ``S``
clipped to the image rectangle ``R``:

``IoU_R(S, Q) = |S n Q| / (|S n R| + |Q| - |S n Q|)``,

which is the IoU of ``S n R`` and ``Q`` because ``Q`` lies inside the image. For convex ``S``
and ``Q`` both areas come from the clipping of :func:`sqfit.geometry.polygon.convex_iou`, and the
derivative in the vertices of ``S`` is analytic (the flux of the vertex velocities across the
pieces of ``S``'s edges inside ``Q``, resp. ``R``, as :func:`sqfit.geometry.polygon.convex_iou_jacobian`).

Occlusion: the pixels that may hide the object (``Observation.hidden``, :mod:`sqfit.views.visibility`)
are left out of both the intersection and the union, counted as unit squares at their centres
(:func:`hidden_counts`): ``IoU_V = (|S n Q| - h_n) / (|S n R| + |Q| - |S n Q| - h_u)`` with ``h_n``
the hidden pixels in ``S n Q`` and ``h_u`` those in ``S u Q``. The counts are piecewise constant
in the parameters; the Jacobian takes them as constants (their derivative is 0 almost everywhere),
so it stays analytic.
"""

from __future__ import annotations

import numpy as np

from .polygon import convex_overlap, half_planes

__all__ = ["image_rectangles", "clipped_convex_iou", "clipped_convex_iou_jacobian", "hidden_counts",
           "points_in_convex"]


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
        :func:`sqfit.geometry.polygon.half_planes` of ``Q`` and ``R``.

    Returns
    -------
    iou : (...,) float
    """
    return clipped_convex_iou_jacobian(S, Q, R, q_planes, r_planes)[0]


def clipped_convex_iou_jacobian(S, Q, R, q_planes=None, r_planes=None, clip=True, hidden_inter=0.0,
                                hidden_union=0.0):
    """``IoU_V(S, Q)`` (module docstring) and its derivative in the vertices of ``S``.

    Parameters
    ----------
    S, Q, R, q_planes, r_planes
        As :func:`clipped_convex_iou`.
    clip : bool or (...,) bool
        Clip ``S`` to ``R`` (views cut by the border); False counts all of ``S``.
    hidden_inter, hidden_union : float or (...,) float
        ``h_n`` and ``h_u`` (:func:`hidden_counts`), pixels; 0 without occluders.

    Returns
    -------
    iou : (...,) float
    weights : callable
        ``weights()`` gives ``(..., k, 2)``: ``d IoU_R / d S``; 0 where ``S n Q`` is empty.
    """
    _, (d, q_lo, q_hi, inter, _, area_s, area_q) = convex_overlap(S, Q, q_planes)
    _, (_, r_lo, r_hi, seen, _, _, _) = convex_overlap(S, R, half_planes(R) if r_planes is None else r_planes)
    clip = np.asarray(clip, dtype=bool)
    seen = np.where(clip, seen, area_s)
    with np.errstate(all="ignore"):
        num = np.maximum(inter - hidden_inter, 0.0)
        union = seen + area_q - inter - hidden_union
        iou = np.clip(np.where(union > 0, num / union, 0.0), 0.0, 1.0)
    ok = (union > 0) & (num > 0)

    def weights():
        with np.errstate(all="ignore"):
            normal = np.stack([d[..., 1], -d[..., 0]], axis=-1)  # outward for CCW, |N| = edge length
            w_inter = _piece_flux(normal, q_lo, q_hi)
            c = clip[..., None] if clip.ndim else clip
            w_seen = _piece_flux(normal, np.where(c, r_lo, 0.0), np.where(c, r_hi, 1.0))
            # iou = num / union, d num = d inter, d union = d seen - d inter:
            # d iou = ((union + num) d inter - num d seen) / union^2
            W = (((union + num) / union ** 2)[..., None, None] * w_inter
                 - (num / union ** 2)[..., None, None] * w_seen)
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


def points_in_convex(S, points):
    """Which points lie inside convex CCW polygons.

    Parameters
    ----------
    S : (..., k, 2) float
    points : (n, 2) float

    Returns
    -------
    inside : (..., n) bool
    """
    d = np.roll(S, -1, axis=-2) - S
    px, py = points[:, 0], points[:, 1]
    inside = np.ones(S.shape[:-2] + (len(points),), dtype=bool)
    for i in range(S.shape[-2]):  # one edge at a time: (..., n) arrays, not (..., k, n)
        sx, sy = S[..., i, 0, None], S[..., i, 1, None]
        inside &= d[..., i, 0, None] * (py - sy) - d[..., i, 1, None] * (px - sx) >= 0.0
    return inside


def hidden_counts(S, points, in_q):
    """``h_n`` and ``h_u`` of the module docstring: hidden pixels in ``S n Q`` and in ``S u Q``.

    Parameters
    ----------
    S : (b, k, 2) float
        Silhouettes of one view.
    points : (n, 2) float
        Centres of the pixels that may hide the object (``Observation.hidden``).
    in_q : (n,) bool
        Which of them lie in the observation polygon ``Q``.

    Returns
    -------
    hidden_inter, hidden_union : (b,) float
    """
    if not len(points):
        return np.zeros(len(S)), np.zeros(len(S))
    in_s = points_in_convex(S, points)
    both = np.sum(in_s & in_q, axis=-1)
    return both.astype(np.float64), (np.sum(in_s, axis=-1) + np.sum(in_q) - both).astype(np.float64)
