"""Stages 3R and 3RH: where a stretch of the outline is no superquadric's silhouette, let it go and graze the rest.

A mug's handle is part of its masks' outline, and 3G/3H ask the superquadric to graze every
outline ray: the fit grows towards the handle, pinches (an exponent 1.2-1.7) or turns its axes
to follow the outline around it (issue "Real objects"). A point-cloud fit with an outlier model
(EMS, :mod:`sqfit.fitting.pointcloud`) simply lets such points go; ``3R`` is the silhouette
analogue with a hard Gaussian-uniform mixture. ``phi`` is a ray's unweighted 3G residual
(:mod:`sqfit.fitting.raycost`), ``s = 1.4826 median |phi|`` over all outline rays.

- Trimmed re-fit (:func:`trim_refit`): :data:`ROUNDS` times, the rays whose ray *misses* the
  superquadric by more than ``max(CUT s, PHI_MIN)`` (``phi > 0``: a part of the mask sticks out of
  it) are dropped (weight 0) and 3G's plain run (no pose corrections, no outline offset) re-fits
  the 11 parameters to the others. Rays that pass *through* the superquadric are never dropped:
  they say it is too large, which is what a handle does to the fit.
- Candidates: the trimmed re-fit from the input, and from a cylinder-like start (``e = (0.1, 1)``)
  about each of the input's three axes (2 ``ROUNDS``): a pinched or turned fit is a basin the
  trimmed re-fit alone does not leave.
- Choice (:func:`truncated_cost`): every fit, the input's included, is scored on *all* outline rays
  by ``sum w^2 min(phi^2, PHI_MIN^2)`` (a ray beyond ``PHI_MIN`` costs the same whatever the fit:
  the uniform part of the mixture); the best candidate replaces the input only when its score is
  below :data:`KEEP` times the input's (on 9 mugs of ``scenes/household.toml``, seed 0, the lowest
  score was the fit of highest 3D IoU in 8, and scores of a better fit were 0.27-0.49 of the
  input's, of a slightly worse one 0.91).
- Gate (:func:`stretches`, :attr:`Stretches.part`): the best candidate is kept only when what it
  leaves unexplained is a part that sticks out. A handle, a neck or a spout is a *stretch*: runs of
  consecutive outline rays of a view that all miss the fit, of one sign, and a part of the object is
  seen from several sides; 2 px mask jitter and 1 deg of pose noise (``scenes/paper-noisy.toml``)
  reach the same 3G costs, but their misfit has both signs (one side of a turned view misses, the
  other passes through) and, at their noise scale ``s``, few outliers. So the candidate needs at
  least :data:`STRETCH_RAYS` outliers in runs of at least :data:`RUN_RAYS` rays, in at least
  :data:`STRETCH_VIEWS` views, and at most :data:`CONTRARY_FRACTION` as many rays passing through
  it by more than ``PHI_MIN``; or no ray beyond ``PHI_MIN`` at all (a better optimum of the plain
  3G cost, nothing trimmed: two cylinders of ``scenes/cylinders.toml``). Measured on the fits 3R
  would keep without the gate (default's fits, 20 objects per kind, 100 noisy trials; seeds 0 / 1):
  mugs and bottles (64 fits, every one better) 10-52 outliers in stretches, in 2-4 views, and 0-5
  contrary rays but for four mugs: two with stretches in one view (+0.06, +0.09 3D IoU), one with
  9 in one view and 11 contrary rays (+0.03), one with none and 12 contrary rays (+0.14); those
  four the gate loses; paper-noisy (24 fits, 17 worse by
  more than 0.01, 6 better) 0 stretch rays on 20, 3 on three (9-30 contrary rays) and 13 on one
  (one view, 41 contrary rays); bowls (11 fits over seeds 0 and 1, 4 worse by 0.05-0.10) stretches
  in one view on all four worse ones. Not a likelihood test: the outline points are smoothed over
  :data:`sqfit.fitting.grazing.SMOOTH_PX` and a turned view's residuals are smooth, so neighbouring
  rays are not independent.

Starts from the visual hull (stage ``3RH``, in the chain ``tolerant``): where none of the re-fits from
the input's own starts is kept, the same candidates are re-fitted from the superquadric of the visual
hull (stage ``HULL``'s carving and EMS point-cloud fit, :func:`hull_starts`) and the cylinder-like
starts about its axes, and kept under the same score and gate. On mugs 3H's fit sometimes turns
towards the handle (pinched, ``e1`` 1.1-1.3, or square, ``e2`` ~ 0.03), and no start about that
fit's axes leaves the basin: 8 of 20 mugs of ``scenes/household.toml`` (seed 0); started at the
mesh's limit superquadric the trimmed re-fit reaches 0.79-0.89 3D IoU on all eight, started on
its axis but at the input's centre or size it does not. The hull's fit lies close enough for 6 of
the 8. ``sqsim experiment KIND.toml --trials 20 --chains default --seed S`` (one kind per scene),
3R against 3RH, seeds 0 / 1: mugs median 0.807 -> 0.834 / 0.864 -> 0.872 (6 and 3 fits changed,
each better by 0.13-0.32), bottles 2 fits better (+0.06, +0.10) / none changed, bowls none
changed, ``scenes/paper-noisy.toml`` (100 trials, seed 0) no fit changed. 3RH is not the default's
because the carving and EMS fit (0.3-0.6 s) run wherever 3R keeps nothing: on a quarter of the
noisy paper trials, whose mean time per object it multiplied by 4.5 (0.35 -> 1.59 s, a loaded
machine), and on bowls and plant pots (median 43 -> 347 and 46 -> 408 ms per object), for nothing.

Pinched inputs (in the default's 3R): where the input is pinched (a shape exponent at least
:data:`PINCHED`), 3R too starts from the visual hull where its own starts keep nothing. A fit that
turned towards a handle is pinched: of the fits of pybullet's ``objects/mug_col.obj`` (a mug with
its handle; README "Real objects", "The issue's own kind of meshes") that stay in that basin, 19
of 40 over seeds 0 and 1, the 13 that the hull start lifts (to 0.88-0.97 3D IoU) all had 3H
exponents of 1.14-1.76. 3H's fits of bowls and plant pots are seldom pinched (3-4 and 6-8 of 20,
seeds 0 and 4), so there the carving runs less often. Measured in the README, "Real objects",
"Pinched inputs": no fit changed on the guard scenes; where 3R carves more, the mean time per object
grows (``paper-noisy``, seed 0: 81 -> 174 ms, its median 34 -> 35 ms). A re-fit is kept only where its
silhouettes still overlap the masks (R-IOU-M at least :data:`MIN_OVERLAP`): from the hull's starts
one laptop's re-fit ran off to 3G's far, huge minimum, whose truncated cost is nearly 0.

On pose-corrected cameras: where the input comes with rotation corrections of the cameras
(:attr:`sqfit.fitting.stages.FitState.camera_corrections`: 3G or 3H found that the cameras disagree,
and its fit grazes the outline), the re-fits, plain 3G runs without pose unknowns, are also made on
the cameras turned by them (:meth:`sqfit.fitting.costs.ObservationSet.turned`); on the given cameras
they fit the views' disagreement as well as the shape. Of the fits each camera set keeps (the same
score and gate, each on its own rays) the one of lower truncated cost is kept, with the corrections
when it is the turned set's (3RH carves the visual hull for its starts on the given cameras only).
The given set stays a candidate because the corrections may have absorbed a wrong basin's misfit
instead: on clean masks of two cylinders (``scenes/cylinders.toml``, seed 0, trials 0 and 14) 3H's
fit (0.79, 0.76 3D IoU) "finds" 0.4-0.9 degrees of pose noise, and the re-fit from a cylinder start
reaches 0.993 on the given cameras, 0.84 and 0.79 on the turned ones. The turned set is tried
only where the corrections' RMS angle reaches :data:`TURN_MIN_DEG`: 3H's fit of a clean mug often
turns towards the handle and its corrections absorb that (12 of the 13 clean mugs of seed 0 that
hand them on: 0.14-0.76 degrees, the turned set never kept; the 13th, 1.38, kept), which cost 3R a
second run for nothing (clean mugs 72 -> 114-117 ms median per object; with the threshold 78 / 77
-> 76 / 75 ms, two rounds alternated with the code before the turned set);
with 1 degree of noise the turned set's fit was kept on mugs at 0.75-1.62 degrees only (seed 0).
Measured on household scenes with 1 degree of pose noise in docs/real-objects.md, "Pose
noise: 3R on the corrected cameras".

It acts only where the input's 3G cost lies between :data:`MIN_COST` (clean superquadric masks: at
most 2.7e-3 over 60 paper trials) and :data:`sqfit.fitting.outline.TRIGGER_COST` (above it, stage
3T's domain). In the default chain (:data:`sqfit.fitting.pipeline.DEFAULT_CHAIN`) since the gate;
measured in docs/real-objects.md, "Stage 3R". Deterministic; no random numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .grazing import minimise, outline_rays, pose_noise_estimate
from .hull import object_hull
from .outline import TRIGGER_COST
from .pointcloud import fit_points
from .raycost import ray_residuals
from .stages import NUMERICAL_ERRORS, StageError, r_iou_m, register, to_superquadric
from ..geometry.superquadric import euler_to_matrix, matrix_to_euler

__all__ = ["ROUNDS", "CUT", "PHI_MIN", "KEEP", "CYLINDER_SHAPE", "MIN_COST", "PINCHED", "MIN_OVERLAP", "RUN_RAYS",
           "STRETCH_RAYS", "STRETCH_VIEWS", "CONTRARY_FRACTION", "ray_phi", "outlier_rays", "outline_runs", "Stretches",
           "stretches", "trim_refit", "truncated_cost", "cylinder_starts", "hull_starts", "HULL_MIN_POINTS",
           "trimmed_stage", "trimmed_hull_stage"]

#: Trim-and-refit rounds.
ROUNDS = 3
#: A ray is an outlier when its residual exceeds this many robust standard deviations ...
CUT = 3.0
#: ... and this absolute value (a relative scale error of ~10 %); also the truncation of the score.
PHI_MIN = 0.1
#: The best candidate replaces the input when its truncated cost is below this fraction of the input's.
KEEP = 0.8
#: Fewest surface points of the visual hull that give 3RH's hull start (one per parameter).
HULL_MIN_POINTS = 11
#: 3R starts from the visual hull too (as 3RH always does, where its own starts keep nothing) where the
#: input is pinched: a shape exponent at least this (module docstring, "Pinched inputs").
PINCHED = 1.1
#: A re-fit is kept only where its silhouettes still overlap the masks: R-IOU-M at least this. The
#: truncated cost bounds each ray's share, so a re-fit run off to 3G's far, huge minimum (a laptop of
#: seed 4 from the visual hull's start: half-axes of 200-1850 m, R-IOU-M 0.002) can score low.
MIN_OVERLAP = 0.5
#: Shape ``(e1, e2)`` of the cylinder-like starts.
CYLINDER_SHAPE = (0.1, 1.0)
#: 3R acts only when the input's 3G cost (``FitState.cost``) is above this.
MIN_COST = 3e-3
#: Re-fits on the cameras turned by the input's pose corrections only where their RMS angle
#: (:func:`sqfit.fitting.grazing.pose_noise_estimate`) is at least this, degrees.
TURN_MIN_DEG = 0.6
#: A stretch is a run of at least this many consecutive outline rays of one view (64 per view) ...
RUN_RAYS = 3
#: ... and a trimmed fit is kept only when at least this many of the rays it drops lie in stretches ...
STRETCH_RAYS = 8
#: ... of at least this many views (a part of the object is seen from more than one side) ...
STRETCH_VIEWS = 2
#: ... and the rays that pass through it by more than ``PHI_MIN`` number at most this fraction of those.
CONTRARY_FRACTION = 0.5


def ray_phi(xi, rays, penalty):
    """``(n,)`` unweighted 3G residual ``phi`` of each ray of ``rays`` at ``xi`` ``(11,)`` (0 where a ray's
    weight is 0)."""
    r = ray_residuals(np.asarray(xi, dtype=np.float64), rays, penalty)[0][:len(rays)]
    w = rays.weights
    return np.where(w > 0, r / np.where(w > 0, w, 1.0), 0.0)


def outlier_rays(xi, rays, penalty):
    """``(mask, s)``: the rays of ``rays`` whose ray misses the superquadric ``xi`` ``(11,)`` by more
    than ``max(CUT s, PHI_MIN)`` (``phi > 0``), and the robust scale ``s`` of all rays' ``phi``."""
    return _outliers(ray_phi(xi, rays, penalty))


