"""Compiled (numba) kernels of the ray minimisers, the 3G residuals and the radial terms.

The same formulas as the numpy code, written per ray / per point: :func:`gauge_minima` is
``sqfit.fitting.line_gauge.gauge_minima``, :func:`ray_rows` is :func:`sqfit.fitting.raycost.batch_ray_residuals`
with the ray solve fused in, :func:`posed_rows` is :func:`sqfit.fitting.raycost.posed_ray_residuals`,
:func:`radial_rows` is ``sqfit.fitting.costs._radial_core``, :func:`g5_rows` is
:func:`sqfit.fitting.costs.g5_residuals` and :func:`log_gauge_rows` is
:func:`sqfit.fitting.raycost.batch_log_gauge_jacobian`; :func:`crossing_fix` is
:func:`sqfit.fitting.raycost.crossing_correction` for one ray. Stage 3H's screen, a loop of these
rows, is :mod:`sqfit.kernels.screen_kernels`. Same operations in the same order wherever the
numpy code does not sum through BLAS, so the two agree to rounding (tests: residuals and
Jacobians to 1e-12). No ``fastmath``: it would reorder them.

Importing this module imports numba; :mod:`sqfit.kernels.backend` does that lazily. Every kernel is
compiled on first use and cached next to this file (``cache=True``), cleared when any kernel source
changed (:mod:`sqfit.kernels.kernel_cache`: numba's own check sees only a kernel's own file). Arrays
in are C-contiguous float64 (``int64`` / ``bool`` where noted), so each kernel compiles one
specialisation.
Constants of the numpy code (bounds, tolerances) are passed in as arguments, never copied here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .kernel_cache import refresh_for

__all__ = ["nan_max", "nan_min", "logaddexp", "ray_minimiser", "gauge_minima", "rotation", "log_gauge_point",
           "crossing_fix", "ray_block", "penalty_rows", "ray_rows", "posed_rows", "radial_rows", "g5_rows",
           "log_gauge_rows"]

_TINY = 1e-300
_LOGE2 = math.log(2.0)
_JIT = dict(cache=True, error_model="numpy", nogil=True)

# ------------------------------------------------------------------------------------------------
# scalar helpers with numpy's NaN semantics (Python's max / min drop a NaN argument)


@njit(**_JIT)
def nan_max(a, b):
    """``np.maximum`` of two floats (a NaN wins)."""
    return a if (a >= b or a != a) else b


@njit(**_JIT)
def nan_min(a, b):
    """``np.minimum`` of two floats (a NaN wins)."""
    return a if (a <= b or a != a) else b


@njit(**_JIT)
def logaddexp(x, y):
    """``np.logaddexp`` of two floats (its branches: equal arguments, infinities, NaN)."""
    if x == y:
        return x + _LOGE2
    t = x - y
    if t > 0:
        return x + math.log1p(math.exp(-t))
    if t <= 0:
        return y + math.log1p(math.exp(t))
    return t


@njit(**_JIT)
def _nz(x):
    return _TINY if x == 0.0 else x


# ------------------------------------------------------------------------------------------------
# the ray minimiser (sqfit.fitting.line_gauge.gauge_minima, one ray at a time)


@njit(**_JIT)
def _logs(q0x, q0y, q0z, ux, uy, uz, d):
    qx, qy, qz = _nz(q0x + d * ux), _nz(q0y + d * uy), _nz(q0z + d * uz)
    return math.log(abs(qx)), math.log(abs(qy)), math.log(abs(qz)), ux / qx, uy / qy, uz / qz


@njit(**_JIT)
def _line_value(q0x, q0y, q0z, ux, uy, uz, d, e1, e2):
    """``log g`` along a line (``sqfit.fitting.line_gauge._line_log_gauge``, first output)."""
    qx, qy, qz = _nz(q0x + d * ux), _nz(q0y + d * uy), _nz(q0z + d * uz)
    p1, p2 = 2.0 / e1, 2.0 / e2
    sx, sy, sz = math.log(abs(qx)), math.log(abs(qy)), math.log(abs(qz))
    XY = p2 * nan_max(sx, sy) + math.log1p(math.exp(-abs(p2 * (sx - sy))))
    A, Bz = (p1 / p2) * XY, p1 * sz
    return (nan_max(A, Bz) + math.log1p(math.exp(-abs(A - Bz)))) / p1


@njit(**_JIT)
def _weights(x, t):
    """``sqfit.fitting.line_gauge._weights`` for one ``x`` (``t = exp(-|x|)``)."""
    big, small = 1.0 / (1.0 + t), t / (1.0 + t)
    return (big, small) if x >= 0 else (small, big)


@njit(**_JIT)
def _line_slope(q0x, q0y, q0z, ux, uy, uz, d, e1, e2):
    """First and second derivative in ``d`` of ``log g`` along a line (``sqfit.fitting.line_gauge._line_log_gauge``;
    its softmax weights and their complements each as ``1 / (1 + t)`` or ``t / (1 + t)``, sharing the
    exponential ``t`` with the log-sum-exp, and each term as weight times ``k``: see there)."""
    sx, sy, sz, kx, ky, kz = _logs(q0x, q0y, q0z, ux, uy, uz, d)
    p1, p2 = 2.0 / e1, 2.0 / e2
    dx = p2 * (sx - sy)
    t = math.exp(-abs(dx))
    wx, wy = _weights(dx, t)
    XY = p2 * nan_max(sx, sy) + math.log1p(t)
    dA = (p1 / p2) * XY - p1 * sz
    t = math.exp(-abs(dA))
    wA, wB = _weights(dA, t)
    cx, cy, cz = wx * kx, wy * ky, wB * kz
    K1 = cx + cy
    K2 = cx * kx + cy * ky
    lg1 = wA * K1 + cz
    lg2 = wA * ((p2 - 1.0) * K2 - p2 * K1 * K1) - cz * kz + p1 * wA * (wB * K1 - cz) * (K1 - kz)
    return lg1, lg2


@njit(**_JIT)
def ray_minimiser(q0x, q0y, q0z, ux, uy, uz, r0x, r0y, r0z, lx, ly, lz, ratio, e1, e2, d0, warm, rtol, max_newton,
                  max_warm, grid, znear, warm_bracket, newton_power):
    """Minimiser ``d`` of ``log g`` along one ray (:func:`sqfit.fitting.line_gauge.ray_minima`); the
    residual kernels evaluate the gauge there with its derivatives, so returning the value there
    would cost them a seventh of each ray's logarithms and exponentials for nothing."""
    bb = lx * lx + ly * ly + lz * lz
    dc = -(r0x * lx + r0y * ly + r0z * lz) / bb
    cx, cy, cz = r0x + dc * lx, r0y + dc * ly, r0z + dc * lz
    rho = math.sqrt(cx * cx + cy * cy + cz * cz)
    half = 1.01 * 3.0 * rho * ratio / math.sqrt(bb) + 1e-9 * (abs(dc) + 1.0)
    lo = nan_max(dc - half, znear)
    hi = nan_max(dc + half, 2.0 * znear)
    tol = rtol * (abs(dc) + 1.0)
    cold = True
    if warm:
        dw = lo if d0 < lo else (hi if d0 > hi else d0)
        delta = warm_bracket * (abs(dw) + 1.0)
        plo, phi = nan_max(dw - delta, lo), nan_min(dw + delta, hi)
        s_lo = _line_slope(q0x, q0y, q0z, ux, uy, uz, plo, e1, e2)[0]
        s_hi = _line_slope(q0x, q0y, q0z, ux, uy, uz, phi, e1, e2)[0]
        if s_lo <= 0 and s_hi >= 0:
            lo, hi, cold = plo, phi, False
    d = 0.5 * (lo + hi)
    if cold and len(grid) == 0:
        # no grid: start at the line's point nearest the centre in unit coordinates (the
        # minimiser for a sphere there); g is unimodal along a line, so Newton and bisection
        # from any point of the bracket reach the one minimum
        uu = ux * ux + uy * uy + uz * uz
        dn = -(q0x * ux + q0y * uy + q0z * uz) / uu
        if dn == dn:
            d = lo if dn < lo else (hi if dn > hi else dn)
    elif cold:
        G = len(grid)
        width = hi - lo
        best, best_v = 0, _line_value(q0x, q0y, q0z, ux, uy, uz, lo + width * grid[0], e1, e2)
        if best_v == best_v:
            for j in range(1, G):
                v = _line_value(q0x, q0y, q0z, ux, uy, uz, lo + width * grid[j], e1, e2)
                if v != v:  # np.argmin stops at the first NaN
                    best = j
                    break
                if v < best_v:
                    best, best_v = j, v
        d = lo + width * grid[best]
        lo, hi = lo + width * grid[max(best - 1, 0)], lo + width * grid[min(best + 1, G - 1)]
    budget = max_newton if cold else max_warm
    dd, dx, dx_old = d, hi - lo, hi - lo
    for it in range(1, max(max_newton, max_warm) + 1):
        lg1, lg2 = _line_slope(q0x, q0y, q0z, ux, uy, uz, dd, e1, e2)
        if lg1 < 0:
            lo = dd
        else:
            hi = dd
        step = -lg1 / (lg2 + newton_power * lg1 * lg1)
        new = dd + step
        if not np.isfinite(new) or new < lo or new > hi or abs(step) > 0.5 * abs(dx_old):
            new = 0.5 * (lo + hi)
        dx_old, dx = dx, abs(new - dd)
        d = new
        if not (dx > tol and hi - lo > tol and budget > it):
            break
        dd = new
    return d


