"""Two-sided silhouette residuals from rays through image points (stage 3G, "beyond the paper").

G4/G5 (:mod:`sqfit.fitting.costs`) pull back-projected samples onto the surface, so they cannot see a
superquadric that is *larger* than the mask; the numeric R-IOU (G2) sees both sides but has no
gradient without overlap. Here each image point ``s`` of a view gives a ray ``x(d) = c + d b``
(camera centre ``c``, world bearing ``b`` with unit camera depth, as eq. 10), and the residual
asks whether that ray meets the superquadric:

- The *gauge* of the superquadric, ``g(t) = F(t / a) ** (e1 / 2)`` in superquadric coordinates, is
  1-homogeneous, ``<= 1`` exactly inside, and convex for ``e <= 2`` (its sublevel sets are the
  superquadric scaled about its centre).
- Along a ray, ``m(xi) = min_{d >= ZNEAR} g(x(d))``: the ray meets the superquadric iff
  ``m <= 1``; ``m`` is the scale of the smallest copy of the superquadric the ray touches.
- Envelope theorem: ``dm / dxi = dg / dxi`` at the fixed world point ``x(d*)``, so no derivative of
  the minimiser ``d*`` is needed. We take the derivatives of ``g`` from the radial distance G3 of
  :func:`sqfit.fitting.costs.radial_terms` (``G3 = |y| / g - |y|`` with ``y`` the point in superquadric
  coordinates), i.e. the same analytic machinery as G3-G5.

Residual of a ray (``mode``; a weight per ray, e.g. ``1 / sqrt(rays in its view)``):

- ``CONTOUR`` (points on the mask outline): ``phi(m)`` with ``phi(m) = log m`` for ``m >= 1`` and
  ``m - 1`` below, C1 at ``m = 1``: positive when the ray misses (superquadric too small there),
  negative when it passes through (too large), zero when it grazes the superquadric. Scale-free,
  and finite when a ray passes through the centre (``m = 0``).
- ``INSIDE`` (points inside the mask): ``max(0, phi(m))`` -- the ray must meet the superquadric.
- ``OUTSIDE`` (points in a band outside the mask): ``max(0, -phi(m))`` -- the ray must miss it.

Partial visibility: a ray through an outline point whose label (:mod:`sqfit.views.visibility`) is not
``background`` -- the object may continue behind another instance or past the image border -- is
one-sided (``RaySet.two_sided`` False): a ``CONTOUR`` ray keeps only "the ray meets the object"
(``max(0, phi(m))``, the pixel is the object) and an ``OUTSIDE`` ray is dropped (weight 0 in
effect: the object may reach past there, unseen). ``INSIDE`` rays are the same either way.

The minimiser ``d*`` is found for all rays at once by a safeguarded Newton iteration on ``g`` (convex
along a line) inside a bracket from the bounding geometry (:func:`ray_minima`).

Outline offset (:func:`posed_ray_residuals`): the residual is relative, ``phi ~ e / h`` for a ray
``e`` px off a silhouette whose points lie ``h`` px from its centre along the normal. An offset
``o`` that moves every ray by ``-o`` px along the normal while the superquadric grows by as much
keeps every ``e`` and changes every ``h`` to ``h - o``: with ``phi`` alone a negative offset buys a
lower cost for the same pixel errors, and most of all on thin objects (``h`` of a few px). On clean
masks (paper scene, 100 trials, 3G from the truth, offset free) it drifted to -0.5 to -3.4 px on
thin objects (the cost of trial 57 of the paper scene, seed 0, fell from 25e-4 at 0 to 14e-4 at -2 px
with the superquadric refitted), and the 10th percentile of IoU fell from 0.970 to 0.938. The
estimated offsets' rays are therefore weighted by ``exp(-o / h)`` for ``o < 0`` (``~ (h - o) / h``:
the residual in pixels, relative to the unshifted ray's; 1 at ``o = 0``), with ``h`` the outline
point's distance from the mask centroid along the normal (``RaySet.radii``): the 10th percentile
came back to 0.960 and the median on 1 px bias from 0.982 to 0.984. Not for ``o > 0``: there the
relative residual already grows as the superquadric shrinks, and a factor below 1 let large local
errors pull the offset out: with masks bitten by 5 % dropout (100 trials, seed 0, default chain) it
went to +1.4 px and the median IoU to 0.871 against 0.908 with no offset; one-sided, +0.46 px and
0.902 (1 px over-segmentation: 0.989 against 0.991 two-sided).
"""

