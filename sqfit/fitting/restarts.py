"""Stage 3S (beyond the paper): multi-starts over the superquadric's symmetries, after a 3G fit.

3G (:mod:`sqfit.fitting.grazing`) is a local method. On the paper scene (100 trials, 1-2-3G) many of its
poor fits are local minima in which the wrong local axis carries ``e1`` (the "latitude" exponent
belongs to the z axis; the other two sections share ``e2``), a few have a square-ish section
turned by 45 degrees: the true shape is a symmetric re-parametrisation of the fit away, but
Levenberg-Marquardt does not cross the ridge between the two. ``3S`` tries those
re-parametrisations as new starts.

Candidates (:func:`symmetric_candidates`; 5 besides the input, ``CANDIDATES`` in order):

- ``P1``, ``P2``: another local axis becomes the z axis (cyclic permutations, so the frame stays
  right-handed; ``a`` permuted with it). The new xy section was a section of exponent ``e1``, so
  ``e1`` and ``e2`` are swapped. Exact when ``e1 == e2``; otherwise only the start of a new basin.
- ``R45``, ``P1R45``, ``P2R45``: each of the three frames turned 45 degrees about its z axis, with
  ``e2 -> 2 - e2`` and both xy sizes set to the radius of the old xy section along the diagonal.
  Exact for a square section (``ax == ay``) at ``e2`` in ``{0, 1, 2}`` (a square of half-side
  ``s`` is a diamond of radius ``sqrt(2) s``), close for other ``e2``; otherwise a start.

Stage ``3S`` (times per object on the paper scene, one process):

1. Gate: the 3G misfit of the input, ``sqrt(sum r**2 / v)`` of :func:`sqfit.fitting.raycost.ray_residuals`
   on :data:`N_SCREEN_CONTOUR` outline rays per view (penalty rows included; ``v`` views), i.e.
   the RMS over views of each view's RMS grazing residual. At or below :data:`TRIGGER_MISFIT`
   the input is returned unchanged (one residual evaluation: ~5 ms).
2. Screen: ``P1`` and ``P2``, and each 45-degree candidate whose frame's xy sizes are within a
   factor :data:`SQUARE_RATIO` of each other (the 45-degree ambiguity needs a square-ish
   section), get :data:`SCREEN_ITERATIONS` Levenberg-Marquardt steps of plain 3G (no pose
   corrections) on the same coarse rays (~10 ms per candidate). Unrefined candidates cannot be
   ranked, by R-IOU-M or by the misfit: the right start often scores worst before these steps.
3. The screened candidate with the lowest misfit, if below :data:`REFINE_RATIO` times the input's
   and with an R-IOU-M at most :data:`RIOU_M_SLACK` below the input's, is refined by the full 3G
   stage (:func:`sqfit.fitting.grazing.silhouette_stage`, pose corrections included: 35-120 ms) and
   replaces the input if its misfit is still lower and its R-IOU-M passes the same guard. R-IOU-M
   is only a guard: against the hull of the samples the true shape and the wrong-axis fit often
   score the same, while their 3G misfits differ by a factor 3-10.

The input state's cost is not used, so ``3S`` may follow any stage; it is meant to follow ``3G``.
Deterministic; no random numbers.

Measured (paper scene, 100 ``paper_trial`` seeds 0-99, one process, each trial's chains timed
alternately, best of 2; median time relative to 1-2-3G, which took 71-89 ms in these runs;
several runs, hence ranges):

===============  ===========  ===========  ===========  ========  ========  ================
TRIGGER_MISFIT   triggered    IoU median   IoU mean     IoU<0.7   IoU<0.5   median time
===============  ===========  ===========  ===========  ========  ========  ================
(1-2-3G alone)   -            0.920        0.856        12        4         1
0.01             61           0.995        0.924        6         4         1.65-1.71
0.02             37           0.984        0.899        9         4         1.36-1.44
0.03             28           0.973        0.889        10        4         1.25-1.33
0.04 (default)   19           0.944        0.879        10        4         1.13-1.16
===============  ===========  ===========  ===========  ========  ========  ================

Reproduce with ``benchmarks/bench_multistart.py``. The median time is set by how many fits
trigger (a triggered fit costs about 3G again), so the gate, not the screen, is the knob. The
gate is absolute, and noise raises the misfit floor: with 2 px boundary jitter and 1 degree of
pose rotation (``scenes/paper.toml`` with those noise keys, polygon masks, 40 trials) 37 of 40
fits trigger at 0.04, the median time grows by 43 % and the IoU median / mean only from
0.658 / 0.625 to 0.670 / 0.632 (the misfit is measured with the given poses, not 3G's corrected
ones).

Not fixed at any setting: the IoU < 0.5 fits (far, huge 3G minima that graze every outline ray;
wrong basins with a poor silhouette fit whose symmetric starts do not lead out), and fits the
three views cannot tell from the truth (misfit as low as the truth's).
"""