@njit(**_JIT)
def gauge_minima(q0, u, rel0, ul, ratio, e1, e2, d0, warm, rtol, max_newton, max_warm, grid, znear, warm_bracket,
                 newton_power):
    """``sqfit.fitting.line_gauge.gauge_minima``: ``q0``, ``u`` ``(3, n)``; ``rel0``, ``ul`` ``(n, 3)``;
    ``ratio``, ``e1``, ``e2``, ``d0`` ``(n,)`` (``d0`` read only if ``warm``). Returns ``d``,
    ``log_m`` ``(n,)``."""
    n = rel0.shape[0]
    d, log_m = np.empty(n), np.empty(n)
    for i in range(n):
        d[i] = ray_minimiser(q0[0, i], q0[1, i], q0[2, i], u[0, i], u[1, i], u[2, i], rel0[i, 0], rel0[i, 1],
                             rel0[i, 2], ul[i, 0], ul[i, 1], ul[i, 2], ratio[i], e1[i], e2[i],
                             d0[i] if warm else 0.0, warm, rtol, max_newton, max_warm, grid, znear,
                             warm_bracket, newton_power)
        log_m[i] = _line_value(q0[0, i], q0[1, i], q0[2, i], u[0, i], u[1, i], u[2, i], d[i], e1[i], e2[i])
    return d, log_m


