"""Stage 3S (beyond the paper): multi-starts over the superquadric's symmetries, after a 3G fit.

3G (:mod:`sqfit.stage3g`) is a local method. On the paper scene (100 trials, 1-2-3G) most of its
poor fits are local minima in which the wrong local axis carries ``e1`` (the "latitude" exponent
belongs to the z axis; the other two sections share ``e2``), and some have a square-ish section
turned by 45 degrees; the true shape is a symmetric re-parametrisation of the fit away, but
Levenberg-Marquardt does not cross the ridge between the two. ``3S`` tries those
re-parametrisations as new starts.

Candidates (:func:`symmetric_candidates`; 5 besides the input, ``CANDIDATES`` in order):

- ``P1``, ``P2``: another local axis becomes the z axis (cyclic permutations, so the frame stays
  right-handed; ``a`` permuted with it). The new xy section was a section of exponent ``e1``, so
  ``e1`` and ``e2`` are swapped. Exact when ``e1 == e2``; otherwise only the start of a new basin.
- ``R45``, ``P1R45``, ``P2R45``: each of the three frames turned 45 degrees about its z axis, with
  ``e2 -> 2 - e2`` and both xy sizes set to the radius of the old xy section along the diagonal.
  Exact for a square section (``ax == ay``) at ``e2`` in ``{0, 1, 2}`` (a square of side ``2 s``
  is a diamond of radius ``sqrt(2) s``); otherwise a start.

Stage ``3S`` (cost per object in brackets, paper scene, one process):

1. Gate: the 3G misfit of the input, ``sqrt(sum r**2 / v)`` of :func:`sqfit.raycost.ray_residuals`
   on :data:`N_SCREEN_CONTOUR` outline rays per view (penalty rows included; ``v`` views), i.e.
   the RMS over views of each view's RMS grazing residual. At or below :data:`TRIGGER_MISFIT`
   the input is returned unchanged (one residual evaluation, ~3 ms).
2. Screen: the candidates of ``SCREENED`` each get :data:`SCREEN_ITERATIONS` Levenberg-Marquardt
   steps of plain 3G (no pose corrections) on the same coarse rays (~13 ms per candidate).
3. The screened candidate with the lowest misfit, if lower than the input's and its R-IOU-M not
   more than :data:`RIOU_M_SLACK` below the input's (R-IOU-M alone cannot tell these fits apart:
   against the hull of the samples the true shape and the wrong-axis fit often score the same,
   while the 3G misfit differs by a factor 3-10), is refined by the full 3G stage
   (:func:`sqfit.stage3g.silhouette_stage`, pose corrections included, ~60 ms) and replaces the
   input if its coarse misfit is still lower and its R-IOU-M passes the same guard.

The input state's cost is not used, so ``3S`` may follow any stage; it is meant to follow ``3G``.
Deterministic; no random numbers.
"""

from __future__ import annotations

import weakref
from dataclasses import replace

import numpy as np

from . import constants as C
from ._checks import check_shape
from .pipeline import r_iou_m, to_superquadric
from .raycost import contour_rays, ray_residuals
from .stage3g import _minimise, silhouette_stage
from .stages import FitState, register
from .superquadric import euler_to_matrix, matrix_to_euler

__all__ = ["CANDIDATES", "SCREENED", "N_SCREEN_CONTOUR", "SCREEN_ITERATIONS", "TRIGGER_MISFIT",
           "RIOU_M_SLACK", "symmetric_candidates", "misfit", "multistart_stage"]

#: Names of the rows of :func:`symmetric_candidates`, in order.
CANDIDATES = ("R45", "P1", "P1R45", "P2", "P2R45")
#: The candidates stage 3S screens.
SCREENED = CANDIDATES
#: Outline rays per view of the gate and the screen (3G itself uses 64).
N_SCREEN_CONTOUR = 16
#: Levenberg-Marquardt iterations per screened candidate.
SCREEN_ITERATIONS = 3
#: 3G misfit (unitless: RMS of log-gauge residuals) above which the input is re-started.
TRIGGER_MISFIT = 0.02
#: A candidate may lose at most this much R-IOU-M against the input (guards against degenerate
#: 3G minima: a far, huge superquadric that grazes every outline ray with a wrong silhouette).
RIOU_M_SLACK = 0.05

# Cyclic axis permutations: new local axis k is old axis _PERMUTATIONS[i][k].
_PERMUTATIONS = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
_QUARTER_TURN = np.pi / 4
_SCREEN_RAYS = weakref.WeakKeyDictionary()


