"""Compiled (numba) kernels of R-IOU-M: silhouettes, convex IoU and the samples' hull.

Every fit scores its snapshots by R-IOU-M (:func:`sqfit.fitting.stages.r_iou_m`) and stage 3H
decides its rescue on it; the numpy code for that (:func:`sqfit.geometry.silhouette.batch_silhouettes`,
:func:`sqfit.geometry.polygon.convex_iou`, scipy's qhull for the hull observations) costs ~1.2 ms of
the default chain's ~11 ms, nearly all per-call overhead on ``(b, v, 64)`` arrays. These kernels
compute the same numbers per view and per vertex:

- :func:`silhouettes` is :func:`~sqfit.geometry.silhouette.batch_silhouettes` without a warm start
  (``start=None``, ``touching=False``): the same quadric-ellipse start, adapted directions, dual
  support function and Newton iteration, but each vertex stops when its own step is below the
  tolerance (the numpy loop stops the batch when every step is), so vertices agree within that
  tolerance (1e-7 px; tested to 1e-6 px) and a score no longer depends on the batch it is in;
  :func:`touching_silhouettes` returns their touching points too (``touching=True``: stage 3U's
  union gradient, with :func:`sqfit.kernels.velocity_kernels.vertex_velocities`);
- :func:`convex_iou` is :func:`~sqfit.geometry.polygon.convex_overlap`'s IoU (Cyrus-Beck clipping of
  both boundaries, Green's theorem), with the same tie rules for shared and degenerate edges;
- :func:`clipped_iou` is :func:`sqfit.geometry.visible_iou.clipped_convex_iou_jacobian`'s IoU (the
  views cut by the image border or with occluding pixels: the silhouette clipped to the image,
  the hidden pixels left out), from the same clipping;
- :func:`convex_hull` is Andrew's monotone chain, counter-clockwise without collinear vertices: the
  polygon qhull returns for ``sqfit.fitting.costs``' hull observations, maybe from another first vertex;
- :func:`hidden_counts` is :func:`sqfit.geometry.visible_iou.hidden_counts` (the occluding pixels
  inside each silhouette, the same edge tests), a point's tests stopping at its first outside edge:
  with thousands of occluding pixels per view the numpy version's ``(b, n)`` passes per edge were
  ~15 % of the factor graph's batch time;
- :func:`points_in_convex` is :func:`sqfit.geometry.visible_iou.points_in_convex` for one polygon, the
  same edge test per point, stopping at its first outside edge (no bounding-box shortcut, so each
  point's answer is the numpy test's bit for bit): which occluding pixels lie in an observation's
  polygon, once per view of every observation set the factor graph's re-fits build.

The Sutherland-Hodgman helpers (:func:`clip_convex`, :func:`clipped_contour`, :func:`clip_buffers`,
:func:`convex_sign`, :func:`polygon_area`) are public: :mod:`sqfit.kernels.union_kernels` clips with them.

Sums run in index order (numpy's pairwise sums and BLAS may round differently: IoUs agree to
1e-12). No ``fastmath``. Importing this module imports numba; :mod:`sqfit.kernels.backend` does that
lazily, and the kernels are cached next to this file (``cache=True``). Constants of the numpy code
(tolerances, exponent range, minimum edge) are passed in as arguments, never copied here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .ray_kernels import nan_max, nan_min

__all__ = ["silhouettes", "touching_silhouettes", "convex_iou", "clipped_iou", "convex_hull", "hidden_counts",
           "points_in_convex", "contour_overlaps", "clip_buffers", "clip_convex", "clipped_contour", "convex_sign",
           "polygon_area"]

_TINY = 1e-300
_JIT = dict(cache=True, error_model="numpy", nogil=True)


@njit(**_JIT)
def _matmul(A, B):
    """``A @ B`` of small matrices, summed in index order."""
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc
    return out


# ------------------------------------------------------------------------------------------------
# silhouettes (sqfit.geometry.silhouette.batch_silhouettes, start=None)


@njit(**_JIT)
def _pnorm2(x, y, q):
    """``sqfit.geometry.silhouette._pnorm2``: the norm and the weight of ``x``."""
    big = nan_max(x, y)
    t = nan_min(x, y)
    t /= big + _TINY
    tq = t ** q
    total = tq + 1.0
    norm = total ** (1.0 / q)
    norm *= big
    w_small = tq / total
    return norm, (1.0 - w_small if x >= y else w_small)


@njit(**_JIT)
def _support(w0, w1, w2, q1, q2, grad):
    """``sqfit.geometry.silhouette.dual_support`` of one direction; the gradient into ``grad`` (3,)."""
    s, rho1 = _pnorm2(abs(w0), abs(w1), q2)
    h, sig_s = _pnorm2(s, abs(w2), q1)
    hs = h * sig_s
    grad[0] = hs * rho1
    grad[1] = hs - grad[0]
    grad[2] = h - hs
    grad[0] /= w0 + math.copysign(_TINY, w0)
    grad[1] /= w1 + math.copysign(_TINY, w1)
    grad[2] /= w2 + math.copysign(_TINY, w2)
    return h


@njit(**_JIT)
def _ellipse(R, a, p, Rt, center, fx, fy, cx, cy, out):
    """Silhouette ellipse of the quadric (``e = 1``) in one camera (``_silhouette_ellipses``):
    ``out = [x0u, x0v, L00, L10, L11]``; returns whether it exists."""
    T = np.zeros((4, 4))
    for i in range(3):
        for j in range(3):
            T[i, j] = R[i, j] * a[j]
        T[i, 3] = p[i]
    T[3, 3] = 1.0
    Q = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            Q[i, j] = T[i, 0] * T[j, 0] + T[i, 1] * T[j, 1] + T[i, 2] * T[j, 2] - T[i, 3] * T[j, 3]
    P = np.zeros((3, 4))  # K [Rt | -Rt c]
    E = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            E[i, j] = Rt[i, j]
        E[i, 3] = -(Rt[i, 0] * center[0] + Rt[i, 1] * center[1] + Rt[i, 2] * center[2])
    for j in range(4):
        P[0, j] = fx * E[0, j] + cx * E[2, j]
        P[1, j] = fy * E[1, j] + cy * E[2, j]
        P[2, j] = E[2, j]
    C = _matmul(_matmul(P, Q), P.T.copy())  # the dual conic P Q* P^T
    lam = -C[2, 2]
    x0u, x0v = -C[0, 2] / lam, -C[1, 2] / lam
    s00 = C[0, 0] / lam + x0u * x0u
    s10 = C[1, 0] / lam + x0v * x0u
    s11 = C[1, 1] / lam + x0v * x0v
    l00 = math.sqrt(s00) if s00 >= 0 else np.nan
    l10 = s10 / l00
    r = s11 - l10 * l10
    l11 = math.sqrt(r) if r >= 0 else np.nan
    out[0], out[1], out[2], out[3], out[4] = x0u, x0v, l00, l10, l11
    return (lam > 0 and np.isfinite(l00) and np.isfinite(l10) and np.isfinite(l11) and l00 > 0 and l11 > 0)


@njit(**_JIT)
def silhouettes(xi, R_sq, rotations, centers, intrinsics, k, tol, max_newton, znear, e_min, e_max):
    """:func:`sqfit.geometry.silhouette.batch_silhouettes` without a start.

    ``xi`` ``(b, 11)``, ``R_sq`` ``(b, 3, 3)`` (``euler_to_matrix(xi[:, 8:11])``), cameras as
    ``camera_arrays`` -> ``polygons`` ``(b, v, k, 2)``, ``valid`` ``(b, v)`` bool.
    """
    b, v = xi.shape[0], rotations.shape[0]
    polys, valid, none = np.empty((b, v, k, 2)), np.zeros((b, v), dtype=np.bool_), np.empty((0, 0, 0, 3))
    _fill(xi, R_sq, rotations, centers, intrinsics, k, tol, max_newton, znear, e_min, e_max, polys, valid, none, none)
    return polys, valid


@njit(**_JIT)
def touching_silhouettes(xi, R_sq, rotations, centers, intrinsics, k, tol, max_newton, znear, e_min, e_max):
    """:func:`silhouettes` and their touching points, as ``batch_silhouettes(..., touching=True)`` returns
    them: ``polygons``, ``valid``, ``unit_points`` and ``points``, the last two ``(b, v, k, 3)`` (the
    unit superquadric's, superquadric frame; the camera frames') for
    :func:`sqfit.kernels.velocity_kernels.vertex_velocities`."""
    b, v = xi.shape[0], rotations.shape[0]
    polys, valid = np.empty((b, v, k, 2)), np.zeros((b, v), dtype=np.bool_)
    unit, points = np.empty((b, v, k, 3)), np.empty((b, v, k, 3))
    _fill(xi, R_sq, rotations, centers, intrinsics, k, tol, max_newton, znear, e_min, e_max, polys, valid, unit, points)
    return polys, valid, unit, points


@njit(**_JIT)
def _fill(xi, R_sq, rotations, centers, intrinsics, k, tol, max_newton, znear, e_min, e_max, polys, valid, unit,
          points):
    """The loop of :func:`silhouettes` into ``polys`` and ``valid``; the touching points too into ``unit``
    and ``points`` unless they are empty."""
    b, v = xi.shape[0], rotations.shape[0]
    touching = unit.shape[0] > 0
    M, Rt = np.empty((3, 3)), np.empty((3, 3))  # superquadric -> camera rotation, camera <- world
    a, c, wz = np.empty(3), np.empty(3), np.empty(3)
    ell, grad = np.empty(5), np.empty(3)
    for s in range(b):
        for j in range(3):
            a[j] = abs(xi[s, j])
        e1 = nan_min(nan_max(xi[s, 3], e_min), e_max)
        e2 = nan_min(nan_max(xi[s, 4], e_min), e_max)
        q1, q2 = 2.0 / (2.0 - e1), 2.0 / (2.0 - e2)
        for t in range(v):
            for i in range(3):
                for j in range(3):
                    Rt[i, j] = rotations[t, j, i]
            fx, fy, cx, cy = intrinsics[t, 0], intrinsics[t, 1], intrinsics[t, 2], intrinsics[t, 3]
            for i in range(3):
                for j in range(3):
                    M[i, j] = Rt[i, 0] * R_sq[s, 0, j] + Rt[i, 1] * R_sq[s, 1, j] + Rt[i, 2] * R_sq[s, 2, j]
                dp0, dp1, dp2 = xi[s, 5] - centers[t, 0], xi[s, 6] - centers[t, 1], xi[s, 7] - centers[t, 2]
                c[i] = Rt[i, 0] * dp0 + Rt[i, 1] * dp1 + Rt[i, 2] * dp2
            for j in range(3):
                wz[j] = a[j] * M[2, j]
            # nearest depth of the superquadric in this camera: c_z - h(-e_z)
            zmin = c[2] - _support(wz[0], wz[1], wz[2], q1, q2, grad)
            ok_view = np.isfinite(zmin) and zmin > znear
            cz = c[2] if ok_view else 1.0
            ok = _ellipse(R_sq[s], a, xi[s, 5:8], Rt, centers[t], fx, fy, cx, cy, ell)
            x0u, x0v, l00, l10, l11 = ell[0], ell[1], ell[2], ell[3], ell[4]
            finite = True
            for m in range(k):
                theta = 2.0 * np.pi * m / k
                bu, bv = math.cos(theta), math.sin(theta)
                if ok:  # L^-T u: evenly spread around the ellipse (_adapted_directions)
                    uu, uv = l11 * bu - l10 * bv, l00 * bv
                    norm = math.sqrt(uu * uu + uv * uv)
                    uu, uv = uu / norm, uv / norm
                else:
                    uu, uv = bu, bv
                n0, n1, n2 = uu * fx, uv * fy, uu * cx + uv * cy
                w0 = (n0 * M[0, 0] + n1 * M[1, 0] + n2 * M[2, 0]) * a[0]
                w1 = (n0 * M[0, 1] + n1 * M[1, 1] + n2 * M[2, 1]) * a[1]
                w2 = (n0 * M[0, 2] + n1 * M[1, 2] + n2 * M[2, 2]) * a[2]
                n0c = n0 * c[0] + n1 * c[1] + n2 * c[2]
                h = np.nan
                if ok:
                    p0, p1 = uu * l00 + uv * l10, uv * l11
                    h = uu * x0u + uv * x0v + math.sqrt(p0 * p0 + p1 * p1)
                if not np.isfinite(h):
                    h = n0c / (c[2] if c[2] > 0 else 1.0)
                # Newton on the support value until its own step is below tol (the numpy code stops
                # the whole batch when every step is: a vertex may take more steps there, moving it
                # by < tol); the vertex is the touching point of the last support value but one
                for it in range(max_newton):
                    hs = _support(w0 - h * wz[0], w1 - h * wz[1], w2 - h * wz[2], q1, q2, grad)
                    if not ok_view:  # an invalid silhouette takes no steps (its g may be NaN)
                        break
                    g = n0c - h * cz + hs
                    step = g / (cz + (grad[0] * wz[0] + grad[1] * wz[1] + grad[2] * wz[2]))
                    h = h + step
                    if not abs(step) > tol:
                        break
                g0, g1, g2 = grad[0] * a[0], grad[1] * a[1], grad[2] * a[2]
                px = c[0] + (g0 * M[0, 0] + g1 * M[0, 1] + g2 * M[0, 2])
                py = c[1] + (g0 * M[1, 0] + g1 * M[1, 1] + g2 * M[1, 2])
                pz = c[2] + (g0 * M[2, 0] + g1 * M[2, 1] + g2 * M[2, 2])
                z = pz if ok_view else 1.0
                polys[s, t, m, 0] = (fx * px + cx * pz) / z
                polys[s, t, m, 1] = (fy * py + cy * pz) / z
                finite = finite and np.isfinite(polys[s, t, m, 0]) and np.isfinite(polys[s, t, m, 1])
                if touching:
                    unit[s, t, m, 0], unit[s, t, m, 1], unit[s, t, m, 2] = grad[0], grad[1], grad[2]
                    points[s, t, m, 0], points[s, t, m, 1], points[s, t, m, 2] = px, py, pz
            valid[s, t] = ok_view and finite


# ------------------------------------------------------------------------------------------------
# convex IoU (sqfit.geometry.polygon.convex_overlap) and the hull observations


@njit(**_JIT)
def _overlap(S, Q, nq, cross_q, area_q, min_edge, lo_q, hi_q):
    """IoU of one convex CCW polygon ``S`` ``(k, 2)`` with ``Q`` ``(m, 2)`` (half-planes ``nq``,
    shoelace terms ``cross_q``, area ``area_q``); ``lo_q``, ``hi_q`` ``(m,)`` are scratch."""
    inter, area2_s = _overlap_area(S, Q, nq, cross_q, min_edge, lo_q, hi_q)
    union = 0.5 * area2_s + area_q - inter
    iou = inter / union if union > 0 else 0.0
    return nan_min(nan_max(iou, 0.0), 1.0) if np.isfinite(iou) else 0.0


@njit(**_JIT)
def _overlap_area(S, Q, nq, cross_q, min_edge, lo_q, hi_q):
    """``(area of S n Q, twice the area of S)`` of one convex CCW polygon ``S`` ``(k, 2)`` and ``Q``
    ``(m, 2)`` (:func:`_overlap`'s arguments)."""
    k, m = S.shape[0], Q.shape[0]
    for j in range(m):
        lo_q[j], hi_q[j] = 0.0, 1.0
    area2_s = 0.0
    inter_s = 0.0
    for i in range(k):
        sx, sy = S[i, 0], S[i, 1]
        nxt = i + 1 if i + 1 < k else 0
        dx, dy = S[nxt, 0] - sx, S[nxt, 1] - sy
        cross_s = sx * dy - sy * dx
        area2_s += cross_s
        free = -_TINY if dx * dx + dy * dy > min_edge * min_edge else 1.0
        t_lo, t_hi = 0.0, 1.0
        for j in range(m):
            Dx, Dy = Q[j, 0] - sx, Q[j, 1] - sy
            nqx, nqy = nq[j, 0], nq[j, 1]
            den = dx * nqx + dy * nqy - _TINY
            anti = nan_min(dy * nqx - dx * nqy, 0.0)
            t = (nqx * Dx + nqy * Dy + _TINY * anti) / den
            if den < 0:
                t_lo = nan_max(t_lo, t)
            else:
                t_hi = nan_min(t_hi, t)
            den2 = -2e-300 - den
            t2 = (dx * Dy - dy * Dx + free) / den2
            if den2 < 0:
                lo_q[j] = nan_max(lo_q[j], t2)
            else:
                hi_q[j] = nan_min(hi_q[j], t2)
        inter_s += nan_max(t_hi - t_lo, 0.0) * cross_s
    inter_q = 0.0
    for j in range(m):
        inter_q += nan_max(hi_q[j] - lo_q[j], 0.0) * cross_q[j]
    return 0.5 * (inter_s + inter_q), area2_s


@njit(**_JIT)
def convex_iou(polys, valid, targets, nq, cross_q, area_q, min_edge):
    """:func:`sqfit.geometry.polygon.batch_iou` (convex path): ``polys`` ``(b, v, k, 2)``, ``valid``
    ``(b, v)``, ``targets`` ``(v, m, 2)`` with their :func:`~sqfit.geometry.polygon.half_planes`
    -> IoU ``(b, v)``, 0 where not valid or not finite."""
    b, v, m = polys.shape[0], polys.shape[1], targets.shape[1]
    out = np.zeros((b, v))
    lo_q, hi_q = np.empty(m), np.empty(m)
    for s in range(b):
        for t in range(v):
            if valid[s, t]:
                out[s, t] = _overlap(polys[s, t], targets[t], nq[t], cross_q[t], area_q[t], min_edge, lo_q, hi_q)
    return out


@njit(**_JIT)
def clipped_iou(polys, valid, targets, nq, cross_q, area_q, frames, nr, cross_r, clip, hidden_inter, hidden_union,
                min_edge):
    """:func:`sqfit.geometry.visible_iou.clipped_convex_iou_jacobian`'s IoU of the views a fit sees
    only in part: ``polys`` ``(b, p, k, 2)``, ``valid`` ``(b, p)``, ``targets`` ``(p, m, 2)`` with
    their half-planes, ``frames`` ``(p, 4, 2)`` the image rectangles with theirs (``nr``,
    ``cross_r``), ``clip`` ``(p,)`` (clip the silhouette to the image), ``hidden_inter``,
    ``hidden_union`` ``(b, p)`` -> IoU ``(b, p)``, 0 where not valid or not finite (as
    :func:`sqfit.fitting.costs.visible_iou` sets it)."""
    b, p, m = polys.shape[0], polys.shape[1], targets.shape[1]
    out = np.zeros((b, p))
    lo_q, hi_q = np.empty(m), np.empty(m)
    lo_r, hi_r = np.empty(4), np.empty(4)
    for s in range(b):
        for t in range(p):
            if not valid[s, t]:
                continue
            inter, area2_s = _overlap_area(polys[s, t], targets[t], nq[t], cross_q[t], min_edge, lo_q, hi_q)
            if clip[t]:
                seen, _ = _overlap_area(polys[s, t], frames[t], nr[t], cross_r[t], min_edge, lo_r, hi_r)
            else:
                seen = 0.5 * area2_s
            num = nan_max(inter - hidden_inter[s, t], 0.0)
            union = seen + area_q[t] - inter - hidden_union[s, t]
            iou = num / union if union > 0 else 0.0
            out[s, t] = nan_min(nan_max(iou, 0.0), 1.0) if np.isfinite(iou) else 0.0
    return out


@njit(**_JIT)
def convex_hull(points):
    """Counter-clockwise convex hull of ``(n, 2)`` points without collinear vertices (Andrew's
    monotone chain) -> indices into ``points`` (fewer than 3 when the points are collinear)."""
    n = points.shape[0]
    by_y = np.argsort(points[:, 1], kind="mergesort")
    order = by_y[np.argsort(points[by_y, 0], kind="mergesort")]  # by x, then y
    hull = np.empty(2 * n + 1, dtype=np.int64)
    size = 0
    for sweep in range(2):
        base = size
        for step in range(n):
            i = order[step] if sweep == 0 else order[n - 1 - step]
            while size >= base + 2:
                o, a = hull[size - 2], hull[size - 1]
                cross = ((points[a, 0] - points[o, 0]) * (points[i, 1] - points[o, 1])
                         - (points[a, 1] - points[o, 1]) * (points[i, 0] - points[o, 0]))
                if cross > 0:
                    break
                size -= 1
            hull[size] = i
            size += 1
        size -= 1  # each chain's last point starts the other chain
    return hull[:size].copy() if size >= 3 else hull[:0].copy()


@njit(**_JIT)
def hidden_counts(S, points, in_q):
    """:func:`sqfit.geometry.visible_iou.hidden_counts`: silhouettes ``S`` ``(b, k, 2)`` (convex,
    CCW), ``points`` ``(n, 2)``, ``in_q`` ``(n,) bool`` -> ``(h_n, h_u)``, each ``(b,)`` float.
    A point outside a silhouette's bounding box is outside it without the edge tests; a silhouette
    with a non-finite vertex holds no point (as the numpy tests, whose comparisons are then false)."""
    b, k, n = S.shape[0], S.shape[1], points.shape[0]
    n_q = 0
    for j in range(n):
        if in_q[j]:
            n_q += 1
    inter, union = np.zeros(b), np.zeros(b)
    for s in range(b):
        lo_x, lo_y, hi_x, hi_y = np.inf, np.inf, -np.inf, -np.inf
        finite = True
        for i in range(k):
            x, y = S[s, i, 0], S[s, i, 1]
            if not (np.isfinite(x) and np.isfinite(y)):
                finite = False
            lo_x, hi_x, lo_y, hi_y = min(lo_x, x), max(hi_x, x), min(lo_y, y), max(hi_y, y)
        both = inside_s = 0
        for j in range(n):
            px, py = points[j, 0], points[j, 1]
            if not finite or px < lo_x or px > hi_x or py < lo_y or py > hi_y:
                continue
            inside = True
            for i in range(k):
                sx, sy = S[s, i, 0], S[s, i, 1]
                nxt = i + 1 if i + 1 < k else 0
                dx, dy = S[s, nxt, 0] - sx, S[s, nxt, 1] - sy
                if not (dx * (py - sy) - dy * (px - sx) >= 0.0):
                    inside = False
                    break
            if inside:
                inside_s += 1
                if in_q[j]:
                    both += 1
        inter[s], union[s] = both, inside_s + n_q - both
    return inter, union


@njit(**_JIT)
def points_in_convex(S, points):
    """:func:`sqfit.geometry.visible_iou.points_in_convex` of one convex CCW polygon ``S`` ``(k, 2)``:
    ``points`` ``(n, 2)`` -> ``(n,) bool``. A NaN vertex or point fails its tests, as in numpy."""
    k, n = S.shape[0], points.shape[0]
    inside = np.empty(n, dtype=np.bool_)
    for j in range(n):
        px, py = points[j, 0], points[j, 1]
        ok = True
        for i in range(k):
            sx, sy = S[i, 0], S[i, 1]
            nxt = i + 1 if i + 1 < k else 0
            dx, dy = S[nxt, 0] - sx, S[nxt, 1] - sy
            if not (dx * (py - sy) - dy * (px - sx) >= 0.0):
                ok = False
                break
        inside[j] = ok
    return inside


# the silhouettes' overlap with non-convex mask contours (stage 3T's R-IOU, shapely otherwise)


@njit(**_JIT)
def convex_sign(S, tol):
    """+1 or -1, the orientation of polygon ``S`` ``(k, 2)`` if it is convex and simple (each
    non-degenerate edge turns the same way from the one before, within ``tol`` of their lengths'
    product, and the turns add up to one full turn), else 0 (also for a non-finite vertex or no area)."""
    k = S.shape[0]
    for i in range(k):
        if not (np.isfinite(S[i, 0]) and np.isfinite(S[i, 1])):
            return 0.0
    area2 = _shoelace2(S, k)
    if not area2 != 0.0:
        return 0.0
    sign = 1.0 if area2 > 0 else -1.0
    px = py = 0.0
    for i in range(k - 1, -1, -1):  # the last non-degenerate edge comes before the first
        j = i + 1 if i + 1 < k else 0
        px, py = S[j, 0] - S[i, 0], S[j, 1] - S[i, 1]
        if px != 0.0 or py != 0.0:
            break
    turned = 0.0
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        ex, ey = S[j, 0] - S[i, 0], S[j, 1] - S[i, 1]
        if ex == 0.0 and ey == 0.0:
            continue
        cross = sign * (px * ey - py * ex)
        if cross < -tol * math.sqrt((px * px + py * py) * (ex * ex + ey * ey)):
            return 0.0
        turned += math.atan2(cross, px * ex + py * ey)
        px, py = ex, ey
    return sign if abs(turned - 2.0 * math.pi) <= 1e-6 else 0.0


@njit(**_JIT)
def _clip_half_plane(src, n, ax, ay, ex, ey, sign, dst):
    """Sutherland-Hodgman: the part of polygon ``src[:n]`` where ``sign * cross(e, p - a) >= 0`` into
    ``dst`` (at least ``2 n`` rows); returns its vertex count."""
    m = 0
    px, py = src[n - 1, 0], src[n - 1, 1]
    dp = sign * (ex * (py - ay) - ey * (px - ax))
    for i in range(n):
        qx, qy = src[i, 0], src[i, 1]
        dq = sign * (ex * (qy - ay) - ey * (qx - ax))
        if dq >= 0.0:
            if dp < 0.0:
                t = dp / (dp - dq)
                dst[m, 0], dst[m, 1] = px + t * (qx - px), py + t * (qy - py)
                m += 1
            dst[m, 0], dst[m, 1] = qx, qy
            m += 1
        elif dp > 0.0:
            t = dp / (dp - dq)
            dst[m, 0], dst[m, 1] = px + t * (qx - px), py + t * (qy - py)
            m += 1
        px, py, dp = qx, qy, dq
    return m


@njit(**_JIT)
def clip_convex(cur, n, C, sign, other):
    """``cur[:n]`` clipped by each edge of the convex polygon ``C`` of orientation ``sign``, ping-pong
    with ``other`` (grown as needed) -> ``(buffer, count, the other buffer)``."""
    k = C.shape[0]
    for i in range(k):
        if n == 0:
            break
        j = i + 1 if i + 1 < k else 0
        ex, ey = C[j, 0] - C[i, 0], C[j, 1] - C[i, 1]
        if ex == 0.0 and ey == 0.0:
            continue
        if other.shape[0] < 2 * n:
            other = np.empty((4 * n, 2))
        n = _clip_half_plane(cur, n, C[i, 0], C[i, 1], ex, ey, sign, other)
        cur, other = other, cur
    return cur, n, other


@njit(**_JIT)
def _shoelace2(P, n):
    """Twice the signed shoelace area of ``P[:n]``."""
    area2 = 0.0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        area2 += P[i, 0] * P[j, 1] - P[i, 1] * P[j, 0]
    return area2


@njit(**_JIT)
def polygon_area(P, n):
    """Absolute shoelace area of ``P[:n]``."""
    return 0.5 * abs(_shoelace2(P, n))


@njit(**_JIT)
def clip_buffers(starts, k):
    """Two ping-pong buffers for clipping any of the contours (``starts`` as :func:`contour_overlaps`
    takes them) or a polygon of ``k`` vertices."""
    longest = max(4, k)
    for t in range(starts.shape[0] - 1):
        longest = max(longest, starts[t + 1] - starts[t])
    return np.empty((4 * longest, 2)), np.empty((4 * longest, 2))


@njit(**_JIT)
def clipped_contour(contours, lo, hi, S, sign, cur, other):
    """The contour ``contours[lo:hi]`` clipped by the convex polygon ``S`` of orientation ``sign``
    (:func:`clip_convex`) -> ``(buffer, count, the other buffer)``."""
    for i in range(lo, hi):
        cur[i - lo, 0], cur[i - lo, 1] = contours[i, 0], contours[i, 1]
    return clip_convex(cur, hi - lo, S, sign, other)


@njit(**_JIT)
def contour_overlaps(polys, pairs, contours, starts, frames, clip, tol):
    """Overlap of silhouettes with mask contours, for shapely's ``intersection`` in
    :func:`sqfit.fitting.costs.visible_iou`'s contour path: ``polys`` ``(b, v, k, 2)``, ``pairs``
    ``(p, 2)`` ``(batch, view)`` indices, ``contours`` ``(M, 2)`` every view's contour (a simple
    polygon) stacked, view ``t``'s at ``starts[t]:starts[t + 1]``, ``frames`` ``(v, 4, 2)`` the
    image rectangles, ``clip`` ``(v,) bool`` (count only the silhouette's part in the image) ->
    ``(inter, area, ok)``, each ``(p,)``: the area of (silhouette, clipped where asked) ∩ contour,
    the (clipped) silhouette's area, and whether the silhouette is convex and simple
    (:func:`convex_sign` with ``tol``); where not, ``inter`` and ``area`` are 0 and the caller
    asks shapely. Sutherland-Hodgman clipping of the contour by the silhouette's edges (a convex
    clip polygon: the clipped polygon's shoelace area is the intersection's, degenerate edges
    adding none), then by the frame's."""
    count = pairs.shape[0]
    inter, area, ok = np.zeros(count), np.zeros(count), np.zeros(count, dtype=np.bool_)
    cur, other = clip_buffers(starts, 0)
    for p in range(count):
        s, t = pairs[p, 0], pairs[p, 1]
        S = polys[s, t]
        sign = convex_sign(S, tol)
        if sign == 0.0:
            continue
        ok[p] = True
        F = frames[t]
        k = S.shape[0]
        if clip[t]:
            frame_sign = 1.0 if _shoelace2(F, F.shape[0]) > 0 else -1.0
            if cur.shape[0] < 2 * k:
                cur, other = np.empty((4 * k, 2)), np.empty((4 * k, 2))
            for i in range(k):
                cur[i, 0], cur[i, 1] = S[i, 0], S[i, 1]
            cur, n, other = clip_convex(cur, k, F, frame_sign, other)
            area[p] = polygon_area(cur, n)
        else:
            area[p] = polygon_area(S, k)
        cur, n, other = clipped_contour(contours, starts[t], starts[t + 1], S, sign, cur, other)
        if clip[t] and n:
            cur, n, other = clip_convex(cur, n, F, frame_sign, other)
        inter[p] = polygon_area(cur, n)
    return inter, area, ok