# ------------------------------------------------------------------------------------------------
# rotation and radial terms (sqfit.geometry.superquadric.rotation_and_derivatives, sqfit.fitting.costs._radial_core)


@njit(**_JIT)
def rotation(r):
    """``R`` ``(3, 3)`` and ``dR`` ``(3, 9)`` (``dR[k]`` is ``dR / dr_k`` flattened row-major)."""
    cx, cy, cz = math.cos(r[0]), math.cos(r[1]), math.cos(r[2])
    sx, sy, sz = math.sin(r[0]), math.sin(r[1]), math.sin(r[2])
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
    R[1, 0], R[1, 1], R[1, 2] = sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx
    R[2, 0], R[2, 1], R[2, 2] = -sy, cy * sx, cy * cx
    dR = np.zeros((3, 9))
    dR[0, 1], dR[0, 2] = cz * sy * cx + sz * sx, -cz * sy * sx + sz * cx
    dR[0, 4], dR[0, 5] = sz * sy * cx - cz * sx, -sz * sy * sx - cz * cx
    dR[0, 7], dR[0, 8] = cy * cx, -cy * sx
    dR[1, 0], dR[1, 1], dR[1, 2] = -cz * sy, cz * cy * sx, cz * cy * cx
    dR[1, 3], dR[1, 4], dR[1, 5] = -sz * sy, sz * cy * sx, sz * cy * cx
    dR[1, 6], dR[1, 7], dR[1, 8] = -cy, -sy * sx, -sy * cx
    dR[2, 0], dR[2, 1], dR[2, 2] = -sz * cy, -sz * sy * sx - cz * cx, -sz * sy * cx + cz * sx
    dR[2, 3], dR[2, 4], dR[2, 5] = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
    return R, dR


