"""The minimum of a superquadric's gauge along lines: where a ray comes closest to the superquadric.

Stage 3G's residuals (:mod:`sqfit.fitting.raycost`) and the factor graph's silhouette factors
(:mod:`sqfit.graph.landmark`) need, per ray ``x(d) = c + d b``, the minimiser
``d* = argmin_{d >= ZNEAR} g(x(d))`` of the superquadric's gauge ``g`` (1-homogeneous, ``<= 1``
exactly inside, convex along a line for ``e <= 2``) and ``log g`` there. This module finds them for
all rays at once: a bracket from the bounding geometry, a start (a grid over the bracket, the
line's point nearest the centre, or a warm start from a nearby solution), then safeguarded Newton
steps (:func:`ray_minima`, :func:`batch_ray_minima`, :func:`gauge_minima`); the compiled kernels of
:mod:`sqfit.kernels.ray_kernels` take the same constants (:func:`solver_args`).
"""

from __future__ import annotations

import numpy as np

from ..kernels.backend import compiled
from .costs import rotation_and_derivatives
from ..geometry.silhouette import ZNEAR

__all__ = ["ray_minima", "batch_ray_minima", "gauge_minima", "solver_args", "STARTS", "D_RTOL", "MAX_NEWTON"]

#: Newton iterations of :func:`ray_minima` at most, and its relative stopping tolerance on ``d``.
MAX_NEWTON = 30
#: Newton iterations at most for a ray whose warm-start bracket held (LM steps are small).
_MAX_NEWTON_WARM = 6
D_RTOL = 1e-10
#: Grid points of the initial bracket search, and the relative half-width of a warm-start bracket.
_GRID = 24
#: Newton runs on ``g ** _NEWTON_POWER`` (2: exact in one step for ellipsoids).
_NEWTON_POWER = 2.0
_WARM_BRACKET = 0.05
_TINY = 1e-300
_GRID_T = np.linspace(0.0, 1.0, _GRID)


def _line_log_gauge(q0, u, d, e1, e2):
    """``log g`` along lines ``q0 + d u`` (unit-size superquadric coordinates) and its first two
    derivatives in ``d``.

    ``q0``, ``u`` are ``(3, n)`` (coordinate-major, for speed), ``d`` is ``(n,)``. With
    ``s_i = log|q_i|``, ``k_i = u_i / q_i``, ``L = log F`` (a nested log-sum-exp of ``2/e2 s_x``,
    ``2/e2 s_y`` and ``2/e1 s_z``) and ``log g = e1 / 2 L``, the chain rule through the two
    log-sum-exps gives ``lg' = wA K1 + wB k_z`` and
    ``lg'' = wA ((p2 - 1) sum_j w_j k_j^2 - p2 K1^2) - wB k_z^2 + p1 wA wB (K1 - k_z)^2`` with
    ``K1 = sum_j w_j k_j`` over ``j = x, y`` and the softmax weights ``w`` of each log-sum-exp.
    """
    q = q0 + d * u
    q[q == 0.0] = _TINY
    p1, p2 = 2.0 / e1, 2.0 / e2
    s = np.log(np.abs(q))
    k = u / q
    dx = p2 * (s[0] - s[1])
    # softmax weights of x and y in the x-y log-sum-exp, and that log-sum-exp, without overflow
    t = np.exp(-np.abs(dx))
    wx, wy = _weights(dx, t)
    XY = p2 * np.maximum(s[0], s[1]) + np.log1p(t)
    A, Bz = (p1 / p2) * XY, p1 * s[2]
    dA = A - Bz
    t = np.exp(-np.abs(dA))
    wA, wB = _weights(dA, t)
    L = np.maximum(A, Bz) + np.log1p(t)
    kx, ky, kz = k
    # each k_j times its weight, never as k_y + w_x (k_x - k_y): near a coordinate plane (q_j -> 0,
    # where Newton's step on a term log|q_j| lands) k_j is huge while its weight vanishes, and that
    # form cancelled every digit of the slope, whose sign then cut the ray's bracket
    cx, cy, cz = wx * kx, wy * ky, wB * kz
    K1 = cx + cy
    K2 = cx * kx + cy * ky
    lg1 = wA * K1 + cz
    lg2 = wA * ((p2 - 1.0) * K2 - p2 * K1 * K1) - cz * kz + p1 * wA * (wB * K1 - cz) * (K1 - kz)
    return L / p1, lg1, lg2