from __future__ import annotations

import weakref
from dataclasses import replace

import numpy as np

from .. import constants as C
from .._checks import check_shape
from .raycost import RAY_BOUNDS, ray_bounds, ray_residuals
from ..views.rays import contour_rays
from .grazing import SMOOTH_PX, minimise, silhouette_stage
from .stages import FitState, r_iou_m, register, to_superquadric
from ..geometry.superquadric import euler_to_matrix, matrix_to_euler

__all__ = ["CANDIDATES", "N_SCREEN_CONTOUR", "SCREEN_ITERATIONS", "TRIGGER_MISFIT", "REFINE_RATIO",
           "SQUARE_RATIO", "RIOU_M_SLACK", "symmetric_candidates", "screen_rays", "misfit", "multistart_stage"]

#: Names of the rows of :func:`symmetric_candidates`, in order.
CANDIDATES = ("R45", "P1", "P1R45", "P2", "P2R45")
#: 45-degree candidates are screened only if their frame's xy sizes are within this factor.
SQUARE_RATIO = 1.2
#: Outline rays per view of the gate and the screen (3G itself uses 64).
N_SCREEN_CONTOUR = 16
#: Levenberg-Marquardt iterations per screened candidate.
SCREEN_ITERATIONS = 3
#: 3G misfit (unitless: RMS of log-gauge residuals) above which the input is re-started. The
#: trade-off of accuracy and time (paper scene, 100 trials, module docstring): 0.01 triggers on
#: 61 % of the fits, 0.02 on 37 %, 0.03 on 28 %, 0.04 on 19 %.
TRIGGER_MISFIT = 0.04
#: The best screened candidate is refined only if its misfit is below this times the input's.
REFINE_RATIO = 0.8
#: A candidate may lose at most this much R-IOU-M against the input (guards against degenerate
#: 3G minima: a far, huge superquadric that grazes every outline ray with a wrong silhouette).
RIOU_M_SLACK = 0.05

# Cyclic axis permutations: new local axis k is old axis _PERMUTATIONS[i][k].
_PERMUTATIONS = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
_EIGHTH_TURN = np.pi / 4
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
    sizes, shapes, frames = [], [], []
    for i, perm in enumerate(_PERMUTATIONS):
        Rp, ap, ep = R[:, perm], a[list(perm)], e if i == 0 else e[::-1]
        if i:
            sizes.append(ap)
            shapes.append(ep)
            frames.append(Rp)
        s = diagonal_radius(ap[0], ap[1], ep[1])
        sizes.append([s, s, ap[2]])
        shapes.append([ep[0], 2.0 - ep[1]])
        frames.append(Rp @ _rot_z(_EIGHTH_TURN))
    rows = np.empty((len(frames), C.N_PARAMS))
    rows[:, C.SIZE] = sizes
    rows[:, C.SHAPE] = np.clip(shapes, *C.SHAPE_BOUNDS)
    rows[:, C.POSITION] = xi[C.POSITION]
    rows[:, C.ROTATION] = matrix_to_euler(np.array(frames))  # one closed-form call for all rows
    return rows


def diagonal_radius(ax, ay, e2):
    """Radius of the section ``|x/ax|^(2/e2) + |y/ay|^(2/e2) = 1`` along the diagonal ``x = y``.

    ``ax``, ``ay`` in metres, ``e2 > 0``; returns metres.
    """
    return np.sqrt(2.0) * (ax ** (-2.0 / e2) + ay ** (-2.0 / e2)) ** (-e2 / 2.0)


def _rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def screen_rays(obs):
    """The :data:`N_SCREEN_CONTOUR` outline rays per view of ``obs`` (points smoothed as 3G's,
    :data:`sqfit.fitting.grazing.SMOOTH_PX`), made once per observation set (cached while ``obs``
    lives; 3H's screen uses the same)."""
    rays = _SCREEN_RAYS.get(obs)
    if rays is None:
        rays = contour_rays(obs.observations, N_SCREEN_CONTOUR, smooth_px=SMOOTH_PX)
        _SCREEN_RAYS[obs] = rays
    return rays