@njit(**_JIT)
def _wmul(w, x):
    """``w * x`` with ``0 * -inf = 0`` (``sqfit.fitting.costs._wmul``)."""
    return w * (x if np.isfinite(x) else 0.0) if w > 0 else 0.0


@njit(**_JIT)
def _dot3(R, i, x, y, z):
    """``(x, y, z) . R[:, i]``: coordinate ``i`` of a world vector in the superquadric frame."""
    return x * R[0, i] + y * R[1, i] + z * R[2, i]


@njit(**_JIT)
def _radial_point(xi, log_a, R, dR, px, py, pz, d_xi, d_point):
    """G3 of one world point; writes ``d g3 / d xi`` into ``d_xi`` ``(11,)`` and ``d g3 / d point``
    into ``d_point`` ``(3,)``; returns ``g3``. ``log_a`` ``(3,)`` is ``log|a|`` (once per
    superquadric). Scalars only: no array is allocated per point."""
    rx, ry, rz = px - xi[5], py - xi[6], pz - xi[7]
    y0, y1, y2 = _nz(_dot3(R, 0, rx, ry, rz)), _nz(_dot3(R, 1, rx, ry, rz)), _nz(_dot3(R, 2, rx, ry, rz))
    e1, e2 = xi[3], xi[4]
    norm2 = y0 * y0 + y1 * y1 + y2 * y2
    la0 = math.log(abs(y0)) - log_a[0]
    la1 = math.log(abs(y1)) - log_a[1]
    la2 = math.log(abs(y2)) - log_a[2]
    X0, X1 = (2.0 / e2) * la0, (2.0 / e2) * la1
    XY = logaddexp(X0, X1)
    w0, w1 = math.exp(X0 - XY), math.exp(X1 - XY)
    A, Bz = (e2 / e1) * XY, (2.0 / e1) * la2
    L = logaddexp(A, Bz)
    wA = math.exp(A - L)
    wB = 1.0 - wA
    S = math.exp(0.5 * (math.log(norm2) - e1 * L))
    norm = math.sqrt(norm2)
    dl0, dl1, dl2 = w0 * wA, w1 * wA, wB
    half_S = 0.5 * S
    c = (S - norm) / norm2
    dy0 = c * y0 - half_S * (2.0 * dl0) / y0
    dy1 = c * y1 - half_S * (2.0 * dl1) / y1
    dy2 = c * y2 - half_S * (2.0 * dl2) / y2
    d_xi[0], d_xi[1], d_xi[2] = S * dl0 / xi[0], S * dl1 / xi[1], S * dl2 / xi[2]
    de1 = L - wA * A - wB * Bz
    de2 = XY - w0 * X0 - w1 * X1
    if not (np.isfinite(de1) and np.isfinite(de2)):
        de1 = L - _wmul(wA, A) - _wmul(wB, Bz)
        de2 = XY - _wmul(w0, X0) - _wmul(w1, X1)
    d_xi[3] = -half_S * de1
    d_xi[4] = -half_S * wA * de2
    for j in range(3):
        d_point[j] = dy0 * R[j, 0] + dy1 * R[j, 1] + dy2 * R[j, 2]
        d_xi[5 + j] = -d_point[j]
    for k in range(3):
        d_xi[8 + k] = (rx * dy0 * dR[k, 0] + rx * dy1 * dR[k, 1] + rx * dy2 * dR[k, 2]
                       + ry * dy0 * dR[k, 3] + ry * dy1 * dR[k, 4] + ry * dy2 * dR[k, 5]
                       + rz * dy0 * dR[k, 6] + rz * dy1 * dR[k, 7] + rz * dy2 * dR[k, 8])
    return S - norm


