"""Stage 3H (in the default chain): choose the superquadric's axes, then fit 3G.

3G (:mod:`sqfit.fitting.grazing`) is a local method, and the start it gets from stage 2 (PCA of the
back-projected samples: an ellipsoid, ``e = (1, 1)``) does not say which local axis carries the
"latitude" exponent ``e1`` nor whether a square-ish section should be turned by 45 degrees: an
ellipsoid is the same surface under all those re-parametrisations, but the superquadrics they
grow into are not, and Levenberg-Marquardt rarely crosses from one to another later. ``3H``
therefore decides before 3G, from the 3G cost itself:

1. Candidates (:func:`axis_candidates`, 6 rows): the input, its two other choices of z axis
   (cyclic permutations of the axes, ``e1`` and ``e2`` swapped), and each of these three frames
   turned 45 degrees about its z axis (``e2 -> 2 - e2``, xy sizes set to the section's diagonal
   radius); see :func:`sqfit.fitting.restarts.symmetric_candidates`.
2. Screen: :data:`SCREEN_ITERATIONS` Levenberg-Marquardt steps of plain 3G (no pose
   corrections) for all candidates at once on :data:`N_SCREEN_CONTOUR` outline rays per view:
   one vectorised ray solve per step for the whole batch (:func:`sqfit.fitting.raycost.batch_ray_residuals`,
   :func:`batch_levenberg_marquardt`), not a Python loop over candidates.
3. The screened candidate with the lowest cost is refined by one 3G run with the per-camera pose
   corrections (:func:`sqfit.fitting.grazing.silhouette_stage` without its plain first run, relative
   cost tolerance :data:`REFINE_FTOL`).
   With the outline offset estimated (``FitOptions.outline_offset_sigma_px > 0``, the default;
   :mod:`sqfit.fitting.grazing`), an estimate beyond :data:`RESCREEN_PX` means the screen ranked
   the candidates on biased outlines: steps 1-3 run once more on rays moved by the estimate (the
   refinement starting from it), and the fit with the lower cost is kept.
   When the refinement's rotation corrections say that the cameras disagree (pose noise; the prior
   is then scaled to the residual noise, :func:`sqfit.fitting.grazing.silhouette_fit`), the screen's
   ranking is not trusted either: it ran without pose corrections, on views that contradict each
   other, and the right candidate often ranked 4th-6th. Every candidate is then refined under that
   one prior and the lowest cost is kept (2 px jitter + 1 deg rotation, 100 trials, seeds 0 / 1:
   refining the screen's best under the fixed prior lost 17 / 29 trials by more than 0.05 of IoU to
   3G started at the truth, and in 22 of seed 1's 29 the truth-started fit had the lower cost;
   refining the best 2 or 3 candidates recovered little, all 6 most). Consistent cameras seldom
   take this branch (clean paper masks: final RMS corrections at most 0.155 deg against the 0.25 deg
   threshold); 2-3 of 100 clean or +-1 px bias fits do, when the screen's best lands in a wrong
   basin whose misfit the corrections absorb, and there it helps (``paper_trial(4)``: 0.799 ->
   0.998). Median time on clean masks is unchanged.
   Where the refinement's nuisance unknowns are idle -- the cameras agree (its pose-noise estimate
   at most :data:`sqfit.fitting.grazing.POSE_NOISE_TRIGGER_DEG`) and the outline offset is within
   :data:`IDLE_OFFSET_PX`, or beyond it but not kept by the plain fit's basin
   (:data:`PLAIN_BASIN_COST_RATIO`) -- and the superquadric grazes the outline (the refinement's cost at most
   :data:`sqfit.fitting.outline.TRIGGER_COST`, below 3T's domain), the fit is plain 3G (no pose
   corrections, no offset) started at the refinement's result, from sharp edges too, with a slab's
   section held square and a box below the size floor: :mod:`sqfit.fitting.plain_run`, where what
   was measured for each is written. At the size floor, where cameras that seem to disagree may be the
   floor's doing, the plain fit is also taken where it costs no more than the refinement
   (:data:`FLOOR_NOISE_COST_RATIO`). ``FitOptions.idle_nuisances_plain = False`` leaves it out
   (:mod:`sqfit.graph`'s landmark fits).
4. Rescue: when the result's silhouettes miss the masks (R-IOU-M below :data:`RESCUE_R_IOU_M`;
   ~2 % of paper trials, mostly needles and slabs with an aspect ratio above 10, where stage 2's
   ellipsoid is far off and 3G slides into its "far, huge" minimum: a large superquadric behind the
   object that grazes every outline ray), the input is fitted again through 3D and 3A
   (:data:`RESCUE_STAGES`, costs without that minimum) and steps 1-3, and the fit with the higher
   R-IOU-M is kept. It costs one R-IOU-M evaluation (~0.4 ms) on every fit and ~60 ms on the
   rescued ones. One answer (issue 22): R-IOU-M here is taken against the hull of each whole
   outline (:func:`sqfit.views.grid.with_outline_samples`; :data:`DECISION_MARGIN` says when the
   samples' hull suffices) and 3D-3A run on a regular grid of samples inside the outline
   (:func:`sqfit.views.grid.with_grid_samples`), so the rescue does not depend on the sampling seed
   either (it used the random samples until issue 22).

Why this and not the alternatives (paper scene ``sqfit.testing.paper_trial`` seeds 0-29, elliptic
cylinders and boxes from ``scenes/cylinders.toml`` / ``scenes/boxes.toml``, 30 trials each; median
3D IoU; CPU time per object, one process, 3H with a Python loop over candidates while it was
being designed; README "Beyond the paper" has the final figures):

=====================================  ======  =========  =====  =======
variant                                paper   cylinders  boxes  time
=====================================  ======  =========  =====  =======
1-2-3G (no search)                     0.897   0.757      0.927  20 ms
1-2-3G-3S (late symmetric restart)     0.934   0.869      0.927  28 ms
6 candidates, 4 screening steps        0.970   0.807      0.925  40 ms
6 candidates, 10 steps                 0.998   0.971      0.962  60 ms
3 candidates (no 45 deg), 10 steps     0.997   0.971      0.962  41 ms
=====================================  ======  =========  =====  =======

(the last three rows with 3G's shape bound lowered to 0.05; at 0.03, the default then,
``constants.SILHOUETTE_SHAPE_BOUNDS``, boxes reach 0.974; with 3G at 0.015, the default now, and
the screen at :data:`SCREEN_SHAPE_MIN` = 0.03, the default chain gives 0.981 / 0.982 / 0.983 on
seeds 0 / 1 / 2). The default as shipped (batched screen,
12 steps, one refining run; README "Beyond the paper", ``scripts/truth_bound.py``, seeds 0 and 1):
paper scene 0.993 / 0.995 (100 trials each, 10th percentile 0.842 / 0.841), cylinders 0.978 /
0.979, boxes 0.970 / 0.971, 36-45 ms CPU per object on a loaded machine. Ranking candidates without or after
only a few steps picks the wrong one: the right start often scores worst until ``e`` has moved
(cylinders need ~10 steps to let ``e1`` drop on the true axis). Starting candidates at other
exponents (``e = (0.3, 1)``, ``(0.3, 0.3)``) instead of the input's did not help at 10 steps. The
45-degree turns matter on the paper's random shapes (10th percentile of IoU 0.949 with them,
0.867 without). A late restart (``3S``) only acts on fits whose misfit crosses a threshold and
then costs a whole second 3G; deciding first costs a fixed, small batch.

Cheaper refinement (paper, 30 trials, same screen): skipping 3G's plain first run kept the
median IoU at 0.998 (10th percentile 0.943 against 0.949) and saved ~7 ms; a relative tolerance
of 1e-3 instead of 1e-6 for that run changed no median and saved ~5 ms. Fewer rays did not save
time (the ray solve is bound by per-call overhead, not by the number of rays): 48 or 32 refinement
rays per view instead of 64 took as long; 10 screening rays per view instead of 16 lowered the
10th percentile to 0.761. The screen's ray minimisers stop at 1e-6 relative instead of 3G's 1e-10
(same fits, ~3 ms less); 1e-4 saved another ~2.5 ms but lowered the 10th percentile of IoU
(paper scene, 100 trials) from 0.842 to 0.826 (seed 0) and from 0.841 to 0.777 (seed 1). Cutting
the screen to 10 steps lowered it from 0.912 to 0.833 (30 trials). The screen's ray minimisers take
at most :data:`SCREEN_MAX_NEWTON` (10) Newton / bisection steps on rays whose warm bracket failed,
instead of 3G's 30: the few slow rays (bisecting at the near-kinks of box-like candidates) held
every step's vectorised loop for up to 30 passes. Truth-bound runs (``scripts/truth_bound.py``, 100
paper trials, seeds 0 and 1; paper-noisy 100, cylinders and boxes 30, seeds 0 and 1) gave the same
medians within 0.003 and the same or higher 10th percentiles and means; a cap of 8 lowered the
mean on paper seed 1 (0.949 against 0.954), 6 lowered it on seed 0. The screen's Jacobians of all
candidates are one vectorised call per step (:func:`sqfit.fitting.raycost.batch_log_gauge_jacobian`; a loop over the six
candidates cost ~6 ms of ~33).

Deterministic; no random numbers. The input state's cost is not used.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import constants as C
from .._checks import check_shape
from .restarts import N_SCREEN_CONTOUR, screen_rays, symmetric_candidates
from ..kernels.backend import compiled
from .line_gauge import solver_args
from .raycost import CROSSING_ARGS, RAY_BOUNDS, batch_ray_residuals, ray_bounds, ray_kind
from .grazing import (POSE_NOISE_TRIGGER_DEG, SilhouetteFit, describe_values, offset_groups,
                      outline_rays, shifted_rays, silhouette_fit)
from .costs import ObservationSet
from .outline import TRIGGER_COST
from .plain_run import at_size_floor, offset_from_plain, plain_fit
from .stages import NUMERICAL_ERRORS, STAGES, FitState, StageError, ellipsoid_depths, r_iou_m, register, to_superquadric
from ..views.grid import with_grid_samples, with_outline_samples

__all__ = ["N_SCREEN_CONTOUR", "SCREEN_SHAPE_MIN", "SCREEN_BOUNDS", "SCREEN_ITERATIONS", "SCREEN_MAX_NEWTON", "CANDIDATES", "RESCUE_R_IOU_M",
           "DECISION_MARGIN", "RESCUE_STAGES", "RESCREEN_PX", "IDLE_OFFSET_PX",
           "PLAIN_BASIN_COST_RATIO", "PLAIN_BASIN_OFFSET_MAX_PX", "FLOOR_NOISE_COST_RATIO",
           "axis_candidates", "batch_levenberg_marquardt", "axis_search_stage"]

#: Names of the rows of :func:`axis_candidates`, in order.
CANDIDATES = ("input", "R45", "P1", "P1R45", "P2", "P2R45")
#: Levenberg-Marquardt steps (trial points) per candidate in the screen.
SCREEN_ITERATIONS = 12
#: Relative cost-reduction tolerance of the final 3G run (3G alone: ``FitOptions.ftol_analytic``).
REFINE_FTOL = 1e-3
#: After this many screening steps, candidates whose cost is above ``PRUNE_RATIO`` times the
#: lowest stop (None: never). Measured and left off: pruning after 5 steps at ratio 4 saved ~3 ms
#: of ~29 but lowered the 10th percentile of IoU from 0.943 to 0.870 (paper, 30 trials) and from
#: 0.969 to 0.807 (cylinders): the right candidate is often still behind half-way.
PRUNE_AFTER = None
PRUNE_RATIO = 4.0
#: Relative tolerance of the screen's ray minimisers (3G: 1e-10; see :func:`sqfit.fitting.line_gauge.batch_ray_minima`).
SCREEN_RTOL = 1e-6
#: Newton / bisection steps at most of the screen's ray minimisers for rays whose warm bracket did not
#: hold (3G: 30; warm rays: 6 in both). The tail of slow rays (near-kinks of box-like candidates,
#: bisecting) set the time of every step: 10 instead of 30 cut the default chain from ~31.5 to
#: ~28 ms per object with the same accuracy (module docstring).
SCREEN_MAX_NEWTON = 10
#: Lower bound of the shape exponents in the screen's penalty rows: 0.03, where 3G's bound was
#: before it went to 0.015 (``constants.SILHOUETTE_SHAPE_BOUNDS``). The screen ranks six axis
#: candidates after a few steps; with 0.015 there too, on ``scenes/paper-noisy.toml`` (100 trials,
#: seeds 0 / 1) the 10th percentile of 3D IoU fell 0.368 / 0.372 -> 0.355 / 0.353 (with the screen
#: at 0.03: unchanged), while boxes gained only 0.0016 more (seed 0, 30 trials: 0.9809 with the
#: screen at 0.03, 0.9825 at 0.015).
SCREEN_SHAPE_MIN = 0.03
#: The screen's penalty bounds: :data:`sqfit.fitting.raycost.RAY_BOUNDS` with :data:`SCREEN_SHAPE_MIN`.
SCREEN_BOUNDS = (np.r_[RAY_BOUNDS[0][:3], [SCREEN_SHAPE_MIN] * 2, RAY_BOUNDS[0][5:]], RAY_BOUNDS[1])
#: A 3H result whose R-IOU-M (the fitter's own, visible part of the masks) is below this is re-fitted
#: through :data:`RESCUE_STAGES` and the screen, and the better of the two by R-IOU-M is kept.
#: Good fits score 0.75-0.95 on clean and noisy masks; the 3G minima this catches score below 0.3.
RESCUE_R_IOU_M = C.POOR_FIT_R_IOU_M
#: The rescue decides on R-IOU-M against the hull of each whole outline, not of the random samples,
#: so that it does not depend on the sampling seed (:mod:`sqfit.views.grid`). That hull costs ~1 ms
#: (qhull on ~600 outline points), so a fit whose R-IOU-M against the samples' hull (computed anyway,
#: and reused by :func:`sqfit.fit`) clears the threshold by this margin is accepted without it: the
#: samples' hull lies inside the outline's, and on the paper and 1 px bias scenes (100 trials, seeds 0
#: and 1) the two scores of a 3H fit differ by far less (scripts/seed_stability.py finds no seed
#: dependence).
DECISION_MARGIN = 0.15
#: Stages of the rescue, from 3H's input (G5 on the samples, then R-IOU: neither has 3G's "far, huge"
#: minimum).
RESCUE_STAGES = ("3D", "3A")
#: With outline offsets estimated (``FitOptions.outline_offset_sigma_px > 0``), a fit whose offset
#: exceeds this (px, in absolute value) is screened and refined once more on outline rays offset by
#: the estimate, and the fit with the lower cost is kept (module docstring). On clean masks the
#: estimates stay within +-0.1 px on most objects, so it rarely costs a second screen there. The
#: screen matters: on 1 px bias the refinement alone reached a median IoU of 0.971, the default
#: with every ray moved by the true offset 0.993 (100 paper trials, seed 0). Tried and not kept: the
#: offset as a 12th unknown of the screen. On 16 rays per view, from the ellipsoid starts, it also
#: drifted on clean masks (0.8 px on a trial whose three views are equally far): 100 paper trials,
#: median / 10th percentile of IoU, seeds 0; 1, outlines smoothed over 1 px: clean 0.993 / 0.907;
#: 0.994 / 0.889 (prior 2 px) against 0.993 / 0.901; 0.994 / 0.924 with the second screen (prior
#: 1 px); 1 px bias 0.989; 0.991 against 0.990; 0.990.
RESCREEN_PX = 0.3
#: The refinement's outline offset counts as idle within this (px, in absolute value; with the cameras
#: agreeing, step 3 of the module docstring): the fit is then taken from plain 3G started at the
#: refinement's. :data:`RESCREEN_PX`, the level below which the offset does not move the screen.
IDLE_OFFSET_PX = RESCREEN_PX
#: An offset beyond :data:`IDLE_OFFSET_PX` still counts as idle where the plain fit costs at most this
#: many times the refinement and keeps the offset idle when it is freed again
#: (:func:`_without_idle_nuisances`): the refinement's basin, not the masks, holds it. Books (seed 4):
#: 1.03-1.14 with the offset back at 0.001 px; masks eroded or grown by a pixel (``paper-erode1``,
#: ``paper-bias1``) where the offset also stayed idle from the plain fit: 1.24, 1.58, 1.98 (the last
#: one's plain fit 0.89 -> 0.49 of 3D IoU). Docs: docs/real-objects.md, "An offset the plain fit does
#: not keep".
PLAIN_BASIN_COST_RATIO = 1.2
#: That test is run only up to this offset (px, in absolute value): it costs a plain run per fit, and on
#: masks biased by a pixel most offsets lie beyond this. In the runs that set :data:`PLAIN_BASIN_COST_RATIO`,
#: of the 339 fits beyond it one kept an idle offset from the plain fit, at 19 times the refinement's cost,
#: and no fit changed with the bound. Without it the test cost 4-7 ms more per object there (median,
#: ``benchmarks/bench_hull.py --chain default``, 40 objects of ``paper-bias1`` and ``paper-erode1``); with it
#: the medians stay within the runs' spread (docs/real-objects.md). An inward offset on a fit at the size floor
#: is tested whatever its size: it thins the outline of a superquadric the floor holds too thick
#: (:func:`sqfit.fitting.plain_run.at_size_floor`; books of seed 14, docs/real-objects.md, "An inward offset at
#: the size floor").
PLAIN_BASIN_OFFSET_MAX_PX = 2 * IDLE_OFFSET_PX
#: Where the refinement sits at the size floor and its pose corrections say the cameras disagree, the plain
#: fit (no corrections, no offset, the floor lowered where :mod:`sqfit.fitting.plain_run` lowers it) is taken
#: where it costs at most this many times the refinement, whose cost counts the nuisances' priors: a point
#: of the refinement's own objective (its nuisances at zero) no worse than where it ended, so the
#: disagreement was the floor's, not the cameras'. Off the floor such a fit is kept: the test would cost a plain
#: run on every fit under pose noise. A book of seed 14 (0.433 -> 0.954 of 3D IoU) and a table of each of seeds
#: 0, 2 and 4 better (+0.14 to +0.26), one more table of seed 0 -0.003; no other fit of the runs in
#: docs/real-objects.md, "Pose noise at the size floor", changed.
FLOOR_NOISE_COST_RATIO = 1.0
#: Initial damping of the screen, times the largest diagonal entry of ``J^T J`` (as :mod:`sqfit.fitting.lm`).
_LAMBDA0 = 1e-3
_LAMBDA_MAX = 1e16


def axis_candidates(xi):
    """The input and its 5 symmetric re-parametrisations, as starts of the screen.

    ``xi`` (11,) float gives ``(6, 11) float``: ``xi`` itself (``|a|``, ``e`` clipped to
    ``constants.SHAPE_DOMAIN``), then the rows of :func:`sqfit.fitting.restarts.symmetric_candidates`
    (``R45``, ``P1``, ``P1R45``, ``P2``, ``P2R45``).
    """
    xi = to_superquadric(check_shape(xi, (C.N_PARAMS,), "xi")).to_vector()
    return np.vstack([xi, symmetric_candidates(xi)])


def batch_levenberg_marquardt(X0, rays, iterations, weight=C.PENALTY_ANALYTIC, prune_after=None,
                              prune_ratio=np.inf, bounds=SCREEN_BOUNDS):
    """A fixed number of Levenberg-Marquardt steps on the 3G cost for ``b`` starts at once.

    The same damping and acceptance as :func:`sqfit.fitting.lm.levenberg_marquardt` (identity scaling,
    Nielsen's update), run independently per start, with one
    :func:`sqfit.fitting.raycost.batch_ray_residuals` call per step for all active starts. A start whose
    trial is not finite or does not decrease its cost keeps its point and raises its damping.

    Parameters
    ----------
    X0 : (b, 11) float
    rays : RaySet
    iterations : int
        Trial points per start, >= 0.
    weight : float
    prune_after, prune_ratio : int or None, float
        After ``prune_after`` steps, starts whose cost is above ``prune_ratio`` times the lowest
        stop (their point and cost are returned as they are).
    bounds : ((11,) float, (11,) float)
        Soft bounds of the penalty rows (default :data:`SCREEN_BOUNDS`).

    Returns
    -------
    X : (b, 11) float
        Best point of each start.
    cost : (b,) float
        ``0.5 * ||r||**2`` there (``inf`` where the start itself was not finite).
    """
    X = np.array(check_shape(X0, (None, C.N_PARAMS), "X0"), dtype=np.float64)
    if int(iterations) != iterations or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0, got {iterations}")
    kernels = compiled("screen")
    if kernels is not None:  # the same loop, compiled (sqfit.kernels.screen_kernels.screen_lm)
        with np.errstate(all="ignore"):
            return kernels.screen_lm(X, rays.origins, rays.directions, rays.weights, ray_kind(rays), int(iterations),
                                     *solver_args(SCREEN_RTOL, SCREEN_MAX_NEWTON), *CROSSING_ARGS, float(weight),
                                     *bounds,
                                     _LAMBDA0, _LAMBDA_MAX, -1 if prune_after is None else int(prune_after),
                                     float(prune_ratio))
    with np.errstate(all="ignore"):
        r, J, d = batch_ray_residuals(X, rays, weight, rtol=SCREEN_RTOL, max_newton=SCREEN_MAX_NEWTON,
                                      bounds=bounds)
        cost = 0.5 * np.einsum("bm,bm->b", r, r)
        ok = np.isfinite(cost) & np.isfinite(J).all(axis=(1, 2))
        cost = np.where(ok, cost, np.inf)
        H, g = _normal_equations(J, r)
        lam = _LAMBDA0 * np.maximum(np.einsum("bii->bi", H).max(axis=1), 1e-12)
        nu = np.full(len(X), 2.0)
        eye = np.eye(C.N_PARAMS)
        for it in range(int(iterations)):
            if it == prune_after:
                ok &= cost <= prune_ratio * cost.min()
            act = np.flatnonzero(ok & (lam < _LAMBDA_MAX))
            if not len(act):
                break
            try:
                dx = -np.linalg.solve(H[act] + lam[act, None, None] * eye, g[act][..., None])[..., 0]
            except np.linalg.LinAlgError:
                dx = np.full((len(act), C.N_PARAMS), np.nan)
            finite = np.isfinite(dx).all(axis=1)
            trial = np.where(finite[:, None], X[act] + dx, X[act])
            dx = np.where(finite[:, None], dx, 0.0)
            r_new, J_new, d_new = batch_ray_residuals(trial, rays, weight, d[act], rtol=SCREEN_RTOL,
                                                      max_newton=SCREEN_MAX_NEWTON, bounds=bounds)
            cost_new = 0.5 * np.einsum("bm,bm->b", r_new, r_new)
            Jdx = np.einsum("bmk,bk->bm", J[act], dx)
            predicted = -np.einsum("bk,bk->b", g[act], dx) - 0.5 * np.einsum("bm,bm->b", Jdx, Jdx)
            rho = np.where(predicted > 0, (cost[act] - cost_new) / predicted, -1.0)
            good = finite & np.isfinite(cost_new) & (rho > 0) & np.isfinite(J_new).all(axis=(1, 2))
            acc = act[good]
            X[acc], r[acc], J[acc], d[acc], cost[acc] = trial[good], r_new[good], J_new[good], d_new[good], cost_new[good]
            H[acc], g[acc] = _normal_equations(J[acc], r[acc])
            lam[act] = np.where(good, lam[act] * np.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3),
                                lam[act] * nu[act])
            nu[act] = np.where(good, 2.0, 2.0 * nu[act])
    return X, cost


def _normal_equations(J, r):
    return np.einsum("bmi,bmj->bij", J, J), np.einsum("bmi,bm->bi", J, r)


@register("3H")
def axis_search_stage(state, obs, options):
    """Stage 3H: screen the 6 axis choices of the input with a few batched 3G steps, then full 3G.

    A result whose silhouettes match the masks with an R-IOU-M below :data:`RESCUE_R_IOU_M` is
    fitted again from the input through 3D and 3A and the screen (see the module docstring); the
    one with the higher R-IOU-M is returned.
    """
    new = _screen_and_refine(state, obs, options)
    if _visible_r_iou_m(new, obs, options) >= RESCUE_R_IOU_M + DECISION_MARGIN:
        return new
    outline = ObservationSet([with_outline_samples(o) for o in obs.observations])
    score = _visible_r_iou_m(new, outline, options)
    if score >= RESCUE_R_IOU_M:
        return new
    path = "-".join(RESCUE_STAGES) + "-3H"
    try:
        grid = ObservationSet([with_grid_samples(o) for o in obs.observations])
        start, nfev = FitState(state.xi, sample_depths=ellipsoid_depths(state.xi, grid)), 0
        for name in RESCUE_STAGES:
            start = STAGES[name](start, grid, options)
            nfev += start.nfev
        other = _screen_and_refine(FitState(start.xi, sample_depths=ellipsoid_depths(start.xi, obs)), obs, options)
        other_score = _visible_r_iou_m(other, outline, options)
    except (StageError, *NUMERICAL_ERRORS) as exc:
        return replace(new, message=f"{new.message}; rescue ({path}) failed: {exc}")
    keep, lost = (other, new) if other_score > score else (new, other)
    note = (f"rescue: R-IOU-M {score:.3f} < {RESCUE_R_IOU_M}, re-fitted through {path} to {other_score:.3f}; "
            f"kept the {'rescue' if keep is other else 'first fit'}")
    return replace(keep, nfev=keep.nfev + lost.nfev + nfev, message=f"{note}; {keep.message}")


def _visible_r_iou_m(state, obs, options):
    return float(r_iou_m([to_superquadric(state.xi)], obs, options.polygon)[0])


def _screen_and_refine(state, obs, options):
    """Screen and refine (steps 1-3), and, with outline offsets estimated, again on rays shifted by
    the estimate when it exceeds :data:`RESCREEN_PX` (module docstring); the lower cost is kept."""
    new = _screen_refine_once(state, obs, options)
    offsets = new.outline_offsets
    if offsets is None or not np.abs(offsets).max() > RESCREEN_PX:
        return new
    other = _screen_refine_once(state, obs, options, offsets)
    keep, lost = (other, new) if other.cost < new.cost else (new, other)
    note = (f"re-screened on outlines offset by {describe_values(offsets)} px: cost {other.cost:.3e} against "
            f"{new.cost:.3e}, kept the {'re-screened' if keep is other else 'first'} fit")
    return replace(keep, nfev=keep.nfev + lost.nfev, message=f"{note}; {keep.message}")


def _without_idle_nuisances(fit, obs, options):
    """``fit`` (a :class:`sqfit.fitting.grazing.SilhouetteFit` of the refinement) or, where its
    nuisance unknowns are idle, plain 3G from it (module docstring, step 3): the cameras agree (pose
    noise at most :data:`sqfit.fitting.grazing.POSE_NOISE_TRIGGER_DEG`, the fixed prior), the
    outline offset is idle, and the superquadric grazes the outline (the refinement's cost at most
    :data:`sqfit.fitting.outline.TRIGGER_COST`, 3T's trigger): :func:`sqfit.fitting.plain_run.plain_fit`.
    The offset is idle within :data:`IDLE_OFFSET_PX`, or beyond it (up to :data:`PLAIN_BASIN_OFFSET_MAX_PX`, or
    inward on a fit at the size floor) where it belongs to the refinement's basin, not to the masks: the plain
    fit costs at most :data:`PLAIN_BASIN_COST_RATIO` times the refinement, and 3G started there with the
    offset free keeps it within :data:`IDLE_OFFSET_PX` (:func:`sqfit.fitting.plain_run.offset_from_plain`).
    On a fit at the size floor whose pose corrections say the cameras disagree, the plain fit is tested too, at
    :data:`FLOOR_NOISE_COST_RATIO` (and with the offset freed as above, where one is estimated); elsewhere such a
    fit is kept. The plain fit uses the given cameras (``camera_corrections`` None).
    The plain fit then has no offset (``outline_offsets`` None, so ``FitResult.outline_offset_px`` is None;
    its message ends with the refinement's, which names the offset it had)."""
    nuisances = options.pose_sigma_deg > 0 or options.outline_offset_sigma_px > 0
    if not (options.idle_nuisances_plain and nuisances):
        return fit
    if fit.state.cost is None or fit.state.cost > TRIGGER_COST:  # no superquadric grazes this outline
        return fit
    floor = at_size_floor(fit.state.xi, options)
    # a fit under the noise-scaled prior is one whose pose noise exceeded the trigger: tested at the floor only
    noisy = fit.pose_noise_deg is not None and fit.pose_noise_deg > POSE_NOISE_TRIGGER_DEG
    if noisy and not floor:
        return fit
    offsets = fit.state.outline_offsets
    idle = offsets is None or not np.abs(offsets).max() > IDLE_OFFSET_PX
    floored = not idle and offsets.max() < 0 and floor
    if not (noisy or idle or floored or np.abs(offsets).max() <= PLAIN_BASIN_OFFSET_MAX_PX):
        return fit
    rays = outline_rays(obs, options.n_contour)
    run = plain_fit(rays, fit.state.xi, options)
    if run is None:
        return fit
    res, nfev, how = run
    if noisy or not idle:
        why, more = _basin_not_masks(fit, rays, res, options, noisy)
        nfev += more
        if why is None:
            return _with_evaluations(fit, nfev)
        how += why
    state = replace(fit.state, xi=res.x, cost=res.cost, status=res.status, nfev=fit.state.nfev + nfev,
                    message=f"{res.message} ({how}: the refinement's nuisances were idle; it ended "
                            f"{fit.state.message})", outline_offsets=None, camera_corrections=None)
    return SilhouetteFit(state, None if noisy else fit.pose_noise_deg, None)


def _basin_not_masks(fit, rays, res, options, noisy):
    """Whether the plain fit ``res`` (an LM result from ``fit``'s refinement) shows the refinement's nuisances
    to be its basin's, not the masks' (:func:`_without_idle_nuisances`): its cost at most
    :data:`FLOOR_NOISE_COST_RATIO` (``noisy``: the cameras seemed to disagree) or :data:`PLAIN_BASIN_COST_RATIO`
    times the refinement's, and, with an offset estimated, the offset freed from it within :data:`IDLE_OFFSET_PX`.
    Returns ``(why, evaluations)``: ``why`` the message's words, None where the nuisances are the masks'."""
    ratio = res.cost / fit.state.cost if fit.state.cost > 0 else np.inf
    if not ratio <= (FLOOR_NOISE_COST_RATIO if noisy else PLAIN_BASIN_COST_RATIO):
        return None, 0
    freed, nfev = "", 0
    if options.outline_offset_sigma_px > 0:
        again, nfev = offset_from_plain(rays, res.x, options)
        if not np.abs(again).max() <= IDLE_OFFSET_PX:
            return None, nfev
        freed = f"from the plain fit {describe_values(again)} px, "
    if noisy:
        what = "pose noise and outline offset were" if fit.state.outline_offsets is not None else "pose noise was"
    else:
        what = "outline offset was"
    return f"; the refinement's {what} its basin's: {freed}cost {ratio:.3g} times", nfev


def _with_evaluations(fit, nfev):
    """``fit`` with ``nfev`` more evaluations counted (the plain runs of an idle test that kept it)."""
    return replace(fit, state=replace(fit.state, nfev=fit.state.nfev + nfev))


def _screen_refine_once(state, obs, options, shift=None):
    """One screen and refinement; ``shift`` (px per offset group): screen on outline rays offset by it
    and start the refinement's offsets there. Returns the state (with its estimated offsets, or None).

    When the refinement finds that the cameras disagree (its pose prior scaled to the residual
    noise, :func:`sqfit.fitting.grazing.silhouette_fit`), the screen, which ranks the candidates
    without pose corrections, is not trusted: every candidate is refined under that prior and the
    lowest cost is kept (module docstring)."""
    candidates = axis_candidates(state.xi)
    rays = screen_rays(obs)
    if shift is not None:
        rays = shifted_rays(rays, shift, offset_groups(rays, options))
    ends, costs = batch_levenberg_marquardt(candidates, rays, SCREEN_ITERATIONS, options.penalty_analytic,
                                            PRUNE_AFTER, PRUNE_RATIO, ray_bounds(options.size_min_m, SCREEN_BOUNDS))
    order = np.argsort(costs, kind="stable")
    refine = replace(options, ftol_analytic=max(options.ftol_analytic, REFINE_FTOL))
    fits = [_without_idle_nuisances(silhouette_fit(replace(state, xi=ends[order[0]]), obs, refine, name="3H",
                                                   plain_first=False, offsets=shift), obs, refine)]
    if fits[0].pose_scale is not None:
        fits += [silhouette_fit(replace(state, xi=ends[j]), obs, refine, name="3H", plain_first=False, offsets=shift,
                                pose_scale=fits[0].pose_scale) for j in order[1:]]
    pick = min(range(len(fits)), key=lambda j: fits[j].state.cost)
    best, new = int(order[pick]), fits[pick].state
    screened = ", ".join(f"{lab} {c:.2e}" for lab, c in zip(CANDIDATES, costs))
    refined = f"refined all under the pose prior: {CANDIDATES[best]} lowest; " if len(fits) > 1 else ""
    nfev = sum(f.state.nfev for f in fits)
    return replace(new, nfev=nfev + (SCREEN_ITERATIONS + 1) * len(candidates),
                   message=f"3H: start {CANDIDATES[best]} (screen costs: {screened}); {refined}{new.message}")