def _outliers(phi):
    """:func:`outlier_rays` of the residuals ``phi``."""
    s = 1.4826 * float(np.median(np.abs(phi)))
    return phi > max(CUT * s, PHI_MIN), s


def outline_runs(mask, view):
    """Length of the run of consecutive ``True`` of ``mask`` that each ray lies in, along its view's outline.

    Parameters
    ----------
    mask : (n,) bool
        One flag per ray.
    view : (n,) int
        Each ray's view; a view's rays are in outline order (:func:`sqfit.views.rays.contour_rays`),
        and the outline is closed, so a run may wrap from a view's last ray to its first.

    Returns
    -------
    runs : (n,) int64
        0 where ``mask`` is False.

    >>> outline_runs([True, False, True, True, False, True], [0, 0, 0, 0, 0, 0]).tolist()
    [2, 0, 2, 2, 0, 2]
    >>> outline_runs([True, True, True, False], [0, 0, 1, 1]).tolist()
    [2, 2, 1, 0]
    """
    mask = np.asarray(mask, dtype=bool)
    view = np.asarray(view)
    if mask.ndim != 1 or view.shape != mask.shape:
        raise ValueError(f"mask and view must be (n,) arrays of one length, got {mask.shape} and {view.shape}")
    runs = np.zeros(len(mask), dtype=np.int64)
    for v in np.unique(view):
        idx = np.flatnonzero(view == v)
        m = mask[idx]
        if m.all():
            runs[idx] = len(m)
            continue
        k = int(np.argmin(m))  # a False ray: rolled to the front, no run wraps past it
        m = np.roll(m, -k)
        run = np.cumsum(m & ~np.concatenate([[False], m[:-1]]))  # each ray's run number (0 before the first)
        lengths = np.where(m, np.bincount(run[m], minlength=run[-1] + 1)[run], 0)
        runs[idx] = np.roll(lengths, k)
    return runs