@njit(**_JIT)
def radial_rows(xi, points):
    """``sqfit.fitting.costs.radial_terms``: ``xi`` ``(11,)``, ``points`` ``(n, 3)`` -> ``g3`` ``(n,)``,
    ``d_xi`` ``(n, 11)``, ``d_point`` ``(n, 3)``."""
    n = points.shape[0]
    R, dR = rotation(xi[8:11])
    log_a = np.log(np.abs(xi[0:3]))
    g3, d_xi, d_point = np.empty(n), np.empty((n, 11)), np.empty((n, 3))
    for i in range(n):
        g3[i] = _radial_point(xi, log_a, R, dR, points[i, 0], points[i, 1], points[i, 2], d_xi[i], d_point[i])
    return g3, d_xi, d_point


@njit(**_JIT)
def g5_rows(xi, depths, origins, rays, scaled, weight, lower, upper):
    """``sqfit.fitting.costs.g5_residuals``: ``xi`` ``(11,)``, ``depths`` ``(n,)``, ``origins`` and
    ``rays`` ``(n, 3)`` -> ``r`` ``(n + 11,)``, ``A`` ``(n, 11)``, ``D`` ``(n,)``, ``P`` ``(11,)``
    (sample points, radial terms, volume factor and penalty in one pass)."""
    n = depths.shape[0]
    R, dR = rotation(xi[8:11])
    log_a = np.log(np.abs(xi[0:3]))
    r, A, D, P = np.empty(n + 11), np.empty((n, 11)), np.empty(n), np.empty(11)
    d_point = np.empty(3)
    vol = xi[0] * xi[1] * xi[2]
    scale = vol + 1.0
    per_size = np.empty(3)
    for j in range(3):
        per_size[j] = vol / (_TINY if xi[j] == 0 else xi[j])
    for i in range(n):
        d = depths[i]
        g3 = _radial_point(xi, log_a, R, dR, origins[i, 0] + rays[i, 0] * d, origins[i, 1] + rays[i, 1] * d,
                           origins[i, 2] + rays[i, 2] * d, A[i], d_point)
        Di = d_point[0] * rays[i, 0] + d_point[1] * rays[i, 1] + d_point[2] * rays[i, 2]
        if scaled:
            for j in range(11):
                A[i, j] *= scale
            for j in range(3):
                A[i, j] += g3 * per_size[j]
            Di *= scale
            g3 = g3 * scale
        r[i], D[i] = g3, Di
    for j in range(11):  # the penalty rows and the diagonal of their Jacobian (as _penalty_rows)
        r[n + j] = weight * (nan_max(lower[j] - xi[j], 0.0) + nan_max(xi[j] - upper[j], 0.0))
        P[j] = weight * ((1.0 if xi[j] > upper[j] else 0.0) - (1.0 if xi[j] < lower[j] else 0.0))
    return r, A, D, P


@njit(**_JIT)
def log_gauge_point(xi, log_a, R, dR, px, py, pz, out, d_g3, d_point):
    """``log g`` of one world point; ``d log g / d xi`` into ``out`` ``(11,)`` (scratch ``d_g3``
    ``(11,)``, ``d_point`` ``(3,)``); see :func:`sqfit.fitting.raycost.log_gauge_jacobian`."""
    g3 = _radial_point(xi, log_a, R, dR, px, py, pz, d_g3, d_point)
    rx, ry, rz = px - xi[5], py - xi[6], pz - xi[7]
    norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    rnorm = norm if norm > 0 else _TINY
    S_ = g3 + rnorm
    for j in range(11):
        out[j] = -d_g3[j] / S_
    dn = -rx / rnorm
    out[5] = dn / rnorm - (d_g3[5] + dn) / S_
    dn = -ry / rnorm
    out[6] = dn / rnorm - (d_g3[6] + dn) / S_
    dn = -rz / rnorm
    out[7] = dn / rnorm - (d_g3[7] + dn) / S_
    return math.log(rnorm) - math.log(S_)