def symmetric_candidates(xi):
    """Symmetric re-parametrisations of a superquadric, as new starts (see the module docstring).

    Parameters
    ----------
    xi : (11,) float
        Parameter vector (``|a|`` is used; ``e`` must lie in ``constants.SHAPE_DOMAIN``).

    Returns
    -------
    candidates : (5, 11) float
        Rows in the order of :data:`CANDIDATES`; the centre is unchanged, ``e`` is clipped to
        ``constants.SHAPE_BOUNDS``.

    Raises
    ------
    ValueError
        If ``xi`` is not 11 finite numbers, a size is 0 or ``e`` is outside the shape domain.
    """
    xi = check_shape(xi, (C.N_PARAMS,), "xi")
    a, e = np.abs(xi[C.SIZE]), xi[C.SHAPE]
    if np.any(a == 0):
        raise ValueError(f"xi: sizes must be non-zero, got {a.tolist()}")
    lo, hi = C.SHAPE_DOMAIN
    if np.any((e < lo) | (e > hi)):
        raise ValueError(f"xi: shape exponents must be in [{lo}, {hi}], got {e.tolist()}")
    R = euler_to_matrix(xi[C.ROTATION])
    rows = []
    for i, perm in enumerate(_PERMUTATIONS):
        Rp, ap, ep = R[:, perm], a[list(perm)], e if i == 0 else e[::-1]
        if i:
            rows.append(_vector(ap, ep, xi[C.POSITION], Rp))
        s = diagonal_radius(ap[0], ap[1], ep[1])
        rows.append(_vector([s, s, ap[2]], [ep[0], 2.0 - ep[1]], xi[C.POSITION], Rp @ _rot_z(_QUARTER_TURN)))
    return np.array(rows)


def diagonal_radius(ax, ay, e2):
    """Radius of the section ``|x/ax|^(2/e2) + |y/ay|^(2/e2) = 1`` along the diagonal ``x = y``.

    ``ax``, ``ay`` in metres, ``e2 > 0``; returns metres.
    """
    return np.sqrt(2.0) * (ax ** (-2.0 / e2) + ay ** (-2.0 / e2)) ** (-e2 / 2.0)


def _rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _vector(a, e, p, R):
    return np.concatenate([a, np.clip(e, *C.SHAPE_BOUNDS), p, matrix_to_euler(R)])


def _screen_rays(obs):
    rays = _SCREEN_RAYS.get(obs)
    if rays is None:
        rays = contour_rays(obs.observations, N_SCREEN_CONTOUR)
        _SCREEN_RAYS[obs] = rays
    return rays


def misfit(xi, rays, penalty_weight=C.PENALTY_ANALYTIC):
    """3G misfit of ``xi``: ``sqrt(sum r**2 / v)`` over the rows of :func:`sqfit.raycost.ray_residuals`.

    With the per-view weights of :func:`sqfit.raycost.contour_rays` this is the RMS over the ``v``
    views of each view's RMS grazing residual (plus the penalty rows, zero inside the bounds).
    Equals ``sqrt(2 cost / v)`` for a Levenberg-Marquardt cost on the same rays.
    """
    r = ray_residuals(np.asarray(xi, dtype=np.float64), rays, penalty_weight)[0]
    return float(np.sqrt(np.sum(r * r) / _views(rays)))


def _views(rays):
    return len(np.unique(rays.view))


def _screen(candidates, rays, options):
    """A few plain-3G steps from each candidate: ``(k, 11)`` end points, ``(k,)`` misfits, nfev."""
    short = replace(options, max_iterations_analytic=SCREEN_ITERATIONS)
    results = [_minimise(rays, c, short, 0.0) for c in candidates]
    ends = np.array([r.x for r in results])
    costs = np.array([r.cost for r in results])
    return ends, np.sqrt(2.0 * costs / _views(rays)), sum(r.nfev for r in results)


@register("3S")
def multistart_stage(state, obs, options):
    """Stage 3S: re-start a poor fit from its symmetric re-parametrisations (module docstring)."""
    rays = _screen_rays(obs)
    xi = np.array(state.xi, dtype=np.float64)
    base = misfit(xi, rays, options.penalty_analytic)
    nfev = 1
    if not base > TRIGGER_MISFIT:  # also catches a NaN misfit: nothing to compare against
        return replace(state, message=f"3S: misfit {base:.4f} <= {TRIGGER_MISFIT}: kept", nfev=nfev)
    picked = [CANDIDATES.index(name) for name in SCREENED]
    candidates = symmetric_candidates(to_superquadric(xi).to_vector())[picked]
    ends, scores, n = _screen(candidates, rays, options)
    nfev += n
    m = r_iou_m([to_superquadric(x) for x in np.vstack([xi, ends])], obs, options.polygon)
    scores = np.where(np.isfinite(scores) & (m[1:] >= m[0] - RIOU_M_SLACK), scores, np.inf)
    best = int(np.argmin(scores))
    if not scores[best] < base:
        return replace(state, message=f"3S: misfit {base:.4f}, no candidate better: kept", nfev=nfev)
    new = silhouette_stage(FitState(ends[best]), obs, options, name="3S")
    nfev += new.nfev + 1
    new_misfit = misfit(new.xi, rays, options.penalty_analytic)
    new_m = r_iou_m([to_superquadric(new.xi)], obs, options.polygon)[0]
    label = SCREENED[best]
    if new_misfit < base and new_m >= m[0] - RIOU_M_SLACK:
        return replace(state, xi=new.xi, cost=new.cost, status=new.status, nfev=nfev,
                       message=f"3S: misfit {base:.4f} -> {new_misfit:.4f} from {label}; {new.message}")
    return replace(state, nfev=nfev, message=f"3S: misfit {base:.4f}, {label} refined to "
                                             f"{new_misfit:.4f}: kept")