from __future__ import annotations

import numpy as np

from .. import constants as C
from .._checks import check_shape
from .backend import compiled
from .costs import LOWER_BOUNDS, UPPER_BOUNDS, batch_radial_terms, penalty, penalty_jacobian, rotation_and_derivatives
from ..geometry.silhouette import ZNEAR
from ..views.rays import RaySet

__all__ = ["ray_minima", "batch_ray_minima", "ray_residuals", "batch_ray_residuals", "posed_ray_residuals",
           "log_gauge_jacobian", "batch_log_gauge_jacobian", "gauge_minima", "gauge_phi", "ray_kind", "solver_args",
           "offset_groups_of", "RAY_BOUNDS", "ray_bounds"]

#: Newton iterations of :func:`ray_minima` at most, and its relative stopping tolerance on ``d``.
_MAX_NEWTON = 30
#: Newton iterations at most for a ray whose warm-start bracket held (LM steps are small).
_MAX_NEWTON_WARM = 6
_D_RTOL = 1e-10
#: A ray is converged once ``|d log g / dd|`` times its bracket width is below this.
_LG_TOL = 1e-12
#: Grid points of the initial bracket search, and the relative half-width of a warm-start bracket.
_GRID = 24
#: Newton runs on ``g ** _NEWTON_POWER`` (2: exact in one step for ellipsoids).
_NEWTON_POWER = 2.0
_WARM_BRACKET = 0.05
_TINY = 1e-300
_GRID_T = np.linspace(0.0, 1.0, _GRID)
#: Soft bounds of the 3G penalty rows: those of eq. 7 but with ``C.SILHOUETTE_SHAPE_BOUNDS``.
RAY_BOUNDS = (np.r_[LOWER_BOUNDS[:3], [C.SILHOUETTE_SHAPE_BOUNDS[0]] * 2, LOWER_BOUNDS[5:]],
               np.r_[UPPER_BOUNDS[:3], [C.SILHOUETTE_SHAPE_BOUNDS[1]] * 2, UPPER_BOUNDS[5:]])


def ray_bounds(size_min=C.SIZE_MIN, bounds=RAY_BOUNDS):
    """``bounds`` (default :data:`RAY_BOUNDS`) with the half-axes' lower bound set to ``size_min``
    (metres, > 0; ``FitOptions.size_min_m``); ``bounds`` itself when that is its bound already."""
    if float(size_min) == bounds[0][0] == bounds[0][1] == bounds[0][2]:
        return bounds
    if not (np.isfinite(size_min) and size_min > 0):
        raise ValueError(f"size_min must be a finite number > 0 (metres), got {size_min}")
    lower = bounds[0].copy()
    lower[C.SIZE] = float(size_min)
    return lower, bounds[1]


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
    # softmax weight of x in the x-y log-sum-exp, and that log-sum-exp, without overflow
    wx = 0.5 * (1.0 + np.tanh(0.5 * dx))
    XY = p2 * np.maximum(s[0], s[1]) + np.log1p(np.exp(-np.abs(dx)))
    A, Bz = (p1 / p2) * XY, p1 * s[2]
    dA = A - Bz
    wA = 0.5 * (1.0 + np.tanh(0.5 * dA))
    L = np.maximum(A, Bz) + np.log1p(np.exp(-np.abs(dA)))
    wB = 1.0 - wA
    kx, ky, kz = k
    K1 = ky + wx * (kx - ky)
    K2 = ky * ky + wx * (kx * kx - ky * ky)
    lg1 = kz + wA * (K1 - kz)
    lg2 = wA * ((p2 - 1.0) * K2 - p2 * K1 * K1) - wB * kz * kz + p1 * wA * wB * (K1 - kz) ** 2
    return L / p1, lg1, lg2


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


def batch_ray_minima(X, origins, directions, d0=None, rtol=_D_RTOL, max_newton=_MAX_NEWTON, start="grid"):
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