def misfit(xi, rays, penalty_weight=C.PENALTY_ANALYTIC, bounds=RAY_BOUNDS):
    """3G misfit of ``xi``: ``sqrt(sum r**2 / v)`` over the rows of :func:`sqfit.fitting.raycost.ray_residuals`
    (penalty rows at ``bounds``, :func:`sqfit.fitting.raycost.ray_bounds`: those 3G's fits ran under).

    With the per-view weights of :func:`sqfit.views.rays.contour_rays` this is the RMS over the ``v``
    views of each view's RMS grazing residual (plus the penalty rows, zero inside the bounds).
    Equals ``sqrt(2 cost / v)`` for a Levenberg-Marquardt cost on the same rays.
    """
    r = ray_residuals(np.asarray(xi, dtype=np.float64), rays, penalty_weight, bounds=bounds)[0]
    return float(np.sqrt(np.sum(r * r) / _views(rays)))


def _views(rays):
    return len(np.unique(rays.view))


def _worth_screening(xi, candidates):
    """``(5,) bool`` per row of :data:`CANDIDATES`: the permutations, and the 45-degree turns of
    square-ish sections (the section a candidate turns is the xy section of ``xi``, ``P1`` or ``P2``)."""
    frames = np.stack([xi, candidates[CANDIDATES.index("P1")], candidates[CANDIDATES.index("P2")]])
    xy = np.abs(frames[:, 0:2])
    square = xy.max(axis=1) <= SQUARE_RATIO * xy.min(axis=1)
    return np.array([square[0], True, square[1], True, square[2]])


def _screen(candidates, rays, options):
    """A few plain-3G steps from each candidate: ``(k, 11)`` end points, ``(k,)`` misfits, nfev."""
    short = replace(options, max_iterations_analytic=SCREEN_ITERATIONS)
    results = [minimise(rays, c, short, 0.0) for c in candidates]
    ends = np.array([r.x for r in results])
    costs = np.array([r.cost for r in results])
    return ends, np.sqrt(2.0 * costs / _views(rays)), sum(r.nfev for r in results)


@register("3S")
def multistart_stage(state, obs, options):
    """Stage 3S: re-start a poor fit from its symmetric re-parametrisations (module docstring)."""
    rays = screen_rays(obs)
    xi = np.array(state.xi, dtype=np.float64)
    bounds = ray_bounds(options.size_min_m)
    base = misfit(xi, rays, options.penalty_analytic, bounds)
    nfev = 1
    if not base > TRIGGER_MISFIT:  # also catches a NaN misfit: nothing to compare against
        return replace(state, message=f"3S: misfit {base:.4f} <= {TRIGGER_MISFIT}: kept", nfev=nfev)
    xi = to_superquadric(xi).to_vector()
    candidates = symmetric_candidates(xi)
    picked = np.flatnonzero(_worth_screening(xi, candidates))
    ends, scores, n = _screen(candidates[picked], rays, options)
    nfev += n
    m = r_iou_m([to_superquadric(x) for x in np.vstack([xi, ends])], obs, options.polygon)
    scores = np.where(np.isfinite(scores) & (m[1:] >= m[0] - RIOU_M_SLACK), scores, np.inf)
    best = int(np.argmin(scores))
    label = CANDIDATES[picked[best]]
    if not scores[best] < REFINE_RATIO * base:
        return replace(state, nfev=nfev, message=f"3S: misfit {base:.4f}, best screened {label} "
                                                 f"{scores[best]:.4f}: kept")
    new = silhouette_stage(FitState(ends[best]), obs, options, name="3S")
    nfev += new.nfev + 1
    new_misfit = misfit(new.xi, rays, options.penalty_analytic, bounds)
    new_m = r_iou_m([to_superquadric(new.xi)], obs, options.polygon)[0]
    if new_misfit < base and new_m >= m[0] - RIOU_M_SLACK:
        return replace(state, xi=new.xi, cost=new.cost, status=new.status, nfev=nfev,
                       outline_offsets=new.outline_offsets,
                       message=f"3S: misfit {base:.4f} -> {new_misfit:.4f} from {label}; {new.message}")
    return replace(state, nfev=nfev, message=f"3S: misfit {base:.4f}, {label} refined to "
                                             f"{new_misfit:.4f}: kept")
