"""Stage 3G (beyond the paper): the two-sided silhouette cost of :mod:`sqfit.fitting.raycost`, all 11 parameters.

``3G`` runs Levenberg-Marquardt (:mod:`sqfit.fitting.lm`, dense, analytic Jacobian) on the residuals of
:func:`sqfit.fitting.raycost.ray_residuals`: for :data:`N_CONTOUR` points evenly spaced along each view's
mask outline (``Observation.contour``), the ray through the point should graze the superquadric
(``m = 1``: too small and the ray misses, too large and it passes through), plus the penalty rows
of eq. 7 with ``c_p = options.penalty_analytic``. Only the 11 parameters are unknown (no depths):
the minimiser along each ray is an inner problem whose derivative the envelope theorem removes.
Unlike G5 it needs no volume factor against over-size, and unlike the numeric R-IOU (3A) it has a
gradient when the superquadric and the mask do not overlap.

The rays are computed once per :class:`sqfit.fitting.costs.ObservationSet` and cached with it.

Pose refinement (``options.pose_sigma_deg > 0``, the default): the cameras' rotations are not
trusted exactly. After the plain run above converges, a second run estimates a small rotation
correction per view jointly with the 11 parameters (:func:`sqfit.fitting.raycost.posed_ray_residuals`,
``11 + 3 v`` unknowns), held near zero by prior rows ``w_v / sigma``. All views turning together is nearly the same as moving the superquadric; that
freedom is held by the prior only. The corrections are used inside this stage only (later stages
and R-IOU-M see the given cameras); the stage message lists them, in degrees, as rotation vectors
``delta_v`` in each camera's frame (corrected pose rotation ``R_v exp([delta_v]x)``).
"""

from __future__ import annotations

import weakref
from dataclasses import replace

import numpy as np

from .lm import DenseJacobian, levenberg_marquardt
from .raycost import posed_ray_residuals, ray_residuals
from ..views.rays import contour_rays
from .stages import StageError, register

__all__ = ["N_CONTOUR", "BAND_PX", "silhouette_stage", "minimise", "camera_corrections"]

#: Contour points (rays) per view.
N_CONTOUR = 64
#: 0: grazing residuals on the contour; > 0: inside / outside hinge residuals this many px off it.
BAND_PX = 0.0

_RAYS = weakref.WeakKeyDictionary()


def _rays(obs):
    key = (N_CONTOUR, BAND_PX)
    cached = _RAYS.get(obs)
    if cached is None or cached[0] != key:
        cached = (key, contour_rays(obs.observations, N_CONTOUR, BAND_PX))
        _RAYS[obs] = cached
    return cached[1]


def silhouette_stage(state, obs, options, name="3G", plain_first=True):
    """Levenberg-Marquardt on the 3G residuals from ``state.xi``; returns the new state.

    ``plain_first=False`` skips the run without pose corrections when they are estimated (for a
    start that is already in the right basin, such as the end of 3H's screen).
    """
    rays = _rays(obs)
    xi0 = np.array(state.xi, dtype=np.float64)
    sigma = np.radians(options.pose_sigma_deg)
    res = None
    nfev = 0
    if sigma == 0 or plain_first:
        res = minimise(rays, xi0, options, 0.0)
        nfev = res.nfev
    if sigma > 0:
        # A second run, from the plain optimum: started from stage 2 the extra unknowns change
        # Levenberg-Marquardt's path and sometimes its basin, which cost clean fits accuracy.
        start = xi0 if res is None else res.x
        res = minimise(rays, np.concatenate([start, np.zeros(3 * len(obs))]), options, sigma)
        nfev += res.nfev
    xi = res.x[:len(xi0)]
    if not np.all(np.isfinite(res.x)) or np.max(np.abs(xi[0:3])) > 1e4:
        raise StageError("diverged", f"stage {name}: the optimiser diverged")
    message = res.message
    if sigma > 0:
        message += "; " + _describe_corrections(camera_corrections(res.x[len(xi0):], obs.rotations))
    return replace(state, xi=xi, cost=res.cost, status=res.status, message=message, nfev=nfev)


def minimise(rays, x0, options, sigma):
    """LM on the 3G residuals of ``rays`` (:func:`sqfit.views.rays.contour_rays`) from ``x0``:
    ``(11,)`` if ``sigma == 0``, else ``(11 + 3 v,)`` with pose corrections and prior scale
    ``sigma`` (radians). Returns the :class:`sqfit.fitting.lm.LMResult`; used by 3G and by 3S
    (:mod:`sqfit.fitting.restarts`) to screen candidates on its own rays."""
    warm = {}

    def model(x):
        if sigma > 0:
            r, J, d = posed_ray_residuals(x, rays, sigma, options.penalty_analytic, warm.get("d"))
        else:
            r, J, d = ray_residuals(x, rays, options.penalty_analytic, warm.get("d"))
        warm["d"] = d
        return r, DenseJacobian(J)

    return levenberg_marquardt(model, x0, max_iterations=options.max_iterations_analytic,
                               ftol=options.ftol_analytic, xtol=options.xtol, gtol=options.gtol)


def camera_corrections(w, rotations):
    """Per-view rotation corrections in each camera's frame.

    Parameters
    ----------
    w : (3 v,) float
        World-frame rotation vectors (radians), as estimated by 3G with pose refinement.
    rotations : (v, 3, 3) float
        Camera-to-world rotations ``R_v``.

    Returns
    -------
    delta : (v, 3) float
        ``R_v^T w_v``, radians: the corrected camera rotation is ``R_v exp([delta_v]x)``.
    """
    return np.einsum("vji,vj->vi", rotations, np.reshape(w, (len(rotations), 3)))


def _describe_corrections(delta):
    views = ", ".join("(" + ", ".join(f"{c:+.3f}" for c in np.degrees(dv)) + ")" for dv in delta)
    return f"camera rotation corrections [deg, camera frame]: {views}"


@register("3G")
def stage_3g(state, obs, options):
    """Stage 3G: two-sided silhouette (ray-gauge) cost, all 11 parameters, analytic Jacobian."""
    return silhouette_stage(state, obs, options)
