"""Compiled (numba) kernels of stage 3U (:mod:`sqfit.fitting.two_parts`): two superquadrics' silhouettes
against a mask contour.

- :func:`union_overlaps` is the overlap of the union of two convex silhouettes with a mask contour
  (shapely's union and intersection per view took most of the union fit's time), from
  :func:`sqfit.kernels.silhouette_kernels.contour_overlaps`' clipping:
  ``|(S1 ∪ S2) ∩ M| = |S1 ∩ M| + |S2 ∩ M| - |S1 ∩ S2 ∩ M|``;
- :func:`union_edge_sums` is the per-view loop of :func:`sqfit.fitting.two_parts.union_gradient` (numpy
  per edge and shapely's ``contains_xy`` per point took 4 of the 10 s of a chair's union fit): each
  silhouette edge's normal speed integrated, by midpoint sums, over its stretch outside the other
  silhouette, and over the part of that inside the mask contour (an even-odd test, the contour a
  simple polygon, over the contour's edges in the point's 1 px band of rows: testing every edge of a
  contour of 700-1000 vertices kept it at 4.5 s of a chair's 9.7).

Sums run in index order. Importing this module imports numba; :mod:`sqfit.kernels.backend` does that
lazily, and the kernels are cached next to this file (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .silhouette_kernels import clip_buffers, clip_convex, clipped_contour, convex_sign, polygon_area

__all__ = ["union_overlaps", "union_edge_sums"]

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@njit(**_JIT)
def union_overlaps(polys, pairs, contours, starts, tol):
    """Overlap of the union of two silhouettes with a mask contour: ``polys`` ``(b, 2, v, k, 2)``,
    ``pairs`` ``(p, 2)`` ``(batch, view)`` indices, ``contours`` and ``starts`` as
    :func:`~sqfit.kernels.silhouette_kernels.contour_overlaps` takes them -> ``(inter, area, ok)``,
    each ``(p,)``: the area of (S1 ∪ S2) ∩ contour, the union's area, and whether both silhouettes
    are convex and simple (:func:`~sqfit.kernels.silhouette_kernels.convex_sign` with ``tol``; where
    not, 0 and 0). The contour clipped by S1 (then by S2) and by S2, and S1 clipped by S2, give the
    four areas of inclusion-exclusion. No image border: for views that it does not cut."""
    count = pairs.shape[0]
    inter, area, ok = np.zeros(count), np.zeros(count), np.zeros(count, dtype=np.bool_)
    cur, other = clip_buffers(starts, polys.shape[3])
    for p in range(count):
        s, t = pairs[p, 0], pairs[p, 1]
        S1, S2 = polys[s, 0, t], polys[s, 1, t]
        sign1, sign2 = convex_sign(S1, tol), convex_sign(S2, tol)
        if sign1 == 0.0 or sign2 == 0.0:
            continue
        ok[p] = True
        k = S1.shape[0]
        for i in range(k):
            cur[i, 0], cur[i, 1] = S1[i, 0], S1[i, 1]
        cur, n, other = clip_convex(cur, k, S2, sign2, other)
        area[p] = polygon_area(S1, k) + polygon_area(S2, S2.shape[0]) - polygon_area(cur, n)
        lo, hi = starts[t], starts[t + 1]
        cur, n, other = clipped_contour(contours, lo, hi, S1, sign1, cur, other)
        inter[p] = polygon_area(cur, n)
        cur, n, other = clip_convex(cur, n, S2, sign2, other)
        inter[p] -= polygon_area(cur, n)
        cur, n, other = clipped_contour(contours, lo, hi, S2, sign2, cur, other)
        inter[p] += polygon_area(cur, n)
    return inter, area, ok


@njit(**_JIT)
def _inside_span(x0, y0, ex, ey, S):
    """``(lo, hi)``: the points ``(x0, y0) + s (ex, ey)`` with ``lo <= s <= hi`` lie in the closed
    counter-clockwise convex polygon ``S``, the others strictly outside (``lo > hi``: none inside):
    each edge's side test is linear in ``s`` (Cyrus-Beck), one pass over ``S`` per segment instead of
    one per point."""
    k = S.shape[0]
    lo, hi = -np.inf, np.inf
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        dx, dy = S[j, 0] - S[i, 0], S[j, 1] - S[i, 1]
        f0 = dx * (y0 - S[i, 1]) - dy * (x0 - S[i, 0])  # >= 0 on the inner side
        df = dx * ey - dy * ex
        if df > 0.0:
            lo = max(lo, -f0 / df)
        elif df < 0.0:
            hi = min(hi, -f0 / df)
        elif f0 < 0.0:
            return np.inf, -np.inf
        if lo > hi:
            break
    return lo, hi


@njit(**_JIT)
def _bands(contours, lo, hi):
    """The edges of the closed polygon ``contours[lo:hi]`` by the 1 px bands of ``y`` they span:
    ``(y0, first, edges)``, band ``b`` (``floor(y) - y0``) holding ``edges[first[b]:first[b + 1]]``
    (each edge by its end ``i``, running from ``i - 1``)."""
    y0, y1 = math.floor(contours[lo, 1]), math.floor(contours[lo, 1])
    for i in range(lo, hi):
        y0, y1 = min(y0, math.floor(contours[i, 1])), max(y1, math.floor(contours[i, 1]))
    first = np.zeros(y1 - y0 + 2, dtype=np.int64)
    j = hi - 1
    for i in range(lo, hi):
        a, b = min(contours[i, 1], contours[j, 1]), max(contours[i, 1], contours[j, 1])
        for band in range(math.floor(a) - y0, math.floor(b) - y0 + 1):
            first[band + 1] += 1
        j = i
    first = np.cumsum(first)
    edges, filled = np.empty(first[-1], dtype=np.int64), first[:-1].copy()
    j = hi - 1
    for i in range(lo, hi):
        a, b = min(contours[i, 1], contours[j, 1]), max(contours[i, 1], contours[j, 1])
        for band in range(math.floor(a) - y0, math.floor(b) - y0 + 1):
            edges[filled[band]] = i
            filled[band] += 1
        j = i
    return y0, first, edges


@njit(**_JIT)
def _in_contour(x, y, contours, lo, hi, y0, first, edges):
    """Even-odd test of ``(x, y)`` against the closed polygon ``contours[lo:hi]``, over the edges of
    its band (:func:`_bands`): an edge crosses the line through ``y`` only in a band it spans."""
    band = math.floor(y) - y0
    if band < 0 or band >= first.shape[0] - 1:
        return False
    inside = False
    for m in range(first[band], first[band + 1]):
        i = edges[m]
        j = i - 1 if i > lo else hi - 1
        xi, yi, xj, yj = contours[i, 0], contours[i, 1], contours[j, 0], contours[j, 1]
        if (yi > y) != (yj > y) and x < (xj - xi) * (y - yi) / (yj - yi) + xi:
            inside = not inside
    return inside


@njit(**_JIT)
def union_edge_sums(polys, velocities, contours, starts, views, n):
    """The union's area and overlap derivatives per view: ``polys`` ``(2, v, k, 2)`` the two parts'
    counter-clockwise silhouettes, ``velocities`` ``(2, v, k, 2, q)`` their vertices' derivatives
    by each part's ``q`` parameters, ``contours`` and ``starts`` the mask contours (simple polygons)
    as :func:`~sqfit.kernels.silhouette_kernels.contour_overlaps` takes them, ``views`` the views to
    sum, ``n`` midpoints per edge -> ``(d_inter, d_union)``, each ``(v, 2 q)`` (0 in the views not
    asked): each edge's outward normal speed, linear along the edge, summed at its midpoints outside
    the other part's silhouette times the edge's length over ``n``; ``d_inter`` only at those inside
    the contour."""
    nv, k, q = polys.shape[1], polys.shape[2], velocities.shape[4]
    d_inter, d_union = np.zeros((nv, 2 * q)), np.zeros((nv, 2 * q))
    for t in views:
        lo, hi = starts[t], starts[t + 1]
        y0, first, edges = _bands(contours, lo, hi)
        for part in range(2):
            S, O = polys[part, t], polys[1 - part, t]
            for e in range(k):
                f = e + 1 if e + 1 < k else 0
                ex, ey = S[f, 0] - S[e, 0], S[f, 1] - S[e, 1]
                length = math.hypot(ex, ey)
                if length <= 1e-12:
                    continue
                nx, ny = ey / length, -ex / length
                # the midpoints' weights of the edge's two ends, summed over those outside O (and in the contour)
                u0, u1, i0, i1 = 0.0, 0.0, 0.0, 0.0
                lo_s, hi_s = _inside_span(S[e, 0], S[e, 1], ex, ey, O)
                for m in range(n):
                    s = (m + 0.5) / n
                    if lo_s <= s <= hi_s:  # inside O
                        continue
                    x, y = S[e, 0] + s * ex, S[e, 1] + s * ey
                    u0 += 1.0 - s
                    u1 += s
                    if _in_contour(x, y, contours, lo, hi, y0, first, edges):
                        i0 += 1.0 - s
                        i1 += s
                if u0 + u1 == 0.0:
                    continue
                w = length / n
                for c in range(q):
                    w0 = nx * velocities[part, t, e, 0, c] + ny * velocities[part, t, e, 1, c]
                    w1 = nx * velocities[part, t, f, 0, c] + ny * velocities[part, t, f, 1, c]
                    d_union[t, part * q + c] += w * (u0 * w0 + u1 * w1)
                    d_inter[t, part * q + c] += w * (i0 * w0 + i1 * w1)
    return d_inter, d_union