@dataclass(frozen=True)
class Stretches:
    """What a fit's outline residuals ``phi`` say about the rays 3R drops (:func:`stretches`).

    Attributes
    ----------
    stretch : int
        Outliers (:func:`outlier_rays`: ``phi > max(CUT s, PHI_MIN)``) in runs of at least
        :data:`RUN_RAYS` consecutive rays of a view's outline.
    views : int
        Views with at least one such run.
    contrary : int
        Rays that pass through the fit by more than ``PHI_MIN`` (``phi < -PHI_MIN``).
    beyond : int
        Rays with ``|phi| > PHI_MIN`` (those the truncated cost truncates).
    """

    stretch: int
    views: int
    contrary: int
    beyond: int

    @property
    def part(self):
        """True when the misfit is a part of the mask that sticks out (a handle, a neck) or there is none:
        no ray beyond ``PHI_MIN``, or at least :data:`STRETCH_RAYS` stretch rays in at least
        :data:`STRETCH_VIEWS` views and at most :data:`CONTRARY_FRACTION` as many contrary rays."""
        return self.beyond == 0 or (self.stretch >= STRETCH_RAYS and self.views >= STRETCH_VIEWS
                                    and self.contrary <= CONTRARY_FRACTION * self.stretch)


def stretches(xi, rays, penalty):
    """The :class:`Stretches` of the outline rays ``rays`` at ``xi`` ``(11,)``."""
    phi = ray_phi(xi, rays, penalty)
    out, _ = _outliers(phi)
    stretch = outline_runs(out, rays.view) >= RUN_RAYS
    return Stretches(int(np.count_nonzero(stretch)), len(np.unique(rays.view[stretch])),
                     int(np.count_nonzero(phi < -PHI_MIN)), int(np.count_nonzero(np.abs(phi) > PHI_MIN)))


