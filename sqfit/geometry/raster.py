"""Rasterising polygons: convex ones given in image coordinates (``sqfit.geometry.camera`` pixel
convention) exactly, any polygon by even-odd scanlines (:func:`fill_polygon`, pixel centres at whole
numbers)."""

from __future__ import annotations

import numpy as np

from .._checks import check_shape

__all__ = ["fill_convex_polygon", "fill_polygon"]


def fill_convex_polygon(polygon, shape):
    """Pixels whose centres lie inside a convex polygon, by an exact vectorised scanline fill.

    Pixel ``(i, j)`` is set iff its centre ``(j + 0.5, i + 0.5)`` is inside, with half-open
    bounds per row and column (``u_min <= u < u_max``, ``v_min <= v < v_max``), so polygons that
    share an edge never claim the same pixel. Cost is O(rows x edges), independent of the area.

    Parameters
    ----------
    polygon : (m, 2) float
        ``(u, v)`` vertices of a convex polygon, either orientation.
    shape : (2,) int
        ``(height, width)`` of the mask.

    Returns
    -------
    mask : (height, width) bool
    """
    P = check_shape(polygon, (None, 2), "polygon")
    h, w = (int(n) for n in shape)
    mask = np.zeros((h, w), dtype=bool)
    if len(P) < 3:
        return mask
    i0 = max(int(np.ceil(P[:, 1].min() - 0.5)), 0)
    i1 = min(int(np.ceil(P[:, 1].max() - 0.5)), h)
    if i1 <= i0:
        return mask
    vc = (np.arange(i0, i1) + 0.5)[:, None]
    A, B = P, np.roll(P, -1, axis=0)
    dv = B[:, 1] - A[:, 1]
    spans = (np.minimum(A[:, 1], B[:, 1]) <= vc) & (vc <= np.maximum(A[:, 1], B[:, 1])) & (dv != 0)
    u = A[:, 0] + (vc - A[:, 1]) / np.where(dv != 0, dv, 1.0) * (B[:, 0] - A[:, 0])
    j0 = np.clip(np.ceil(np.where(spans, u, np.inf).min(axis=1) - 0.5), 0, w)
    j1 = np.clip(np.ceil(np.where(spans, u, -np.inf).max(axis=1) - 0.5), 0, w)
    cols = np.arange(w)
    mask[i0:i1] = (cols >= j0[:, None]) & (cols < j1[:, None])
    return mask


def fill_polygon(polygon, shape):
    """Pixels whose centre lies inside a closed polygon (even-odd rule), by scanlines.

    Parameters
    ----------
    polygon : (m, 2) float
        Vertices ``(x, y)`` = (column, row) with pixel centres at whole numbers.
    shape : (2,) int
        ``(height, width)``.

    Returns
    -------
    inside : (height, width) bool
        Undefined for a centre exactly on an edge (none is, for a mask's contour).
    """
    polygon = check_shape(polygon, (None, 2), "polygon")
    h, w = shape
    x0, y0 = polygon.T
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
    first = np.maximum(np.ceil(lo), 0).astype(np.int64)
    count = np.maximum(np.minimum(np.ceil(hi), h) - first, 0).astype(np.int64)  # rows in [lo, hi)
    edge = np.repeat(np.arange(len(polygon)), count)
    rows = first[edge] + np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)
    t = (rows - y0[edge]) / (y1[edge] - y0[edge])
    xs = x0[edge] + t * (x1[edge] - x0[edge])
    toggles = np.zeros((h, w + 1), dtype=np.int64)
    np.add.at(toggles, (rows, np.clip(np.ceil(xs), 0, w).astype(np.int64)), 1)
    return (np.cumsum(toggles[:, :w], axis=1) % 2).astype(bool)