@njit(**_JIT)
def log_gauge_rows(X, points):
    """:func:`sqfit.fitting.raycost.batch_log_gauge_jacobian`: ``X`` ``(b, 11)``, ``points`` ``(b, n, 3)``
    -> ``log_g`` ``(b, n)``, ``d_xi`` ``(b, n, 11)``."""
    b, n = points.shape[0], points.shape[1]
    log_g, d_xi = np.empty((b, n)), np.empty((b, n, 11))
    d_g3, d_point = np.empty(11), np.empty(3)
    for s in range(b):
        R, dR = rotation(X[s, 8:11])
        log_a = np.log(np.abs(X[s, 0:3]))
        for i in range(n):
            log_g[s, i] = log_gauge_point(X[s], log_a, R, dR, points[s, i, 0], points[s, i, 1], points[s, i, 2], d_xi[s, i],
                                           d_g3, d_point)
    return log_g, d_xi


@njit(**_JIT)
def crossing_fix(xi, R, dR, px, py, pz, bx, by, bz, out, tol, parallel):
    """:func:`sqfit.fitting.raycost.crossing_correction` of one ray: ``out`` ``(11,)``, ``d log g / d xi``
    at the ray's minimiser ``(px, py, pz)`` (world), corrected in place where that point lies on a
    coordinate plane of the superquadric whose power is below 2; ``(bx, by, bz)`` the ray's world
    direction."""
    rx, ry, rz = px - xi[5], py - xi[6], pz - xi[7]
    lx, ly, lz = _dot3(R, 0, bx, by, bz), _dot3(R, 1, bx, by, bz), _dot3(R, 2, bx, by, bz)
    ax, ay, az = abs(xi[0]), abs(xi[1]), abs(xi[2])
    reach = parallel * math.sqrt((lx / ax) ** 2 + (ly / ay) ** 2 + (lz / az) ** 2)
    plane, planes, across = -1, 0, 0.0
    for j in range(3):
        a, lj = abs(xi[j]), (lx, ly, lz)[j]
        if abs(_dot3(R, j, rx, ry, rz)) / a < tol:
            planes += 1
            if (xi[4] if j < 2 else xi[3]) > 1.0 and abs(lj) / a > reach:  # |y_j|^(2 / e), 2 / e < 2
                plane, across = j, lj
    if plane < 0 or planes > 1:  # off every plane, or on an axis (two planes): as it was
        return
    c = -(out[5] * bx + out[6] * by + out[7] * bz) / across  # the slope along the ray over d y_j / d d
    for m in range(3):
        out[5 + m] += c * R[m, plane]
    for k in range(3):
        out[8 + k] -= c * (rx * dR[k, plane] + ry * dR[k, 3 + plane] + rz * dR[k, 6 + plane])


# ------------------------------------------------------------------------------------------------
# 3G residuals (sqfit.fitting.raycost.batch_ray_residuals / posed_ray_residuals)