def truncated_cost(xi, rays, penalty):
    """``sum w^2 min(phi^2, PHI_MIN^2)`` over ``rays`` at ``xi`` (module docstring)."""
    phi = ray_phi(xi, rays, penalty)
    return float(np.sum(rays.weights ** 2 * np.minimum(phi ** 2, PHI_MIN ** 2)))


def trim_refit(xi, rays, options, rounds=ROUNDS):
    """``(xi, nfev)``: ``rounds`` of dropping :func:`outlier_rays` and re-fitting 3G's plain run to the rest."""
    xi = np.array(xi, dtype=np.float64)
    nfev = 0
    for _ in range(rounds):
        out, _ = outlier_rays(xi, rays, options.penalty_analytic)
        kept = replace(rays, weights=np.where(out, 0.0, rays.weights))
        res = minimise(kept, xi, options, 0.0)
        nfev += res.nfev
        if not np.all(np.isfinite(res.x)) or np.max(np.abs(res.x[:3])) > 1e4:
            raise StageError("diverged", "stage 3R: the optimiser diverged")
        xi = res.x
    return xi, nfev


def cylinder_starts(xi):
    """Three ``(11,)`` starts at ``xi``'s centre, shape :data:`CYLINDER_SHAPE`, axis along each of
    ``xi``'s axes in turn (length that axis's size, radius the geometric mean of the other two)."""
    xi = np.asarray(xi, dtype=np.float64)
    R = euler_to_matrix(xi[8:11])
    starts = []
    for axis in range(3):
        perm = [(axis + 1) % 3, (axis + 2) % 3, axis]
        Rp = R[:, perm]
        if np.linalg.det(Rp) < 0:
            Rp[:, 0] *= -1.0
        radius = float(np.sqrt(xi[perm[0]] * xi[perm[1]]))
        starts.append(np.concatenate([[radius, radius, xi[perm[2]]], CYLINDER_SHAPE, xi[5:8],
                                      matrix_to_euler(Rp)]))
    return starts


