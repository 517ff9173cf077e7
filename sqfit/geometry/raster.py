"""Rasterising convex polygons given in image coordinates (``sqfit.geometry.camera`` pixel convention)."""

from __future__ import annotations

import numpy as np

from .._checks import check_shape

__all__ = ["fill_convex_polygon"]


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