def gauge_minima(q0, u, rel0, ul, ratio, e1, e2, d0, rtol=_D_RTOL, max_newton=_MAX_NEWTON, start="grid"):
    """The solver of :func:`ray_minima` on rays in unit-size superquadric coordinates.

    ``q0``, ``u`` are ``(3, n)``; ``rel0``, ``ul`` the same rays in superquadric coordinates
    (metres), ``(n, 3)``; ``ratio`` is ``a_max / a_min`` per ray; ``e1``, ``e2`` scalars or ``(n,)``.
    ``start``: where a ray without a warm start begins: ``"grid"`` at the best of a
    :data:`_GRID`-point grid over its bracket (:func:`ray_minima`), ``"nearest"`` at the line's point
    nearest the centre in unit coordinates (the minimiser for a sphere there), clipped to the
    bracket: ``g`` is unimodal along a line, so Newton and bisection reach the same minimum from
    there, with one evaluation instead of the grid's :data:`_GRID` (the factor graph's cold solves,
    :func:`sqfit.graph.landmark.batch_silhouette_residuals`). Runs the compiled kernel
    (:func:`sqfit.fitting.ray_kernels.gauge_minima`) unless :mod:`sqfit.fitting.backend` chose numpy.
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
        t = np.linspace(0.0, 1.0, _GRID)
        grid = lo[idx, None] + (hi[idx] - lo[idx])[:, None] * t  # (k, G)
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


def solver_args(rtol=_D_RTOL, max_newton=_MAX_NEWTON, start="grid"):
    """The ray minimiser's tolerances and constants, as the compiled kernels (:mod:`.ray_kernels`) take
    them: ``(rtol, max_newton, max_newton_warm, grid, znear, warm_bracket, newton_power)``; ``start``
    (:func:`gauge_minima`): ``"nearest"`` passes an empty grid, which tells the kernels."""
    if start not in STARTS:
        raise ValueError(f"start must be one of {STARTS}, got {start!r}")
    grid = _NO_GRID if start == "nearest" else _GRID_T
    return float(rtol), int(max_newton), _MAX_NEWTON_WARM, grid, ZNEAR, _WARM_BRACKET, _NEWTON_POWER


def ray_kind(rays):
    """``(n,) int64`` per ray of ``rays`` for the compiled kernels: 0 two-sided, 1 active where
    ``phi > 0`` (hinge in), 2 active where ``phi < 0`` (two-sided hinge out), 3 never (one-sided
    hinge out); computed once per RaySet."""
    kind = rays.__dict__.get("_kind")
    if kind is None:
        kind = np.zeros(len(rays), dtype=np.int64)
        kind[rays._hinge_in] = 1
        kind[rays._hinge_out] = np.where(rays.two_sided[rays._hinge_out], 2, 3)
        object.__setattr__(rays, "_kind", kind)
    return kind


def _compiled_rows(kernels, X, rays, weight, d0, rtol=_D_RTOL, max_newton=_MAX_NEWTON, bounds=RAY_BOUNDS):
    """:func:`batch_ray_residuals` by :func:`sqfit.fitting.ray_kernels.ray_rows`."""
    f = np.ascontiguousarray
    warm = d0 is not None
    return kernels.ray_rows(f(X, dtype=np.float64), f(rays.origins), f(rays.directions), f(rays.weights),
                            ray_kind(rays), f(d0, dtype=np.float64).reshape(len(X), len(rays)) if warm else
                            _NO_WARM[None], warm, *solver_args(rtol, max_newton), float(weight), *bounds)


def gauge_phi(log_m):
    """``phi(m)``: ``log m`` for ``m >= 1``, ``m - 1`` below; and ``d phi / d log m``."""
    m = np.exp(np.minimum(log_m, 0.0))
    inside = log_m < 0
    return np.where(inside, m - 1.0, log_m), np.where(inside, m, 1.0)


def log_gauge_jacobian(xi, points):
    """``d log g / d xi`` at fixed world points, from :func:`sqfit.fitting.costs.radial_terms`.

    ``G3 = S - |y|`` with ``S = |y| / g``, so ``log g = log|y| - log S``; ``|y| = |x - p|`` depends on
    ``p`` only (``d|y| / dp = -(x - p) / |y|``).

    Returns
    -------
    log_g : (n,) float
    d_xi : (n, 11) float
    """
    log_g, d_xi = batch_log_gauge_jacobian(np.asarray(xi, dtype=np.float64)[None], np.asarray(points)[None])
    return log_g[0], d_xi[0]


def _ray_terms(xi, rays, directions, d0, d=None):
    """Weighted ray residuals, ``d r / d log m``, ``d log m / d xi`` at the minimisers, and ``d``
    (``d`` given: the minimisers are known, e.g. from :func:`batch_ray_minima`)."""
    if d is None:
        d, _ = ray_minima(xi, rays.origins, directions, d0)
    log_m, d_log_m = log_gauge_jacobian(xi, rays.origins + d[:, None] * directions)
    phi, dphi = gauge_phi(log_m)
    scale = rays.weights
    hinge_in, hinge_out = rays._hinge_in, rays._hinge_out
    if len(hinge_in) or len(hinge_out):
        active = np.ones(len(phi), dtype=bool)
        active[hinge_in] = phi[hinge_in] > 0
        active[hinge_out] = (phi[hinge_out] < 0) & rays.two_sided[hinge_out]
        scale = scale * active
    return scale * phi, scale * dphi, d_log_m, d


def ray_residuals(xi, rays, weight=C.PENALTY_ANALYTIC, d0=None, bounds=RAY_BOUNDS):
    """3G residuals (see the module docstring) and their analytic Jacobian.

    Parameters
    ----------
    xi : (11,) float
    rays : RaySet
    weight : float
        ``c_p`` of the penalty rows (eq. 7).
    d0 : (n,) float, optional
        Warm start of the ray minimisers.
    bounds : ((11,) float, (11,) float)
        Soft bounds of the penalty rows (default :data:`RAY_BOUNDS`; :func:`ray_bounds`).

    Returns
    -------
    r : (n + 11,) float
        Weighted ray residuals, then the penalty.
    J : (n + 11, 11) float
        ``d r / d xi``.
    d : (n,) float
        Ray minimisers (pass back as ``d0`` at a nearby ``xi``).
    """
    xi = np.asarray(xi, dtype=np.float64)
    kernels = compiled()
    if kernels is not None:
        r, J, d = _compiled_rows(kernels, xi[None], rays, weight, None if d0 is None else np.asarray(d0)[None],
                                 bounds=bounds)
        return r[0], J[0], d[0]
    r_rays, coef, d_log_m, d = _ray_terms(xi, rays, rays.directions, d0)
    r = np.concatenate([r_rays, penalty(xi, weight, *bounds)])
    J = np.vstack([coef[:, None] * d_log_m, np.diag(penalty_jacobian(xi, weight, *bounds))])
    return r, J, d


def batch_ray_residuals(X, rays, weight=C.PENALTY_ANALYTIC, d0=None, rtol=_D_RTOL, max_newton=_MAX_NEWTON,
                        bounds=RAY_BOUNDS):
    """:func:`ray_residuals` of ``b`` superquadrics on the same rays (one vectorised ray solve).

    Parameters
    ----------
    X : (b, 11) float
    rays : RaySet
    weight : float
        ``c_p`` of the penalty rows.
    d0 : (b, n) float, optional
        Warm start of the ray minimisers.
    rtol, max_newton : float, int
        Tolerance and step budget of the ray minimisers (:func:`batch_ray_minima`).
    bounds : ((11,) float, (11,) float)
        Soft bounds of the penalty rows (default :data:`RAY_BOUNDS`).

    Returns
    -------
    r : (b, n + 11) float
    J : (b, n + 11, 11) float
    d : (b, n) float
    """
    X = check_shape(X, (None, C.N_PARAMS), "X", finite=False)
    if not isinstance(rays, RaySet):
        raise TypeError(f"rays must be a sqfit.views.rays.RaySet, got {type(rays).__name__}")
    kernels = compiled()
    if kernels is not None:
        return _compiled_rows(kernels, X, rays, weight, d0, rtol, max_newton, bounds)
    b, n, k = len(X), len(rays), C.N_PARAMS
    d, _ = batch_ray_minima(X, rays.origins, rays.directions, d0, rtol, max_newton)
    r = np.empty((b, n + k))
    J = np.zeros((b, n + k, k))
    points = rays.origins[None] + d[:, :, None] * rays.directions[None]
    log_m, d_log_m = batch_log_gauge_jacobian(X, points)
    phi, dphi = gauge_phi(log_m)
    scale = np.broadcast_to(rays.weights, (b, n))
    hinge_in, hinge_out = rays._hinge_in, rays._hinge_out
    if len(hinge_in) or len(hinge_out):
        active = np.ones((b, n), dtype=bool)
        active[:, hinge_in] = phi[:, hinge_in] > 0
        active[:, hinge_out] = (phi[:, hinge_out] < 0) & rays.two_sided[hinge_out]
        scale = scale * active
    r[:, :n] = scale * phi
    J[:, :n] = (scale * dphi)[:, :, None] * d_log_m
    diag = np.arange(k)
    for i, xi in enumerate(X):
        r[i, n:] = penalty(xi, weight, *bounds)
        J[i, n + diag, diag] = penalty_jacobian(xi, weight, *bounds)
    return r, J, d


def batch_log_gauge_jacobian(X, points):
    """:func:`log_gauge_jacobian` of ``b`` superquadrics at once, each at its own points.

    From :func:`sqfit.fitting.costs.batch_radial_terms` (same ``X`` (b, 11) and ``points`` (b, n, 3)),
    so a screen pays one vectorised evaluation per step instead of one per candidate. Returns
    ``log_g`` (b, n) and ``d_xi`` (b, n, 11).
    """
    X = np.asarray(X, dtype=np.float64)
    kernels = compiled()
    if kernels is not None:
        return kernels.log_gauge_rows(np.ascontiguousarray(X), np.ascontiguousarray(points, dtype=np.float64))
    g3, d_g3, _ = batch_radial_terms(X, points)
    rel = points - X[:, None, 5:8]
    norm = np.sqrt((rel * rel).sum(axis=2))
    # log g = log|y| - log S with S = g3 + |y| (see log_gauge_jacobian).
    rnorm = np.where(norm > 0, norm, _TINY)
    S_ = g3 + rnorm
    d_norm_p = -rel / rnorm[..., None]
    d_xi = -d_g3 / S_[..., None]
    d_xi[..., 5:8] = d_norm_p / rnorm[..., None] - (d_g3[..., 5:8] + d_norm_p) / S_[..., None]
    return np.log(rnorm) - np.log(S_), d_xi


def posed_ray_residuals(x, rays, sigma_rad, weight=C.PENALTY_ANALYTIC, d0=None, offset_sigma_px=0.0,
                        offset_groups=None, offset_prior=None, bounds=RAY_BOUNDS):
    """3G residuals with nuisance unknowns -- a small rotation correction per view and an outline
    offset per group of rays -- and their analytic Jacobian.

    Rotation (``sigma_rad > 0``): view ``v``'s rays are turned by the world-frame rotation vector
    ``w_v`` to first order: a direction ``b`` becomes ``b + w_v x b``. As the ray minimum ``m`` only
    depends on the ray's line, not on the length of ``b``, this is the rotation ``exp([w_v]x)`` up to
    ``O(|w_v|^2)`` (0.02 px per px of image shift at 1 degree), and it is linear in ``w_v``. In the
    camera's own frame the correction is ``delta_v = R_v^T w_v`` (``R_v' = R_v exp([delta_v]x)``, the
    model of a noisy camera rotation); an isotropic prior has the same value in both frames. By the
    envelope theorem ``d log m / d b = d* grad_x log g(x*)``, so ``d log m / d w_v = d* (b x grad_x
    log g)`` (``grad_x log g = -d log g / d p``).

    Outline offset (``offset_sigma_px > 0``): the masks' outlines lie ``o_k`` px outside the
    silhouette (``o_k < 0``: inside) for the rays of group ``k`` (``offset_groups``), so a ray's
    direction before the turn is ``b + o_k c`` with ``c = rays.offsets`` (:mod:`sqfit.views.rays`),
    exact in ``o_k``; ``d log m / d o_k = d* grad_x log g . (c + w_v x c)``. Each such ray's
    residual is multiplied by the radius factor ``exp(-min(o_k, 0) / h)`` (``h = rays.radii``; see
    the module docstring), which adds ``-r / h`` to its derivative in ``o_k`` where ``o_k < 0``.

    Parameters
    ----------
    x : (11 + p + g,) float
        Parameter vector, then ``w_0 .. w_{v-1}`` (radians; ``p = 3 v``, ``v = rays.view.max() + 1``,
        or ``p = 0`` when ``sigma_rad == 0``), then ``o_0 .. o_{g-1}`` (px; ``g`` groups, or none
        when ``offset_sigma_px == 0``).
    rays : RaySet
    sigma_rad : float
        Scale of the prior rows ``w_v / sigma_rad``, radians, >= 0 (0: no rotation unknowns).
    weight : float
        ``c_p`` of the penalty rows (eq. 7).
    d0 : (n,) float, optional
        Warm start of the ray minimisers.
    offset_sigma_px : float
        Scale of the prior rows ``o_k / offset_sigma_px``, px, >= 0 (0: no offset unknowns).
    offset_groups : (n,) int, optional
        Offset group of each ray, ``0 .. g - 1`` (``g = offset_groups.max() + 1``); default all 0
        (one offset for the object). ``rays.view`` gives one per view.
    offset_prior : (g, g) float, optional
        The offsets' prior rows are ``offset_prior @ o`` instead of ``o / offset_sigma_px`` (a
        square root of the prior's information matrix, px^-1: correlated offsets, such as views'
        offsets that share the object's).
    bounds : ((11,) float, (11,) float)
        Soft bounds of the penalty rows (default :data:`RAY_BOUNDS`; :func:`ray_bounds`).

    Returns
    -------
    r : (n + 11 + p + g,) float
        Weighted ray residuals, the penalty, then the priors (rotations, offsets).
    J : (n + 11 + p + g, 11 + p + g) float
        ``d r / d x``.
    d : (n,) float
        Ray minimisers.
    """
    x = np.asarray(x, dtype=np.float64)
    n, k = len(rays), C.N_PARAMS
    for name, value in (("sigma_rad", sigma_rad), ("offset_sigma_px", offset_sigma_px)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value}")
    v = int(rays.view.max()) + 1
    p = 3 * v if sigma_rad > 0 else 0
    groups = offset_groups_of(rays, offset_groups)
    g = int(groups.max()) + 1 if offset_sigma_px > 0 else 0
    x = check_shape(x, (k + p + g,), "x")
    prior = np.eye(g) / offset_sigma_px if offset_prior is None or not g else check_shape(offset_prior, (g, g),
                                                                                          "offset_prior")
    kernels = compiled()
    if kernels is not None:
        f = np.ascontiguousarray
        warm = d0 is not None
        return kernels.posed_rows(f(x), f(rays.origins), f(rays.directions), f(rays.offsets), f(rays.weights),
                                  f(rays.radii), ray_kind(rays), f(rays.view), groups, p,
                                  f(d0, dtype=np.float64) if warm else _NO_WARM,
                                  warm, *solver_args(_D_RTOL, _MAX_NEWTON), float(weight), *bounds,
                                  float(sigma_rad), f(prior, dtype=np.float64).reshape(g, g))
    xi, w, o = x[:k], x[k:k + p].reshape(-1, 3), x[k + p:]
    b = rays.directions + o[groups][:, None] * rays.offsets if g else rays.directions
    directions = b + np.cross(w[rays.view], b) if p else b
    r_rays, coef, d_log_m, d = _ray_terms(xi, rays, directions, d0)
    J = np.zeros((n + k + p + g, k + p + g))
    J[:n, :k] = coef[:, None] * d_log_m
    rows = np.arange(n)
    if p:  # d log m / d w = d* b x grad_x log g, with grad_x log g = -d log g / d p
        J[rows[:, None], k + 3 * rays.view[:, None] + np.arange(3)] = (coef * d)[:, None] * np.cross(d_log_m[:, 5:8], b)
    if g:  # d log m / d o = d* grad_x log g . (c + w x c)
        c = rays.offsets + np.cross(w[rays.view], rays.offsets) if p else rays.offsets
        J[rows, k + p + groups] = -(coef * d) * np.einsum("ij,ij->i", d_log_m[:, 5:8], c)
        # the radius factor (module docstring): r -> r exp(-min(o, 0) / h), so d r / d o gains -r / h
        # where o < 0
        inward = np.minimum(o[groups], 0.0)
        factor = np.exp(-inward / rays.radii)
        r_rays = r_rays * factor
        J[:n] *= factor[:, None]
        J[rows, k + p + groups] -= np.where(inward < 0, r_rays / rays.radii, 0.0)
    J[n:n + k, :k] = np.diag(penalty_jacobian(xi, weight, *bounds))
    J[n + k:n + k + p, k:k + p] = np.eye(p) / sigma_rad if p else 0.0
    J[n + k + p:, k + p:] = prior
    r = np.concatenate([r_rays, penalty(xi, weight, *bounds), w.ravel() / sigma_rad if p else [], prior @ o])
    return r, J, d


def offset_groups_of(rays, offset_groups=None):
    """``(n,) int64`` outline-offset group per ray of ``rays``, checked: ``offset_groups`` or all 0."""
    if offset_groups is None:
        return np.zeros(len(rays), dtype=np.int64)
    groups = check_shape(offset_groups, (len(rays),), "offset_groups", dtype=np.int64)
    if len(groups) and groups.min() < 0:
        raise ValueError("offset_groups must be >= 0")
    return np.ascontiguousarray(groups)
