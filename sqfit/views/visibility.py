"""Boundary labels: what lies across each point of a mask's outline (occlusion and truncation).

A mask's outline is the object's silhouette only where the object ends. Every vertex of
``Observation.contour`` (and every point taken on it) carries one label:

- :data:`BACKGROUND` (0): the pixel across the outline is background -- a true silhouette edge;
  the object does not reach past it.
- :data:`INSTANCE` (1): the pixel across is another object, or within :data:`OCCLUDER_REACH_PX`
  pixels of one (a "may hide it" pixel) -- the object may continue behind it, unseen.
- :data:`BORDER` (2): the pixel across is outside the image -- the object may continue past
  the border (truncation).

Area samples (inside the mask, not on the outline) carry :data:`INTERIOR` (3).

Rules (pinned by tests/test_visibility.py):

1. Outline vertices come from ``find_contours`` on a binary mask at level 0.5, so every vertex is
   the midpoint of two 4-adjacent pixel centres, one in the mask and one not; that second pixel is
   the one "across" the vertex. If it is outside the image the label is ``BORDER``; else if the
   dilated "may hide" mask holds there it is ``INSTANCE``; else ``BACKGROUND``.
   An outline given as a polygon (:meth:`sqfit.Observation.from_outline`) has vertices anywhere;
   there the pixel across a vertex is the one holding the point half a pixel outward along the
   vertex's normal (:func:`polygon_labels`). On a marching-squares outline both rules give the
   same label (every vertex of 30 random silhouettes, truncated and occluded ones included:
   tests/test_polygon_route.py).
2. The "may hide" mask is, from an instance-id image, every pixel of another instance (id not 0
   and not the object's); from a binary mask, what the user passes (none: nothing hides it). It
   is dilated by :data:`OCCLUDER_REACH_PX` (a square) before the lookup, so a one- or two-pixel
   gap from mask noise between an object and its occluder does not make a silhouette edge.
3. A point between two outline vertices (e.g. the evenly spaced points of stage 3G) takes the
   larger label of the two, so one-sided wins at the ends of an occluded stretch.
4. Labels are conservative: an object in *front* of its neighbour is labelled ``INSTANCE`` along
   the shared edge too (an instance image holds no depth order). That only drops a constraint.

5. The pixels that may hide the object (``Observation.hidden``) are those of the "may hide"
   connected components (8-connectivity) that come within :data:`OCCLUDER_REACH_PX` of the mask:
   where the object could be, unseen. The R-IOU costs leave them out of the union.

A cost uses a point as a two-sided constraint ("the object reaches here and not further") only
where the label is ``BACKGROUND``; elsewhere only "this pixel is the object" holds. Costs read
the labels; none re-derives them.
"""

from __future__ import annotations

import numpy as np

from ..geometry.outline import outward_normals

__all__ = ["BACKGROUND", "INSTANCE", "BORDER", "INTERIOR", "LABEL_NAMES", "OCCLUDER_REACH_PX",
           "outline_labels", "polygon_labels", "point_labels", "silhouette_fraction", "hiding_pixels"]

BACKGROUND, INSTANCE, BORDER, INTERIOR = 0, 1, 2, 3
LABEL_NAMES = {BACKGROUND: "background", INSTANCE: "instance", BORDER: "border", INTERIOR: "interior"}
#: Pixels (square dilation radius) by which a "may hide" mask is grown before labelling.
OCCLUDER_REACH_PX = 2


def outline_labels(contour, mask, occluder=None, reach_px=OCCLUDER_REACH_PX):
    """Labels of the vertices of a mask's outline (rules 1-2 of the module docstring).

    Parameters
    ----------
    contour : (m, 2) float
        Outline vertices ``(u, v)`` from :func:`sqfit.views.observation.outer_contour` of ``mask``.
    mask : (h, w) bool
        The object's mask (after any clean-up: the mask the contour was taken from).
    occluder : (h, w) bool, optional
        Pixels that may hide the object; None: nothing hides it.
    reach_px : int
        Dilation radius of ``occluder``, pixels, >= 0.

    Returns
    -------
    labels : (m,) int8
        :data:`BACKGROUND`, :data:`INSTANCE` or :data:`BORDER` per vertex.
    """
    contour = np.asarray(contour, dtype=np.float64)
    h, w = mask.shape
    x, y = contour[:, 0] - 0.5, contour[:, 1] - 0.5  # pixel-centre coordinates (column, row)
    # The coordinate that is a whole number is shared by both pixels; the other one is a half-integer.
    col_whole = np.abs(x - np.round(x)) < np.abs(y - np.round(y))
    r_a = np.where(col_whole, np.floor(y), np.round(y)).astype(np.int64)
    c_a = np.where(col_whole, np.round(x), np.floor(x)).astype(np.int64)
    r_b, c_b = r_a + col_whole, c_a + ~col_whole
    in_a = _lookup(mask, r_a, c_a)
    # The pixel across is the one of the pair that is not in the mask.
    r_out, c_out = np.where(in_a, r_b, r_a), np.where(in_a, c_b, c_a)
    return _labels_across(r_out, c_out, (h, w), occluder, reach_px)