@njit(**_JIT)
def ray_block(xi, origins, directions, weights, kind, d0, warm, rtol, max_newton, max_warm, grid, znear,
               warm_bracket, newton_power, crossing_tol, crossing_parallel, r, J, d):
    """Weighted ray residuals of one superquadric into ``r`` ``(n,)``, their Jacobian into ``J``
    ``(n, 11)`` and the minimisers into ``d`` ``(n,)``.

    ``kind`` ``(n,) int64``: 0 two-sided, 1 active where ``phi > 0`` (INSIDE and one-sided
    CONTOUR rays), 2 active where ``phi < 0`` (two-sided OUTSIDE), 3 never (one-sided OUTSIDE).
    """
    R, dR = rotation(xi[8:11])
    log_a = np.log(np.abs(xi[0:3]))
    ax, ay, az = nan_max(abs(xi[0]), _TINY), nan_max(abs(xi[1]), _TINY), nan_max(abs(xi[2]), _TINY)
    ratio = max(ax, ay, az) / min(ax, ay, az)
    d_g3, d_point = np.empty(11), np.empty(3)
    for i in range(origins.shape[0]):
        ox, oy, oz = origins[i, 0] - xi[5], origins[i, 1] - xi[6], origins[i, 2] - xi[7]
        bx, by, bz = directions[i, 0], directions[i, 1], directions[i, 2]
        r0x = ox * R[0, 0] + oy * R[1, 0] + oz * R[2, 0]
        r0y = ox * R[0, 1] + oy * R[1, 1] + oz * R[2, 1]
        r0z = ox * R[0, 2] + oy * R[1, 2] + oz * R[2, 2]
        lx = bx * R[0, 0] + by * R[1, 0] + bz * R[2, 0]
        ly = bx * R[0, 1] + by * R[1, 1] + bz * R[2, 1]
        lz = bx * R[0, 2] + by * R[1, 2] + bz * R[2, 2]
        di = ray_minimiser(r0x / ax, r0y / ay, r0z / az, lx / ax, ly / ay, lz / az, r0x, r0y, r0z, lx, ly, lz,
                           ratio, xi[3], xi[4], d0[i] if warm else 0.0, warm, rtol, max_newton, max_warm, grid, znear,
                           warm_bracket, newton_power)
        d[i] = di
        px, py, pz = origins[i, 0] + di * bx, origins[i, 1] + di * by, origins[i, 2] + di * bz
        log_m = log_gauge_point(xi, log_a, R, dR, px, py, pz, J[i], d_g3, d_point)
        crossing_fix(xi, R, dR, px, py, pz, bx, by, bz, J[i], crossing_tol, crossing_parallel)
        if log_m < 0:
            phi, dphi = math.exp(nan_min(log_m, 0.0)) - 1.0, math.exp(nan_min(log_m, 0.0))
        else:
            phi, dphi = log_m, 1.0
        k = kind[i]
        active = 1.0 if (k == 0 or (k == 1 and phi > 0) or (k == 2 and phi < 0)) else 0.0
        scale = weights[i] * active
        r[i] = scale * phi
        coef = scale * dphi
        for j in range(11):
            J[i, j] = coef * J[i, j]


@njit(**_JIT)
def penalty_rows(xi, weight, lower, upper, r, J, row):
    for j in range(11):
        r[row + j] = weight * (nan_max(lower[j] - xi[j], 0.0) + nan_max(xi[j] - upper[j], 0.0))
        J[row + j, j] = weight * ((1.0 if xi[j] > upper[j] else 0.0) - (1.0 if xi[j] < lower[j] else 0.0))


@njit(**_JIT)
def ray_rows(X, origins, directions, weights, kind, d0, warm, rtol, max_newton, max_warm, grid, znear, warm_bracket,
             newton_power, crossing_tol, crossing_parallel, weight, lower, upper):
    """:func:`sqfit.fitting.raycost.batch_ray_residuals`: ``X`` ``(b, 11)``, rays ``(n, 3)``, ``d0``
    ``(b, n)`` (read only if ``warm``) -> ``r`` ``(b, n + 11)``, ``J`` ``(b, n + 11, 11)``, ``d``
    ``(b, n)``."""
    b, n = X.shape[0], origins.shape[0]
    r, J, d = np.empty((b, n + 11)), np.zeros((b, n + 11, 11)), np.empty((b, n))
    for s in range(b):
        ray_block(X[s], origins, directions, weights, kind, d0[s] if warm else d[s], warm, rtol, max_newton,
                   max_warm, grid, znear, warm_bracket, newton_power, crossing_tol, crossing_parallel, r[s], J[s],
                   d[s])
        penalty_rows(X[s], weight, lower, upper, r[s], J[s], n)
    return r, J, d