def _weights(x, t):
    """The two weights ``1 / (1 + exp(-x))`` and ``1 / (1 + exp(x))`` of a two-term softmax, with ``t =
    exp(-|x|)``: each computed on its own (not one as ``1 -`` the other), so the smaller keeps its
    digits where it is tiny."""
    big, small = 1.0 / (1.0 + t), t / (1.0 + t)
    return np.where(x >= 0, big, small), np.where(x >= 0, small, big)


def ray_minima(xi, origins, directions, d0=None, start="grid"):
    """Minimiser and minimum of the superquadric's gauge along rays.

    Parameters
    ----------
    xi : (11,) float
        Parameter vector (``|a|`` is used).
    origins, directions : (n, 3) float
        Rays ``x(d) = origin + d * direction``, ``d >= ZNEAR``.
    d0 : (n,) float, optional
        Starting points (e.g. the minimisers at a nearby ``xi``): where ``g'`` changes sign within
        :data:`_WARM_BRACKET` (relative) of ``d0``, that is the bracket; the other rays use the grid.
    start : str
        Where a ray without a warm start begins (:func:`gauge_minima`): ``"grid"`` or ``"nearest"``.

    Returns
    -------
    d : (n,) float
        ``argmin_{d >= ZNEAR} g(x(d))``.
    log_m : (n,) float
        ``log g`` at ``d``; the ray meets the superquadric iff ``log_m <= 0``.

    Notes
    -----
    ``g`` is convex along a line, so ``g'`` changes sign once. The bracket: with ``rho`` the
    distance of the line from the centre, ``g(y) >= max_i |y_i| / a_i >= |y| / (sqrt(3) a_max)`` and
    ``g(y) <= sum_i |y_i| / a_i <= sqrt(3) |y| / a_min`` (the superquadric lies between the
    octahedron ``e = 2`` and the box ``e = 0``), so the minimiser is within
    ``3 rho a_max / a_min`` of the point of the line nearest the centre. That bracket is cut to two
    cells of a :data:`_GRID`-point grid around the grid minimum (one vectorised evaluation), then
    Newton steps on ``g ** 2`` (exact in one step for ellipsoids) that leave the bracket, which
    shrinks at every evaluation, are replaced by bisection.
    """
    xi = np.asarray(xi, dtype=np.float64)
    d, log_m = batch_ray_minima(xi[None], origins, directions, None if d0 is None else np.asarray(d0)[None],
                                start=start)
    return d[0], log_m[0]


def batch_ray_minima(X, origins, directions, d0=None, rtol=D_RTOL, max_newton=MAX_NEWTON, start="grid"):
    """:func:`ray_minima` for ``b`` superquadrics at once, on the same rays (one vectorised solve).

    Parameters
    ----------
    X : (b, 11) float
    origins, directions : (n, 3) float
    d0 : (b, n) float, optional
    rtol : float
        Relative tolerance on ``d`` (an error ``delta`` in ``d`` changes ``m`` by ``O(delta**2)``:
        a screen can stop much earlier than the default).
    max_newton : int
        Newton / bisection steps at most for a ray whose warm-start bracket did not hold (or with no
        warm start); rays whose bracket held take at most :data:`_MAX_NEWTON_WARM`.
    start : str
        :func:`gauge_minima`'s ``start``.

    Returns
    -------
    d, log_m : (b, n) float
    """
    X = np.asarray(X, dtype=np.float64)
    b, n = len(X), len(origins)
    a = np.maximum(np.abs(X[:, 0:3]), _TINY)
    R = np.stack([rotation_and_derivatives(x[8:11])[0] for x in X]) if b > 1 else \
        rotation_and_derivatives(X[0, 8:11])[0][None]
    rel0 = np.einsum("bnj,bjk->bnk", origins[None] - X[:, None, 5:8], R).reshape(b * n, 3)
    ul = np.einsum("nj,bjk->bnk", directions, R).reshape(b * n, 3)
    a_ray = np.repeat(a, n, axis=0)
    ratio = np.repeat(a.max(axis=1) / a.min(axis=1), n)
    e1, e2 = np.repeat(X[:, 3], n), np.repeat(X[:, 4], n)
    if b == 1:  # scalar exponents: the common case stays as fast as before
        e1, e2 = float(X[0, 3]), float(X[0, 4])
    q0, u = np.ascontiguousarray((rel0 / a_ray).T), np.ascontiguousarray((ul / a_ray).T)
    d, log_m = gauge_minima(q0, u, rel0, ul, ratio, e1, e2, None if d0 is None else np.reshape(d0, b * n), rtol,
                             max_newton, start)
    return d.reshape(b, n), log_m.reshape(b, n)