def polygon_labels(contour, shape, occluder=None, reach_px=OCCLUDER_REACH_PX):
    """Labels of the vertices of an outline polygon with vertices anywhere (rule 1, polygons).

    Parameters
    ----------
    contour : (m, 2) float
        Outline vertices ``(u, v)``, counter-clockwise in image coordinates (positive shoelace
        area), m >= 3.
    shape : (2,) int
        ``(height, width)`` of the image.
    occluder : (h, w) bool, optional
        Pixels that may hide the object (not the object's own); None: nothing hides it.
    reach_px : int
        Dilation radius of ``occluder``, pixels, >= 0.

    Returns
    -------
    labels : (m,) int8
        Per vertex, the label of the pixel holding ``vertex + normal / 2``
        (:func:`sqfit.geometry.outline.outward_normals`): :data:`BORDER` outside the image, else
        :data:`INSTANCE` in the dilated occluder, else :data:`BACKGROUND`.
    """
    contour = np.asarray(contour, dtype=np.float64)
    across = contour + 0.5 * outward_normals(contour)
    cols, rows = np.floor(across).astype(np.int64).T
    return _labels_across(rows, cols, tuple(int(n) for n in shape), occluder, reach_px)


def _labels_across(rows, cols, shape, occluder, reach_px):
    """Labels from the pixel across each outline point (``rows``, ``cols``; may lie outside the image)."""
    h, w = shape
    outside = (rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)
    labels = np.full(len(rows), BACKGROUND, dtype=np.int8)
    if occluder is not None:
        hide = np.asarray(occluder, dtype=bool)
        if reach_px > 0 and hide.any():
            from scipy import ndimage

            hide = ndimage.binary_dilation(hide, np.ones((2 * reach_px + 1,) * 2, dtype=bool))
        labels[_lookup(hide, rows, cols)] = INSTANCE
    labels[outside] = BORDER
    return labels


def _lookup(image, rows, cols):
    h, w = image.shape
    ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    out = np.zeros(len(rows), dtype=bool)
    out[ok] = image[rows[ok], cols[ok]]
    return out


def point_labels(vertex_labels, index):
    """Labels of points on a closed outline's edges (rule 3): the larger of the two end vertices.

    Parameters
    ----------
    vertex_labels : (m,) int
    index : (n,) int
        Edge of each point (edge ``k`` runs from vertex ``k`` to ``k + 1 mod m``).

    Returns
    -------
    labels : (n,) int8
    """
    vertex_labels = np.asarray(vertex_labels)
    index = np.asarray(index, dtype=np.int64)
    nxt = (index + 1) % len(vertex_labels)
    return np.maximum(vertex_labels[index], vertex_labels[nxt]).astype(np.int8)


def silhouette_fraction(contour, labels):
    """Fraction of an outline's length that is true silhouette (both ends :data:`BACKGROUND`).

    Parameters
    ----------
    contour : (m, 2) float
    labels : (m,) int

    Returns
    -------
    fraction : float
        In [0, 1]; 1 for an object seen whole.
    """
    contour = np.asarray(contour, dtype=np.float64)
    seg = np.linalg.norm(np.roll(contour, -1, axis=0) - contour, axis=1)
    total = seg.sum()
    if total <= 0:
        return 1.0
    edge = point_labels(labels, np.arange(len(contour)))
    return float(seg[edge == BACKGROUND].sum() / total)


def hiding_pixels(mask, occluder, reach_px=OCCLUDER_REACH_PX):
    """Centres of the pixels that may hide the object (rule 5 of the module docstring).

    Parameters
    ----------
    mask : (h, w) bool
    occluder : (h, w) bool or None
    reach_px : int

    Returns
    -------
    centres : (k, 2) float
        Image coordinates ``(u, v)`` of the pixel centres; ``(0, 2)`` when nothing hides it.
    """
    if occluder is None or not np.any(occluder):
        return np.zeros((0, 2))
    from scipy import ndimage

    occluder = np.asarray(occluder, dtype=bool) & ~mask
    near = ndimage.binary_dilation(mask, np.ones((2 * reach_px + 3,) * 2, dtype=bool))
    comps, n = ndimage.label(occluder, structure=np.ones((3, 3), dtype=bool))
    touching = np.unique(comps[near & occluder])
    touching = touching[touching > 0]
    rows, cols = np.nonzero(np.isin(comps, touching))
    return np.stack([cols + 0.5, rows + 0.5], axis=1).astype(np.float64)
