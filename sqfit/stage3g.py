"""Stage 3G (beyond the paper): the two-sided silhouette cost of :mod:`sqfit.raycost`, all 11 parameters.

``3G`` runs Levenberg-Marquardt (:mod:`sqfit.lm`, dense, analytic Jacobian) on the residuals of
:func:`sqfit.raycost.ray_residuals`: for :data:`N_CONTOUR` points evenly spaced along each view's
mask outline (``Observation.contour``), the ray through the point should graze the superquadric
(``m = 1``: too small and the ray misses, too large and it passes through), plus the penalty rows
of eq. 7 with ``c_p = options.penalty_analytic``. Only the 11 parameters are unknown (no depths):
the minimiser along each ray is an inner problem whose derivative the envelope theorem removes.
Unlike G5 it needs no volume factor against over-size, and unlike the numeric R-IOU (3A) it has a
gradient when the superquadric and the mask do not overlap.

The rays are computed once per :class:`sqfit.costs.ObservationSet` and cached with it.
"""

from __future__ import annotations

import weakref
from dataclasses import replace

import numpy as np

from .lm import DenseJacobian, levenberg_marquardt
from .raycost import contour_rays, ray_residuals
from .stages import StageError, register

__all__ = ["N_CONTOUR", "BAND_PX", "silhouette_stage"]

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


def silhouette_stage(state, obs, options, name="3G"):
    """Levenberg-Marquardt on the 3G residuals from ``state.xi``; returns the new state."""
    rays = _rays(obs)
    xi0 = np.array(state.xi, dtype=np.float64)
    warm = {}

    def model(x):
        r, J, d = ray_residuals(x, rays, options.penalty_analytic, warm.get("d"))
        warm["d"] = d
        return r, DenseJacobian(J)

    res = levenberg_marquardt(model, xi0, max_iterations=options.max_iterations_analytic,
                              ftol=options.ftol_analytic, xtol=options.xtol, gtol=options.gtol)
    xi = res.x
    if not np.all(np.isfinite(xi)) or np.max(np.abs(xi[0:3])) > 1e4:
        raise StageError("diverged", f"stage {name}: the optimiser diverged")
    return replace(state, xi=xi, cost=res.cost, status=res.status, message=res.message, nfev=res.nfev)


@register("3G")
def stage_3g(state, obs, options):
    """Stage 3G: two-sided silhouette (ray-gauge) cost, all 11 parameters, analytic Jacobian."""
    return silhouette_stage(state, obs, options)
