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
along a line) inside a bracket from the bounding geometry (:func:`sqfit.fitting.line_gauge.ray_minima`).

Where ``d*`` lies on a coordinate plane of the superquadric (``y_j = 0``) whose power ``2 / e`` is
below 2 (``e2 > 1`` for ``x`` and ``y``, ``e1 > 1`` for ``z``), the envelope theorem holds in exact
arithmetic but not at the minimiser the solver returns: ``|y_j|^(2 / e)`` has a slope ``~ |y_j|^(2 /
e - 1)`` that vanishes so slowly (``e = 1.8``: ``|y_j|^0.11``, still 0.1 at 1e-9) that no minimiser
within rounding of the plane has a slope near 0 along the ray, and the derivative at that fixed
point missed the minimiser's motion with the plane: on such rays the Jacobian of a ray residual in
the position and rotation was off by up to 70 % (finite differences as the reference), where
diamond-like sections graze their outline at their corners. :func:`crossing_correction` adds that
motion: there ``y_j`` dominates the curvature along the ray, so ``dd* / dxi = -(dy_j / dxi) / (dy_j /
dd)`` and ``dm / dxi = dg / dxi + (dg / dd) dd* / dxi`` (the derivative of ``g`` at the plane's
crossing of the ray). A ray counts as on the plane when ``|y_j| / a_j`` is below
:data:`CROSSING_TOL` and it is not within :data:`CROSSING_PARALLEL` of parallel to the plane;
elsewhere, and on every superquadric with ``e1, e2 <= 1``, nothing changes. A minimiser on two
planes at once (on an axis: a ray through a pointed tip, which an outline ray of a mask passes at a
fraction of a pixel rather than through it) is left as it was. Without the correction the graph's
Levenberg-Marquardt and iSAM2 stopped part way along its flattest direction, the map's scale, where
such landmarks' linearisation promised decreases that did not come (docs/slam-history.md, "Issue 23,
twenty-seventh pass").

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
from ..kernels.backend import compiled
from .costs import LOWER_BOUNDS, UPPER_BOUNDS, batch_radial_terms, penalty, penalty_jacobian
from .line_gauge import D_RTOL, MAX_NEWTON, batch_ray_minima, ray_minima, solver_args
from ..geometry.superquadric import rotation_and_derivatives
from ..views.rays import RaySet

__all__ = ["ray_residuals", "batch_ray_residuals", "posed_ray_residuals",
           "log_gauge_jacobian", "batch_log_gauge_jacobian", "gauge_phi", "ray_kind",
           "offset_groups_of", "RAY_BOUNDS", "ray_bounds", "crossing_correction", "CROSSING_TOL",
           "CROSSING_PARALLEL", "CROSSING_ARGS"]

_TINY = 1e-300
_NO_WARM = np.zeros(1)
#: Soft bounds of the 3G penalty rows: those of eq. 7 but with ``C.SILHOUETTE_SHAPE_BOUNDS``.
RAY_BOUNDS = (np.r_[LOWER_BOUNDS[:3], [C.SILHOUETTE_SHAPE_BOUNDS[0]] * 2, LOWER_BOUNDS[5:]],
               np.r_[UPPER_BOUNDS[:3], [C.SILHOUETTE_SHAPE_BOUNDS[1]] * 2, UPPER_BOUNDS[5:]])

#: A ray's minimiser lies on a coordinate plane of the superquadric when its distance from it,
#: relative to that half-axis, is below this (module docstring): the solver's tolerance puts such
#: minimisers within ~1e-8 of it; a minimiser 1e-6 off the plane is already one of its own, where
#: the slope along the ray is ~0 and the correction vanishes with it.
CROSSING_TOL = 1e-6
#: ... and the ray is not parallel to that plane: the ray's direction across it, relative to its
#: whole direction (both in half-axis units), is above this.
CROSSING_PARALLEL = 1e-3
#: The compiled kernels' arguments for :func:`crossing_correction` (``crossing_tol, crossing_parallel``).
CROSSING_ARGS = (CROSSING_TOL, CROSSING_PARALLEL)