def _take(e, idx):
    """Per-ray exponents at ``idx`` (scalars pass through)."""
    return e if np.ndim(e) == 0 else e[idx]


#: How a ray without a warm start finds its first point (:func:`gauge_minima`).
STARTS = ("grid", "nearest")


def gauge_minima(q0, u, rel0, ul, ratio, e1, e2, d0, rtol=D_RTOL, max_newton=MAX_NEWTON, start="grid"):
    """The solver of :func:`ray_minima` on rays in unit-size superquadric coordinates.

    ``q0``, ``u`` are ``(3, n)``; ``rel0``, ``ul`` the same rays in superquadric coordinates
    (metres), ``(n, 3)``; ``ratio`` is ``a_max / a_min`` per ray; ``e1``, ``e2`` scalars or ``(n,)``.
    ``start``: where a ray without a warm start begins: ``"grid"`` at the best of a
    :data:`_GRID`-point grid over its bracket (:func:`ray_minima`), ``"nearest"`` at the line's point
    nearest the centre in unit coordinates (the minimiser for a sphere there), clipped to the
    bracket: ``g`` is unimodal along a line, so Newton and bisection reach the same minimum from
    there, with one evaluation instead of the grid's :data:`_GRID` (the factor graph's cold solves,
    :func:`sqfit.graph.landmark.batch_silhouette_residuals`). Runs the compiled kernel
    (:func:`sqfit.kernels.ray_kernels.gauge_minima`) unless :mod:`sqfit.kernels.backend` chose numpy.
    """
    if start not in STARTS:
        raise ValueError(f"start must be one of {STARTS}, got {start!r}")
    kernels = compiled()
    if kernels is not None:
        n = len(ratio)
        f = np.ascontiguousarray
        warm = d0 is not None
        args = solver_args(rtol, max_newton, start)
        return kernels.gauge_minima(f(q0, dtype=np.float64), f(u, dtype=np.float64), f(rel0, dtype=np.float64),
                                    f(ul, dtype=np.float64), f(ratio, dtype=np.float64),
                                    *(f(np.broadcast_to(e, (n,)), dtype=np.float64) for e in (e1, e2)),
                                    f(d0, dtype=np.float64) if warm else _NO_WARM, warm, *args)
    bb = np.einsum("ij,ij->i", ul, ul)
    dc = -np.einsum("ij,ij->i", rel0, ul) / bb
    rho = np.linalg.norm(rel0 + dc[:, None] * ul, axis=1)
    half = 1.01 * 3.0 * rho * ratio / np.sqrt(bb) + 1e-9 * (np.abs(dc) + 1.0)
    lo = np.maximum(dc - half, ZNEAR)
    hi = np.maximum(dc + half, 2.0 * ZNEAR)
    n = len(lo)
    tol = rtol * (np.abs(dc) + 1.0)
    cold = np.ones(n, dtype=bool)
    if d0 is not None:
        d0 = np.clip(np.asarray(d0, dtype=np.float64), lo, hi)
        delta = _WARM_BRACKET * (np.abs(d0) + 1.0)
        probe = np.concatenate([np.maximum(d0 - delta, lo), np.minimum(d0 + delta, hi)])
        e12 = [e if np.ndim(e) == 0 else np.tile(e, 2) for e in (e1, e2)]
        slope = _line_log_gauge(np.tile(q0, 2), np.tile(u, 2), probe, *e12)[1]
        ok = (slope[:n] <= 0) & (slope[n:] >= 0)
        lo = np.where(ok, probe[:n], lo)
        hi = np.where(ok, probe[n:], hi)
        cold = ~ok
    d = 0.5 * (lo + hi)
    idx = np.flatnonzero(cold)
    if len(idx) and start == "nearest":
        with np.errstate(divide="ignore", invalid="ignore"):
            dn = -np.einsum("ij,ij->j", q0[:, idx], u[:, idx]) / np.einsum("ij,ij->j", u[:, idx], u[:, idx])
        d[idx] = np.where(np.isnan(dn), d[idx], np.clip(dn, lo[idx], hi[idx]))
    elif len(idx):
        grid = lo[idx, None] + (hi[idx] - lo[idx])[:, None] * _GRID_T  # (k, G)
        e12 = [e if np.ndim(e) == 0 else np.repeat(e[idx], _GRID) for e in (e1, e2)]
        lg = _line_log_gauge(np.repeat(q0[:, idx], _GRID, 1), np.repeat(u[:, idx], _GRID, 1), grid.ravel(),
                             *e12)[0]
        best = np.argmin(lg.reshape(len(idx), _GRID), axis=1)
        rows = np.arange(len(idx))
        d[idx] = grid[rows, best]
        lo[idx] = grid[rows, np.maximum(best - 1, 0)]
        hi[idx] = grid[rows, np.minimum(best + 1, _GRID - 1)]
    # rtsafe (Numerical Recipes): Newton, but bisect when the step leaves the bracket or does not
    # shrink to half the step before last (Newton overshoots at kinks, where g'' is unbounded).
    idx = np.arange(n)
    dd, lo_a, hi_a, tola = d.copy(), lo, hi, tol
    dx = dx_old = hi - lo
    qa, ua, e1a, e2a = q0, u, e1, e2
    budget = np.where(cold, max_newton, _MAX_NEWTON_WARM)
    for it in range(1, max(max_newton, _MAX_NEWTON_WARM) + 1):
        _, lg1, lg2 = _line_log_gauge(qa, ua, dd, e1a, e2a)
        neg = lg1 < 0
        lo_a = np.where(neg, dd, lo_a)
        hi_a = np.where(neg, hi_a, dd)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = -lg1 / (lg2 + _NEWTON_POWER * lg1 * lg1)
        new = dd + step
        bad = ~np.isfinite(new) | (new < lo_a) | (new > hi_a) | (np.abs(step) > 0.5 * np.abs(dx_old))
        new = np.where(bad, 0.5 * (lo_a + hi_a), new)
        dx_old, dx = dx, np.abs(new - dd)
        d[idx] = new
        keep = (dx > tola) & (hi_a - lo_a > tola) & (budget > it)
        if not keep.any():
            break
        if not keep.all():
            idx, new, lo_a, hi_a, tola, budget = idx[keep], new[keep], lo_a[keep], hi_a[keep], tola[keep], budget[keep]
            dx, dx_old, qa, ua = dx[keep], dx_old[keep], qa[:, keep], ua[:, keep]
            e1a, e2a = _take(e1a, keep), _take(e2a, keep)
        dd = new
    log_m = _line_log_gauge(q0, u, d, e1, e2)[0]
    return d, log_m


_NO_WARM = np.zeros(1)
_NO_GRID = np.zeros(0)


def solver_args(rtol=D_RTOL, max_newton=MAX_NEWTON, start="grid"):
    """The ray minimiser's tolerances and constants, as the compiled kernels (:mod:`.ray_kernels`) take
    them: ``(rtol, max_newton, max_newton_warm, grid, znear, warm_bracket, newton_power)``; ``start``
    (:func:`gauge_minima`): ``"nearest"`` passes an empty grid, which tells the kernels."""
    if start not in STARTS:
        raise ValueError(f"start must be one of {STARTS}, got {start!r}")
    grid = _NO_GRID if start == "nearest" else _GRID_T
    return float(rtol), int(max_newton), _MAX_NEWTON_WARM, grid, ZNEAR, _WARM_BRACKET, _NEWTON_POWER
