"""The overlap of superquadric silhouettes with mask contours that are not convex: stage 3T's
R-IOU (:func:`sqfit.fitting.costs.visible_iou` with ``polygon="contour"``), which the factor graph's
re-fits of household landmarks run thousands of times per sequence.

shapely intersected each silhouette with its mask contour: ~70 us per pair on household masks, and
twice for a view cut by the image border (first with the image, then with the contour), with the
contour made valid again at every call; that was over half of a household sequence's batch time.
A silhouette is convex, so the contour clipped by each of its edges (Sutherland-Hodgman) is the
intersection, whatever the contour's shape: :func:`sqfit.kernels.silhouette_kernels.contour_overlaps`
(compiled) does that where the silhouette is convex and the contour simple, and shapely the rest.
"""

from __future__ import annotations

import numpy as np

from ..kernels.backend import compiled

__all__ = ["CONVEX_TOL", "contour_overlaps", "contour_ious"]


#: :func:`sqfit.kernels.silhouette_kernels.contour_overlaps`: a silhouette vertex may turn the wrong
#: way by this much (relative to its edges' lengths: rounding on nearly collinear vertices) and
#: still count as convex.
CONVEX_TOL = 1e-9


def contour_overlaps(polys, valid, obs, views, clip):
    """``(inter, area)``, each ``(b, len(views))``: the area of each silhouette of ``polys``
    ``(b, v, K, 2)`` overlapping the mask contour of each of ``views`` (of the ObservationSet
    ``obs``), and the silhouette's area, both clipped to the image where ``clip`` ``(len(views),)
    bool``; 0 where not ``valid``. Compiled (``contour_overlaps``) where the kernels are, the
    silhouette convex and the contour simple: on household masks of ~240 contour vertices 21 us per
    pair against shapely's 69 us (module docstring); shapely for the rest (the silhouette made valid
    first) and without numba. The two agree to rounding (tested)."""
    import shapely

    b, views = len(polys), np.asarray(views, dtype=np.int64)
    inter, area = np.zeros((b, len(views))), np.zeros((b, len(views)))
    todo = valid[:, views].copy()
    shapes, (stacked, starts, simple, _) = obs.contour_shapes(), obs.contour_arrays()
    kernels = compiled("silhouettes")
    if kernels is not None and todo.any():
        rows, cols = np.nonzero(todo & simple[views])
        clip_all = np.zeros(len(obs), dtype=bool)
        clip_all[views] = clip
        done_inter, done_area, ok = kernels.contour_overlaps(
            np.ascontiguousarray(polys, dtype=np.float64), np.stack([rows, views[cols]], axis=1), stacked, starts,
            obs.frames, clip_all, CONVEX_TOL)
        inter[rows[ok], cols[ok]], area[rows[ok], cols[ok]] = done_inter[ok], done_area[ok]
        todo[rows[ok], cols[ok]] = False
    if todo.any():
        rows, cols = np.nonzero(todo)
        sil = shapely.make_valid(shapely.polygons(polys[rows, views[cols]]))
        sil = np.where(clip[cols], shapely.intersection(sil, shapely.polygons(obs.frames[views[cols]])), sil)
        inter[rows, cols] = shapely.area(shapely.intersection(sil, shapes[views[cols]]))
        area[rows, cols] = shapely.area(sil)
    return inter, area


def contour_ious(polys, valid, obs, views, clip, hidden_inter, hidden_union):
    """IoU ``(b, len(views))`` of silhouettes ``polys`` ``(b, v, K, 2)`` with the mask contours of
    ``views`` (of the ObservationSet ``obs``), the silhouettes clipped to the image where ``clip``
    ``(len(views),) bool``, the hidden-pixel counts (broadcastable to ``(b, len(views))``) out of
    both intersection and union (:func:`sqfit.fitting.costs.visible_iou`); 0 where not ``valid``.
    The overlaps are :func:`contour_overlaps`'."""
    views = np.asarray(views, dtype=np.int64)
    inter, area = contour_overlaps(polys, valid, obs, views, clip)
    areas = obs.contour_arrays()[3]
    union = area + areas[views] - inter - hidden_union
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(union > 0, np.maximum(inter - hidden_inter, 0.0) / union, 0.0)
    return np.where(valid[:, views] & np.isfinite(iou), iou, 0.0)