def _best_refit(starts, rays, options, pen):
    """``(xi, cost, name, nfev)``: the trimmed re-fit (:func:`trim_refit`) of lowest truncated cost over
    ``starts`` (``(name, xi, rounds)`` each); ``xi`` None when every re-fit failed."""
    best, best_cost, best_name, nfev = None, np.inf, "", 0
    for name, start, rounds in starts:
        try:
            xi, n = trim_refit(start, rays, options, rounds)
        except (StageError, *NUMERICAL_ERRORS):
            continue
        nfev += n
        cost = truncated_cost(xi, rays, pen)
        if cost < best_cost:
            best, best_cost, best_name = xi, cost, name
    return best, best_cost, best_name, nfev


def _own_starts(xi):
    """The input and the cylinder-like starts about its axes, as ``(name, xi, rounds)``."""
    return [("input", xi, ROUNDS)] + [(f"cylinder about axis {k}", c, 2 * ROUNDS) for k, c in enumerate(cylinder_starts(xi))]


def hull_starts(obs):
    """The visual hull's superquadric (stage ``HULL``'s carving and EMS fit, :mod:`sqfit.fitting.hull`) and
    the cylinder-like starts about its axes, as ``(name, xi, rounds)``; empty when the carving keeps
    too few surface points or the point-cloud fit fails."""
    try:
        points = object_hull(obs).surface_points()
        if len(points) < HULL_MIN_POINTS:
            return []
        xi = fit_points(points).xi
    except (StageError, *NUMERICAL_ERRORS):
        return []
    return [("visual hull's fit", xi, 2 * ROUNDS)] + [(f"cylinder about the hull fit's axis {k}", c, 2 * ROUNDS)
                                                    for k, c in enumerate(cylinder_starts(xi))]


