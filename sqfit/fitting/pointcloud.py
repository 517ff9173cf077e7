"""An outlier-tolerant superquadric fit to a 3D point cloud (the EMS idea, Liu et al., CVPR 2022).

Model (a Gaussian-uniform mixture on the radial distance): a point ``x`` is an inlier with
probability ``1 - w`` and then lies off the surface by its radial distance ``d(x; xi)`` (G3,
:func:`sqfit.geometry.superquadric.radial_distance`: along the ray from the centre) with density
``(2 pi s^2)^(-3/2) exp(-d^2 / (2 s^2))``; or it is an outlier, uniform over the point cloud's
bounding box (density ``1 / V``). Expectation-maximisation:

- E-step: each point's posterior probability of being an inlier, ``z_i``;
- M-step: ``xi`` minimising ``sum z_i d_i^2`` (a few trust-region steps of
  ``scipy.optimize.least_squares``, bounded: ``a`` positive, ``e`` in ``constants.SHAPE_BOUNDS``),
  then ``s^2 = sum z_i d_i^2 / (3 sum z_i)`` (floored);
- S-step ("similarity switching"): EM is local, and a superquadric has near-equivalent
  re-parametrisations between which it rarely moves (another local axis carrying ``e1``; a
  square-ish section turned by 45 degrees). After EM converges, the five re-parametrisations of
  :func:`sqfit.fitting.restarts.symmetric_candidates` get :data:`SWITCH_ITERATIONS` EM iterations
  each; if the best one's log-likelihood beats the current fit's by :data:`SWITCH_MARGIN`, EM
  continues from it (at most :data:`MAX_SWITCHES` times).

Start: median and principal axes (a proper rotation) of the 75 % of the points nearest to them
(a trimmed covariance, three concentration steps), half-axes the :data:`START_PERCENTILE`
percentile of those points' absolute coordinates along each axis, ``e = 1``,
``s^2`` the mean squared radial distance (every point an inlier at first).

Why our own and not a library: the authors' code (MATLAB, with a Python port in their repository)
is not published as a package; the one superquadric package on PyPI that fits point clouds
(``sage-superquadric`` 1.0.0, a single release) is a recognition system whose fit is a
``soft_l1`` least-squares fit without an outlier model or similarity switching, and it would add
scikit-learn to ``sqfit``. The mixture, the E-step and the S-step are a few lines over
``scipy.optimize.least_squares``, which does the optimisation.

The radial residuals and their Jacobian run in one compiled loop where numba is chosen
(:mod:`sqfit.kernels.backend`, :func:`sqfit.kernels.hull_kernels.radial_residuals`: the same numbers to
rounding); what is left of EMS's time is ``least_squares``'s own (its SVDs and bookkeeping).

Deterministic: no random numbers (a cloud larger than ``max_points`` is thinned by a fixed stride).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .. import constants as C
from .._checks import check_shape
from ..geometry.superquadric import matrix_to_euler, rotation_and_derivatives
from ..kernels.backend import compiled
from .restarts import symmetric_candidates

__all__ = ["PointFit", "fit_points", "radial_residuals", "OUTLIER_WEIGHT", "MAX_POINTS", "EM_ITERATIONS",
           "SWITCH_ITERATIONS", "MAX_SWITCHES", "SWITCH_MARGIN", "START_PERCENTILE"]

#: Prior probability ``w`` of an outlier (EMS treats it as a fixed hyper-parameter).
OUTLIER_WEIGHT = 0.2
#: Points used by the fit; a larger cloud is thinned by a fixed stride.
MAX_POINTS = 1500
#: Largest number of EM iterations per run (before or after a switch).
EM_ITERATIONS = 20
#: Trust-region function evaluations of one M-step.
M_STEP_EVALUATIONS = 6
#: EM stops when no parameter moved by more than this fraction of the cloud's size (sizes,
#: position) or this many radians / exponent units (rotation, shape).
EM_TOL = 1e-3
#: EM iterations given to each similarity candidate before they are compared.
SWITCH_ITERATIONS = 3
#: Rounds of similarity switching.
MAX_SWITCHES = 2
#: Log-likelihood gain (nats per point) a candidate needs to replace the current fit.
SWITCH_MARGIN = 1e-3
#: Percentile of the absolute coordinates along each principal axis taken as the start's half-axis.
START_PERCENTILE = 95.0
#: Concentration steps of the trimmed start, and the fraction of points each keeps.
_TRIM_STEPS = 3
_TRIM_KEEP = 0.75
#: Floor of the inlier scale ``s``, as a fraction of the cloud's size.
_SIGMA_FLOOR = 1e-4


@dataclass(frozen=True)
class PointFit:
    """Result of :func:`fit_points`.

    Attributes
    ----------
    xi : (11,) float
        Parameter vector (``constants.PARAMETER_NAMES``).
    sigma : float
        Inlier scale ``s`` of the mixture, metres.
    inlier : (n,) float
        Posterior probability of being an inlier, per point used (after thinning).
    log_likelihood : float
        Mean per point of the mixture's log-density, nats.
    iterations : int
        EM iterations run, candidates' included.
    switches : int
        Times a similarity candidate replaced the fit.
    cost : float
        ``0.5 * sum z_i d_i^2`` of the last M-step, square metres.
    """

    xi: np.ndarray
    sigma: float
    inlier: np.ndarray
    log_likelihood: float
    iterations: int
    switches: int
    cost: float


def radial_residuals(xi, points, jacobian=False):
    """Radial distances of points to a superquadric (G3, positive inside), and their Jacobian.

    Parameters
    ----------
    xi : (11,) float
        Parameter vector; ``|a|`` is used.
    points : (n, 3) float
        World coordinates, metres.
    jacobian : bool
        Also return ``dd / dxi``.

    Returns
    -------
    d : (n,) float
        ``|t| (F(t)^(-e1/2) - 1)`` with ``t`` the point in superquadric coordinates and ``F`` the
        implicit function: the distance along the ray from the centre to the surface, metres.
    J : (n, 11) float
        Only with ``jacobian``. Exact where no coordinate of ``t`` is 0 (there the terms of that
        coordinate are taken as 0, their limit for ``e < 2``).
    """
    R, dR = rotation_and_derivatives(xi[8:11])
    kernels = compiled("hull")
    if kernels is not None:  # the same formulas in one compiled loop (sqfit.kernels.hull_kernels)
        xi = np.asarray(xi, dtype=np.float64)
        points = np.ascontiguousarray(points, dtype=np.float64)
        d = np.empty(len(points))
        J = np.empty((len(points), C.N_PARAMS) if jacobian else (0, C.N_PARAMS))
        kernels.radial_residuals(xi, points, R, dR, bool(jacobian), d, J)
        return (d, J) if jacobian else d
    offset = points - xi[5:8]
    t = offset @ R
    a, e1, e2 = np.abs(xi[0:3]), xi[3], xi[4]
    norm = np.maximum(np.linalg.norm(t, axis=1), 1e-300)
    with np.errstate(divide="ignore"):
        la = np.log(np.abs(t)) - np.log(a)
    xy = np.logaddexp((2.0 / e2) * la[:, 0], (2.0 / e2) * la[:, 1])
    log_f = np.logaddexp((e2 / e1) * xy, (2.0 / e1) * la[:, 2])
    ratio = np.exp(-0.5 * e1 * log_f)  # F^(-e1/2) = r_surface / |t|
    d = norm * (ratio - 1.0)
    if not jacobian:
        return d
    s = np.exp((e2 / e1) * xy - log_f)  # share of the xy term in F
    g = np.exp((2.0 / e2) * la[:, 0] - xy)  # share of x in the xy term
    safe_la = np.where(np.isfinite(la), la, 0.0)
    # dlogF / d(log|t_i|), i = x, y, z; and dlogF / de1, de2.
    dl = np.stack([2.0 * s * g / e1, 2.0 * s * (1.0 - g) / e1, 2.0 * (1.0 - s) / e1], axis=1)
    dxy_de2 = -(2.0 / e2**2) * (g * safe_la[:, 0] + (1.0 - g) * safe_la[:, 1])
    dlf_de2 = s * (xy / e1 + (e2 / e1) * dxy_de2)
    dlf_de1 = -s * e2 * xy / e1**2 - (1.0 - s) * 2.0 * safe_la[:, 2] / e1**2
    surface = norm * ratio
    k = -0.5 * e1 * surface  # dd / dlogF
    inv_t = np.divide(1.0, t, out=np.zeros_like(t), where=t != 0)
    dd_dt = (k[:, None] * dl) * inv_t + (t / norm[:, None]) * (ratio - 1.0)[:, None]
    J = np.empty((len(points), C.N_PARAMS))
    J[:, 0:3] = -(k[:, None] * dl) / a * np.sign(xi[0:3])
    J[:, 3] = surface * (-0.5 * log_f) + k * dlf_de1
    J[:, 4] = k * dlf_de2
    J[:, 5:8] = -dd_dt @ R.T  # t = R^T (x - p)
    J[:, 8:11] = np.einsum("ni,kji,nj->nk", dd_dt, dR, offset)  # dt_i / dr_k = (dR_k^T offset)_i
    return d, J


class _Mixture:
    """The Gaussian-uniform mixture over one point cloud: E-step, M-step, log-likelihood."""

    def __init__(self, points, outlier_weight):
        self.points = points
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.scale = float(np.linalg.norm(hi - lo))
        extent = np.maximum(hi - lo, 1e-3 * self.scale)
        self.log_uniform = np.log(outlier_weight) - float(np.sum(np.log(extent)))
        self.log_inlier = np.log1p(-outlier_weight)
        self.sigma2_floor = (_SIGMA_FLOOR * self.scale) ** 2
        centre = 0.5 * (lo + hi)
        big = np.full(3, np.inf)
        self.lower = np.concatenate([np.full(3, 1e-3 * self.scale), [C.SHAPE_BOUNDS[0]] * 2,
                                     centre - self.scale, -big])
        self.upper = np.concatenate([np.full(3, 2.0 * self.scale), [C.SHAPE_BOUNDS[1]] * 2,
                                     centre + self.scale, big])

    def feasible(self, xi):
        xi = np.array(xi, dtype=np.float64)
        xi[0:3] = np.abs(xi[0:3])
        span = self.upper - self.lower
        margin = np.where(np.isfinite(span), 1e-9 * span, 0.0)
        return np.clip(xi, self.lower + margin, self.upper - margin)

    def log_parts(self, d, sigma2):
        """Per-point log-densities of the inlier and outlier components, ``(2, n)``."""
        gauss = self.log_inlier - 1.5 * np.log(2.0 * np.pi * sigma2) - 0.5 * d * d / sigma2
        return np.stack([gauss, np.full_like(d, self.log_uniform)])

    def posterior(self, d, sigma2):
        parts = self.log_parts(d, sigma2)
        return np.exp(parts[0] - np.logaddexp(parts[0], parts[1]))

    def log_likelihood(self, xi, sigma2):
        parts = self.log_parts(radial_residuals(xi, self.points), sigma2)
        return float(np.mean(np.logaddexp(parts[0], parts[1])))

    def em(self, xi, sigma2, iterations):
        """Up to ``iterations`` EM iterations from ``(xi, sigma2)``; returns the state and the count."""
        step_scale = np.concatenate([np.full(3, self.scale), [1.0, 1.0], np.full(3, self.scale), [1.0] * 3])
        cost, done = 0.0, 0
        for done in range(1, iterations + 1):
            z = self.posterior(radial_residuals(xi, self.points), sigma2)
            w = np.sqrt(z)
            res = least_squares(lambda x: w * radial_residuals(x, self.points), xi,
                                jac=lambda x: w[:, None] * radial_residuals(x, self.points, jacobian=True)[1],
                                bounds=(self.lower, self.upper), method="trf", x_scale="jac",
                                max_nfev=M_STEP_EVALUATIONS)
            moved = np.max(np.abs(res.x - xi) / step_scale)
            xi, cost = self.feasible(res.x), float(res.cost)
            d = radial_residuals(xi, self.points)
            sigma2 = max(float(np.sum(z * d * d) / (3.0 * max(np.sum(z), 1e-12))), self.sigma2_floor)
            if moved < EM_TOL:
                break
        return xi, sigma2, cost, done


def _start(points):
    """Principal-axes start from a trimmed covariance (a few concentration steps of the minimum
    covariance determinant estimator), so uniform outliers do not inflate it."""
    keep = np.ones(len(points), dtype=bool)
    for _ in range(_TRIM_STEPS):
        centre = np.median(points[keep], axis=0)
        cov = np.cov((points[keep] - centre).T) + 1e-12 * np.eye(3)
        centred = points - centre
        mahalanobis = np.einsum("ni,ij,nj->n", centred, np.linalg.inv(cov), centred)
        keep = mahalanobis <= np.quantile(mahalanobis, _TRIM_KEEP)
    _, vectors = np.linalg.eigh(np.cov(centred[keep].T))
    R = vectors[:, ::-1].copy()  # largest spread on the local x axis
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    a = np.percentile(np.abs(centred[keep] @ R), START_PERCENTILE, axis=0)
    return np.concatenate([a, [1.0, 1.0], centre, matrix_to_euler(R)])


def fit_points(points, outlier_weight=OUTLIER_WEIGHT, max_points=MAX_POINTS, start=None):
    """Fit one superquadric to a point cloud with outliers (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float
        World coordinates, metres; n >= 11.
    outlier_weight : float
        Prior outlier probability ``w``, in (0, 1).
    max_points : int
        Points used (>= 11); a larger cloud is thinned by a fixed stride.
    start : (11,) float, optional
        Initial parameter vector instead of the principal-axes start.

    Returns
    -------
    fit : PointFit

    Raises
    ------
    ValueError
        If ``points`` is not ``(n, 3)`` finite with n >= 11, is degenerate (all points equal), or
        an argument is out of range.
    """
    points = check_shape(points, (None, 3), "points")
    if int(max_points) != max_points or max_points < C.N_PARAMS:
        raise ValueError(f"max_points must be an integer >= {C.N_PARAMS}, got {max_points}")
    if len(points) < C.N_PARAMS:
        raise ValueError(f"points must hold >= {C.N_PARAMS} points for 11 parameters, got {len(points)}")
    if not 0.0 < outlier_weight < 1.0:
        raise ValueError(f"outlier_weight must be in (0, 1), got {outlier_weight}")
    if np.ptp(points, axis=0).max() <= 0:
        raise ValueError("points are all equal: no surface to fit")
    if len(points) > max_points:
        points = points[np.linspace(0, len(points) - 1, int(max_points)).round().astype(np.int64)]
    mix = _Mixture(points, outlier_weight)
    xi = mix.feasible(_start(points) if start is None else check_shape(start, (C.N_PARAMS,), "start"))
    d = radial_residuals(xi, points)
    sigma2 = max(float(np.mean(d * d)) / 3.0, mix.sigma2_floor)
    xi, sigma2, cost, total = mix.em(xi, sigma2, EM_ITERATIONS)
    best = mix.log_likelihood(xi, sigma2)
    switches = 0
    for _ in range(MAX_SWITCHES):
        trials = []
        for cand in symmetric_candidates(xi):
            cx, cs, cc, n = mix.em(mix.feasible(cand), sigma2, SWITCH_ITERATIONS)
            total += n
            trials.append((mix.log_likelihood(cx, cs), cx, cs, cc))
        score, cx, cs, cc = max(trials, key=lambda t: t[0])
        if score <= best + SWITCH_MARGIN:
            break
        xi, sigma2, cost, n = mix.em(cx, cs, EM_ITERATIONS)
        total += n
        best, switches = mix.log_likelihood(xi, sigma2), switches + 1
    z = mix.posterior(radial_residuals(xi, points), sigma2)
    return PointFit(xi, float(np.sqrt(sigma2)), z, best, total, switches, cost)