@njit(**_JIT)
def posed_rows(x, origins, directions, offsets, weights, radii, kind, view, group, n_pose, d0, warm, rtol,
               max_newton, max_warm, grid, znear, warm_bracket, newton_power, crossing_tol, crossing_parallel, weight,
               lower, upper, sigma, offset_prior):
    """:func:`sqfit.fitting.raycost.posed_ray_residuals`: ``x`` ``(11 + p + g,)`` (``n_pose = p``, 0 or
    ``3 v``; ``g`` outline offsets, prior rows ``offset_prior @ o``, ``(g, g)``), ``offsets`` ``(n, 3)``,
    ``radii`` ``(n,)``, ``view`` and ``group`` ``(n,) int64`` -> ``r`` ``(n + 11 + p + g,)``, ``J``
    ``(n + 11 + p + g, 11 + p + g)``, ``d`` ``(n,)``."""
    n, k = origins.shape[0], 11
    m = x.shape[0] - k
    n_off = m - n_pose
    shifted, turned = np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        bx, by, bz = directions[i, 0], directions[i, 1], directions[i, 2]
        if n_off > 0:
            o = x[k + n_pose + group[i]]
            bx, by, bz = bx + o * offsets[i, 0], by + o * offsets[i, 1], bz + o * offsets[i, 2]
        shifted[i, 0], shifted[i, 1], shifted[i, 2] = bx, by, bz
        if n_pose > 0:
            w = x[k + 3 * view[i]:k + 3 * view[i] + 3]
            turned[i, 0] = bx + (w[1] * bz - w[2] * by)
            turned[i, 1] = by + (w[2] * bx - w[0] * bz)
            turned[i, 2] = bz + (w[0] * by - w[1] * bx)
        else:
            turned[i, 0], turned[i, 1], turned[i, 2] = bx, by, bz
    r, J, d = np.empty(n + k + m), np.zeros((n + k + m, k + m)), np.empty(n)
    block = np.empty((n, k))
    ray_block(x[:k], origins, turned, weights, kind, d0, warm, rtol, max_newton, max_warm, grid, znear,
               warm_bracket, newton_power, crossing_tol, crossing_parallel, r, block, d)
    for i in range(n):
        for j in range(k):
            J[i, j] = block[i, j]
        # grad_x log g = -d log g / d p; the residual's coef is folded into block
        gx, gy, gz = block[i, 5], block[i, 6], block[i, 7]
        if n_pose > 0:  # d log m / d w = d* b x grad_x log g
            bx, by, bz = shifted[i, 0], shifted[i, 1], shifted[i, 2]
            c = k + 3 * view[i]
            J[i, c] = d[i] * (gy * bz - gz * by)
            J[i, c + 1] = d[i] * (gz * bx - gx * bz)
            J[i, c + 2] = d[i] * (gx * by - gy * bx)
        if n_off > 0:  # d log m / d o = d* grad_x log g . (c + w x c)
            cx, cy, cz = offsets[i, 0], offsets[i, 1], offsets[i, 2]
            if n_pose > 0:
                w = x[k + 3 * view[i]:k + 3 * view[i] + 3]
                cx, cy, cz = (cx + (w[1] * cz - w[2] * cy), cy + (w[2] * cx - w[0] * cz),
                              cz + (w[0] * cy - w[1] * cx))
            col = k + n_pose + group[i]
            J[i, col] = -d[i] * (gx * cx + gy * cy + gz * cz)
            # the radius factor: r -> r exp(-min(o, 0) / h), d r / d o gains -r / h where o < 0
            inward = nan_min(x[col], 0.0)
            factor = math.exp(-inward / radii[i])
            r[i] = r[i] * factor
            for j in range(k + m):
                J[i, j] *= factor
            if inward < 0:
                J[i, col] -= r[i] / radii[i]
    penalty_rows(x[:k], weight, lower, upper, r, J, n)
    for j in range(n_pose):
        r[n + k + j] = x[k + j] / sigma
        J[n + k + j, k + j] = 1.0 / sigma
    for j in range(n_off):
        acc = 0.0
        for col in range(n_off):
            acc += offset_prior[j, col] * x[k + n_pose + col]
            J[n + k + n_pose + j, k + n_pose + col] = offset_prior[j, col]
        r[n + k + n_pose + j] = acc
    return r, J, d


# before any kernel here or in the modules importing from here runs (sqfit.kernels.kernel_cache)
refresh_for(nan_max)