def crossing_correction(X, points, directions, d_xi, tol=CROSSING_TOL, parallel=CROSSING_PARALLEL):
    """``d log g / d xi`` at the rays' minimisers, with the motion of a minimiser that lies on a
    coordinate plane of its superquadric (module docstring); in place.

    Parameters
    ----------
    X : (b, 11) float
    points : (b, n, 3) float
        The rays' minimisers (world).
    directions : (n, 3) or (b, n, 3) float
        The rays' world directions.
    d_xi : (b, n, 11) float
        ``d log g / d xi`` at ``points`` (:func:`batch_log_gauge_jacobian`); corrected in place.
    tol, parallel : float
        :data:`CROSSING_TOL` and :data:`CROSSING_PARALLEL`.

    Returns
    -------
    d_xi : (b, n, 11) float
    """
    directions = np.broadcast_to(directions, points.shape)
    for s in range(len(X)):
        xi = X[s]
        R, dR = rotation_and_derivatives(xi[8:11])
        rel = points[s] - xi[5:8]
        a = np.abs(xi[:3])
        with np.errstate(invalid="ignore", divide="ignore"):
            on, across = np.abs(rel @ R) / a < tol, (directions[s] @ R) / a
            eligible = on & (np.abs(across) > parallel * np.sqrt((across * across).sum(axis=1))[:, None]) & (
                np.array([xi[4], xi[4], xi[3]]) > 1.0)
        # on one plane only (on two: an axis, left as it was)
        rows = np.flatnonzero((on.sum(axis=1) == 1) & eligible.any(axis=1))
        if not len(rows):
            continue
        j = np.argmax(eligible[rows], axis=1)
        # the slope of log g along the ray over d y_j / d d (d log g / d p = -(d log g / d point))
        c = -np.einsum("ij,ij->i", d_xi[s, rows, 5:8], directions[s, rows]) / (across[rows, j] * a[j])
        d_xi[s, rows, 5:8] += c[:, None] * R[:, j].T
        d_xi[s, rows, 8:11] -= c[:, None] * np.einsum("kmi,im->ik", dR[:, :, j], rel[rows])
    return d_xi


def ray_bounds(size_min=C.SIZE_MIN, bounds=RAY_BOUNDS, shape_min=None):
    """``bounds`` (default :data:`RAY_BOUNDS`) with the half-axes' lower bound set to ``size_min``
    (metres, > 0; ``FitOptions.size_min_m``) and, unless None, the shape exponents' to ``shape_min``
    (3H's plain run, :data:`sqfit.fitting.plain_run.PLAIN_SHAPE_MIN`); ``bounds`` itself when those
    are its bounds already."""
    size_same = float(size_min) == bounds[0][0] == bounds[0][1] == bounds[0][2]
    if size_same and (shape_min is None or float(shape_min) == bounds[0][3] == bounds[0][4]):
        return bounds
    if not (np.isfinite(size_min) and size_min > 0):
        raise ValueError(f"size_min must be a finite number > 0 (metres), got {size_min}")
    lower = bounds[0].copy()
    lower[C.SIZE] = float(size_min)
    if shape_min is not None:
        lower[C.SHAPE] = float(shape_min)
    return lower, bounds[1]



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


def _compiled_rows(kernels, X, rays, weight, d0, rtol=D_RTOL, max_newton=MAX_NEWTON, bounds=RAY_BOUNDS):
    """:func:`batch_ray_residuals` by :func:`sqfit.kernels.ray_kernels.ray_rows`."""
    f = np.ascontiguousarray
    warm = d0 is not None
    return kernels.ray_rows(f(X, dtype=np.float64), f(rays.origins), f(rays.directions), f(rays.weights),
                            ray_kind(rays), f(d0, dtype=np.float64).reshape(len(X), len(rays)) if warm else
                            _NO_WARM[None], warm, *solver_args(rtol, max_newton), *CROSSING_ARGS, float(weight),
                            *bounds)


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
    points = rays.origins + d[:, None] * directions
    log_m, d_log_m = log_gauge_jacobian(xi, points)
    crossing_correction(xi[None], points[None], directions, d_log_m[None])
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


def batch_ray_residuals(X, rays, weight=C.PENALTY_ANALYTIC, d0=None, rtol=D_RTOL, max_newton=MAX_NEWTON,
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
    crossing_correction(X, points, rays.directions, d_log_m)
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
                                  warm, *solver_args(D_RTOL, MAX_NEWTON), *CROSSING_ARGS, float(weight), *bounds,
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