def _trimmed(state, obs, options, code, hull):
    """Stages 3R and 3RH (``hull``: the visual hull's starts where the input's own give no fit to keep)."""
    if state.cost is None or not MIN_COST < state.cost <= TRIGGER_COST:
        cost = "no 3G cost" if state.cost is None else f"3G cost {state.cost:.2e} outside ({MIN_COST:g}, {TRIGGER_COST:g}]"
        return replace(state, message=f"{code}: {cost}: kept the input")
    xi0 = np.array(state.xi, dtype=np.float64)
    hull = hull or max(xi0[3], xi0[4]) >= PINCHED
    cameras, w = [("", obs, None)], state.camera_corrections
    if w is not None and pose_noise_estimate(w) >= TURN_MIN_DEG:
        cameras.append((" on the pose-corrected cameras", obs.turned(w), w))
    nfev, tried = 0, []
    for where, seen, corrections in cameras:
        best, n, note = _kept_refit(xi0, seen, options, hull and corrections is None)
        nfev += n
        tried.append((best, note + where, corrections))
    kept = [t for t in tried if t[0] is not None]
    if not kept:
        return replace(state, nfev=state.nfev + nfev,
                       message=f"{code}: {'; '.join(note for _, note, _ in tried)}: kept the input")
    (xi, _), note, corrections = min(kept, key=lambda t: t[0][1])
    others = "".join(f"; not {other}" for _, other, _ in tried if other != note)
    return replace(state, xi=xi, nfev=state.nfev + nfev, outline_offsets=None, camera_corrections=corrections,
                   message=f"{code}: {note}: kept it{others}")


def _kept_refit(xi0, obs, options, hull):
    """3R's trimmed re-fits from ``xi0`` on the outline rays of ``obs`` (its own starts, then the visual
    hull's where ``hull`` and none of those is kept): ``(kept, nfev, note)``, ``kept`` the first
    re-fit that passes :data:`KEEP` and the gate as ``(xi, truncated cost)``, or None."""
    rays = outline_rays(obs, options.n_contour)
    pen = options.penalty_analytic
    before = truncated_cost(xi0, rays, pen)
    nfev, found = 0, []
    for starts in (lambda: _own_starts(xi0), lambda: hull_starts(obs) if hull else []):
        best, best_cost, best_name, n = _best_refit(starts(), rays, options, pen)
        nfev += n
        if best is None:
            continue
        what = f"the best candidate {best_cost:.3g} from the {best_name}"
        if best_cost < KEEP * before:
            ev = stretches(best, rays, pen)
            detail = (f"{ev.stretch} of {len(rays)} rays outliers in stretches of {ev.views} views, {ev.contrary} "
                      f"passing through by > {PHI_MIN:g}, {ev.beyond} beyond it")
            if not ev.part:
                what += f" ({detail}: no part sticks out)"
            else:
                overlap = r_iou_m([to_superquadric(best)], obs)[0]
                if overlap >= MIN_OVERLAP:
                    note = (f"truncated cost {before:.3g} -> {best_cost:.3g} (trimmed re-fit from the {best_name}, "
                            f"{detail})")
                    return (best, best_cost), nfev, note
                what += f" ({detail}; its silhouettes leave the masks, R-IOU-M {overlap:.3f})"
        found.append(what)
    return None, nfev, f"truncated cost {before:.3g}, " + ("; ".join(found) or "no candidate")


@register("3R")
def trimmed_stage(state, obs, options):
    """Stage 3R: re-fit 3G without the outline rays no superquadric grazes, from the visual hull's fit too
    where the input is pinched (module docstring)."""
    return _trimmed(state, obs, options, "3R", hull=False)


@register("3RH")
def trimmed_hull_stage(state, obs, options):
    """Stage 3RH: stage 3R, then, where no re-fit from the input's starts is kept, the same from the visual
    hull's superquadric (module docstring, "Starts from the visual hull")."""
    return _trimmed(state, obs, options, "3RH", hull=True)
