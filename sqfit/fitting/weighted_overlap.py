"""Stage 3W (the default's last stage): where no superquadric matches the masks, a silhouette pixel
outside the mask costs twice a mask pixel the silhouette misses.

Where the masks are of a superquadric, the fit's silhouettes match them and how a mismatch is
weighed does not matter. Where they are not (a soft toy's arms and ears, a plant's leaves over its
pot, a lamp's stand), the earlier stages take the whole outline as silhouette and the fit grows to
reach it: on household toys and plant pots of seed 0 the default's fits held 1.25 and 1.17 times
the object's volume (median of 20), their best superquadrics (the representation limit) 1.01 and
1.02, with 3D precision 0.69 and 0.81 against the limit's 0.81 and 0.90. Yet the default's
silhouettes matched the masks better than the limit's (mean IoU 0.78 against 0.75 on toys, 0.91
against 0.87 on plant pots, all 20 fits of each): an outline-matching cost cannot tell them apart.
The two errors differ in 3D. Silhouette outside the mask is superquadric volume along a ray that
misses the object: all of it wrong. Mask outside the silhouette is object volume the superquadric
misses, and where no superquadric can follow the outline it is a thin part (an arm, a leaf, a pole),
little volume behind much outline.

So ``3W`` maximises the mean over the views of ``I / (I + w (S - I) + (M - I))``, with ``I`` the
silhouette's overlap with the mask contour, ``S`` and ``M`` their areas and ``w`` =
:data:`EXCESS_WEIGHT` (the IoU at ``w = 1``), by least squares with forward differences evaluated
in one batch, from four starts: the input's fit and the cylinder-like starts about its three axes
(:func:`sqfit.fitting.trimmed.cylinder_starts`, as 3R's). Each runs :data:`SCREEN_EVALUATIONS`
evaluations, the best goes on to :data:`EVALUATIONS` in all. A mug's fit that the handle rounded
(``e1`` 0.45-1.1, 1.3-1.6 times the mug's volume) is a basin the input's start does not leave; from
the cylinder about the right axis the weighted overlap is higher and so is the 3D IoU (mugs of seed
4: 7 of 20 fits better, none worse; docs/real-objects.md, "3W from four starts"). It acts only where
the input does not graze the outline (its 3G cost above :data:`GRAZED_COST`) and its silhouettes
match the mask contours below :data:`MISFIT` in mean IoU (3T's measure,
:func:`sqfit.fitting.outline.contour_score`), and where the masks are exact outlines under the given
cameras, as far as the fit and the masks can tell:

- no view is cut by the image border or occluded;
- the outline offset 3G and 3H estimate, where there is one, is at most :data:`OFFSET_MAX` px (a
  segmenter that grows or shrinks the masks by a pixel: the weighted overlap would undo the offset
  the default fitted);
- the masks' epipolar tangents agree to :data:`CONSISTENT_PX`
  (:func:`sqfit.views.consistency.tangent_disagreement`): on clean masks at most 1.44 px on 100
  household objects and 2.38 px on 100 paper trials, under 1 deg of pose noise at least 2.83 px
  (100 paper trials), under 2 px of boundary jitter above 2 px on 45 of 50 (its docstring).
  That is the test of the cameras: it acts on the given cameras even where 3G or 3H handed on
  rotation corrections, which where no superquadric fits the outline are the fit's misfit, not the
  cameras' (on clean masks 3H corrected the cameras of 8 of 20 plant pots, 5 of 20 mugs and 11 of 20
  bowls of seed 4, which 3W then skipped; docs/real-objects.md, "3W on the given cameras where 3H
  corrected them").

Without gates (40 fits of ``scenes/paper-noisy.toml``, 20 of ``paper-erode1`` and ``paper-bias1``,
seed 0, ``w = 2``) it lost 0.10, 0.06 and 0.05 median 3D IoU there; with the gates above but the
tangents' (and one that kept it off fits whose cameras 3H corrected) it still moved 4-6 of 100
paper-noisy fits per seed both ways (by up to 0.16), which the tangents' gate leaves alone. Where it
acts, the four starts and acting on corrected cameras took the default's CPU time per object from
0.13-0.23 s to 0.23-0.41 s (medians of 10 mugs, toys and plant pots of seed 0, two rounds). Measurements:
docs/real-objects.md, "Stage 3W" and the two sections after it. Deterministic.

Parts apart. Where the masks' opening (3V's, :func:`~sqfit.fitting.least_volume.bulk_observations`) leaves parts
apart, the second holding at least :data:`SPLIT_SHARE` of the mask's area in :data:`SPLIT_VIEWS` views or more (a
lamp's pole opened away leaves its shade and its base: the base up to 0.48 of the mask on the lamps of seed 0), the
smaller part is a second piece of the object that one superquadric does not follow, and its outline, a miss in every
view, pulled the fit towards it. There the stage scores its fits on each view's main part (:func:`parts_apart`: the
largest part with its corners, which the opening rounds; on a monitor's screen the rounded corners cost the board
its size, the opened masks alone took a monitor of seed 0 from 0.852 to 0.818). It triggers on 19, 17 and 19 of the
20 lamps of seeds 0, 4 and 2, 3 and 2 monitors of seeds 0 and 2, one table of seeds 4 and 2, one bottle of seed 0
(its cap past the neck) and on no other household object of those seeds, nor on the paper scenes, boxes or cylinders
run with it (a convex mask does not fall apart; an occluded or cut view is not opened); of the 2,278 objects of the
fourteen noise sweeps, on 20 whose masks the noise cut or frayed, of which one object's fit changed (3D IoU 0.000
before and after). Lamps, median 3D IoU of 20 against the full masks' scores, seeds 0 / 4 / 2 / 6 / 8 (the last
three never used to set it): 0.640 / 0.618 / 0.616 / 0.641 / 0.631 -> 0.646 / 0.625 / 0.615 / 0.647 / 0.641, the
mean up by 0.007-0.024 on every seed, 38 fits better by more than 0.01 and 5 worse (by 0.010-0.026); a monitor 0.573
-> 0.597 and a table 0.078 -> 0.209, the other fits where it triggers within 0.01.
Measured: docs/real-objects.md, "Parts apart: a lamp's shade without its base".

Slabs. Where the fit is a slab (:func:`sqfit.geometry.slab.thin_section`: a table's top, a monitor's screen) its
thickness is the one the whole outline asked for, legs and stand included: of the 20 tables of seed 0 the default
fitted 18 as slabs, their width and depth within 4 % of the limit superquadric's on 17, their thickness 1.08-2.24
times the limit's (median 1.47). So the stage last tries the slab thinner (:func:`slab_thickness`): the thin
half-axis times each factor of :data:`THICKNESS_FACTORS`, scored by the same weighted overlap with the masks
opened (3V's :func:`~sqfit.fitting.least_volume.bulk_observations`, the legs gone), and keeps the best where it
scores higher than the fit as it is. Only where the slab leaves a part out of the outline (stage 3TP's test,
:func:`sqfit.fitting.parts.leaves_a_part`: outlier rays in stretches of two views or more, the legs that pulled
it; without it, true superquadric slabs under mask noise, fitted right, were thinned too: 8 fits of the fourteen
noise sweeps moved, 7 lower, by up to 0.10) and not where the opening leaves every view alone. Where the input
is a slab that 3V made square at equal volume (:func:`~sqfit.fitting.least_volume.squared_slab`) its thickness
is the volume's, and too thin rather than too thick (the board of a diamond's volume is about half as thick as
the diamond the masks showed; thinned further, 5 of 8 such fits lost in the probe that set the rule, by up to
0.17): there :func:`squared_thickness` makes it thicker, by the smaller of the factors of :data:`SQUARED_FACTORS`
whose silhouettes match the full and the opened mask contours best, where both ask for more than 1 (of the 26
such tables and monitors of seeds 0, 4, 2, 6 and 8, 9 monitors better by 0.02-0.08, one table 0.015 worse, the
others the same; the full contours' pick alone lost 4 of 8 tables, docs/real-objects.md, "Squared slabs'
thickness"). Measured with the default (``sqsim experiment scenes/household.toml --set "objects.catalogue=[KIND]"
--set experiment.limit=false --trials 20 --seed S --chains default``; seeds 2, 6 and 8 never used to set it),
median 3D IoU per seed 0 / 4 / 2 / 6 / 8: tables 0.550 / 0.558 / 0.518 / 0.587 / 0.580 -> 0.617 / 0.605 / 0.512 /
0.658 / 0.645 (mean +0.025 to +0.058), monitors 0.704 / 0.715 / 0.741 / 0.676 / 0.701 -> 0.710 / 0.715 / 0.750 /
0.687 / 0.706 (mean +0.006 to +0.023); the other ten kinds (seeds 0 and 4) keep their medians and all their fits
but two bowls' (-0.002 each). Of those 600 objects 113 changed by more than 0.01: 108 better (up to +0.21), 5
worse (tables, -0.019 to -0.079). 10-30 ms of CPU per object where it runs (docs/real-objects.md, "Tables: the
top's thickness").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares

from .contour_overlap import contour_overlaps
from .grazing import outline_rays
from .least_volume import bulk_observations, is_squared_slab
from .outline import OUTLINE_POLYGON, contour_score
from .parts import leaves_a_part
from .stages import NUMERICAL_ERRORS, FitState, StageError, r_iou_m, register, to_superquadric
from .trimmed import cylinder_starts, stretches
from ..constants import SHAPE_DOMAIN
from ..geometry.silhouette import batch_silhouettes
from ..geometry.slab import thin_section
from ..views.consistency import tangent_disagreement
from ..views.opening import main_part, split_share

__all__ = ["EXCESS_WEIGHT", "GRAZED_COST", "MISFIT", "OFFSET_MAX", "CONSISTENT_PX", "VERTICES", "EVALUATIONS",
           "SCREEN_EVALUATIONS", "STEP", "SPLIT_SHARE", "SPLIT_VIEWS", "THICKNESS_FACTORS",
           "SQUARED_FACTORS", "weighted_ious", "gate", "fit_weighted", "thickness_candidates", "slab_thickness",
           "squared_thickness", "parts_apart", "weighted_overlap_stage"]

#: ``w``: what a silhouette pixel outside the mask costs, in mask pixels the silhouette misses.
EXCESS_WEIGHT = 2.0
#: The stage acts where the input's 3G cost (``FitState.cost``) is above this (below it the fit grazes the
#: outline: 0-3e-4 on 20 paper trials; the fits it changed among 200 household objects of seed 0 had 3.5e-3 or
#: more): a test that costs nothing, before the next one's ~1.4 ms on a paper trial ...
GRAZED_COST = 1e-3
#: ... and where its silhouettes match the mask contours below this mean IoU.
MISFIT = 0.95
#: ... and its outline offset (stages 3G, 3H; px), where it has one, is at most this.
OFFSET_MAX = 0.25
#: ... and the masks' epipolar tangents agree to this (px, :func:`sqfit.views.consistency.tangent_disagreement`).
CONSISTENT_PX = 2.0
#: Silhouette vertices per view.
VERTICES = 48
#: Evaluations of the least squares, the best start's screen included (the Jacobian's batches not counted).
EVALUATIONS = 50
#: Evaluations of each start before the best goes on (the input and :func:`cylinder_starts`).
SCREEN_EVALUATIONS = 20
#: Forward-difference step, relative to ``max(|x|, 1)``.
STEP = 1e-3
#: :func:`parts_apart`: the share of a mask's area the second part its opening leaves must hold ...
SPLIT_SHARE = 0.05
#: ... in at least this many views.
SPLIT_VIEWS = 2
#: The factors :func:`slab_thickness` tries on a slab's thin half-axis (1 is the fit as it is).
THICKNESS_FACTORS = np.round(np.arange(0.5, 1.0001, 0.05), 2)
#: The factors :func:`squared_thickness` scores on a squared slab's thin half-axis.
SQUARED_FACTORS = np.round(np.arange(0.7, 1.6001, 0.05), 2)


def weighted_ious(X, obs, weight=None):
    """``(b, v)``: ``I / (I + weight (S - I) + (M - I))`` of each superquadric of ``X`` ``(b, 11)``
    in each view of ``obs`` (an ObservationSet no view of which is cut by the image border):
    ``I`` the silhouette's overlap with the mask contour, ``S`` its area, ``M`` the contour's; 0
    where the silhouette is not valid. ``weight``: :data:`EXCESS_WEIGHT` if None; 1 gives the
    silhouette's IoU."""
    weight = EXCESS_WEIGHT if weight is None else weight
    X = np.asarray(X, dtype=np.float64)
    polys, valid = batch_silhouettes(X, obs.rotations, obs.centers, obs.intrinsics, VERTICES)[:2]
    views = np.arange(len(obs))
    inter, area = contour_overlaps(polys, valid, obs, views, np.zeros(len(obs), dtype=bool))
    masks = obs.contour_arrays()[3][None]
    denominator = inter + weight * (area - inter) + (masks - inter)
    with np.errstate(divide="ignore", invalid="ignore"):
        score = inter / denominator
    return np.where(valid & (denominator > 0) & np.isfinite(score), score, 0.0)


def gate(state, obs):
    """Why stage 3W leaves ``state`` as it is, or None where it acts (module docstring)."""
    if (obs.border_views | obs.occluded_views).any():
        return "a view is cut by the image border or occluded"
    offset = None if state.outline_offsets is None else float(np.abs(state.outline_offsets).max())
    if offset is not None and offset > OFFSET_MAX:
        return f"outline offset {offset:.2f} px > {OFFSET_MAX}"
    if state.cost is not None and state.cost <= GRAZED_COST:
        return f"its 3G cost {state.cost:.1e} <= {GRAZED_COST:g}: it grazes the outline"
    score = contour_score(state, obs)
    if score >= MISFIT:
        return f"its silhouettes match the mask contours at {score:.3f} >= {MISFIT}"
    disagreement = tangent_disagreement(obs.observations)
    if not np.isfinite(disagreement).any():
        return "no two views' epipolar tangents can be compared"
    worst = float(np.nanmax(disagreement))
    if worst > CONSISTENT_PX:
        return f"the masks' epipolar tangents disagree by {worst:.1f} px > {CONSISTENT_PX}"
    return None


def fit_weighted(x, obs, size_min, weight=None, evaluations=EVALUATIONS):
    """The superquadric of the highest mean :func:`weighted_ious` near ``x`` ``(11,)``: least squares
    on ``sqrt(1 - score)`` per view (their squares sum to the views' mean loss), each half-axis at
    least ``size_min`` or ``x``'s where that is smaller (stage 3V's squared slabs), exponents in
    ``SHAPE_DOMAIN``; the Jacobian by forward differences, all columns in one
    :func:`weighted_ious` call (``weight`` as there), at most ``evaluations`` evaluations. Returns the
    vector, the mean score at ``x`` and at the result, and the evaluations (the Jacobian's columns
    counted)."""
    x0 = to_superquadric(x).to_vector()
    lower = np.r_[np.minimum(x0[:3], size_min), [SHAPE_DOMAIN[0]] * 2, [-np.inf] * 6]
    upper = np.r_[[np.inf] * 3, [SHAPE_DOMAIN[1]] * 2, [np.inf] * 6]
    margin = 1e-9 * np.maximum(np.abs(x0), 1.0)
    x0 = np.clip(x0, lower + margin, upper - margin)  # strictly inside, as least_squares asks
    columns, start = [0], []  # start: the residuals at x0, where least_squares evaluates first

    def rows(X):
        return np.sqrt(np.maximum(1.0 - weighted_ious(X, obs, weight), 1e-12))

    def residuals(v):
        r = rows(v[None])[0]
        if not start and np.array_equal(v, x0):
            start.append(r)
        return r

    def jacobian(v):
        h = STEP * np.maximum(np.abs(v), 1.0)
        h = np.where(v + h > upper, -h, h)  # stay inside the bounds
        r = rows(np.vstack([v, v + np.diag(h)]))
        columns[0] += len(v)
        return ((r[1:] - r[0]) / h[:, None]).T

    scale = np.r_[x0[:3], 0.2, 0.2, [x0[:3].mean()] * 3, 0.1, 0.1, 0.1]
    res = least_squares(residuals, x0, jac=jacobian, bounds=(lower, upper), x_scale=scale, max_nfev=evaluations)
    before = 1.0 - float(np.mean((start[0] if start else residuals(x0)) ** 2))
    after = 1.0 - float(np.mean(res.fun ** 2))
    return res.x, before, after, int(res.nfev) + columns[0]


def parts_apart(obs):
    """Where the opening of the masks (:func:`sqfit.views.opening.opened`, 3V's) leaves parts apart, the second
    holding at least :data:`SPLIT_SHARE` of the mask's area (:func:`sqfit.views.opening.split_share`) in
    :data:`SPLIT_VIEWS` views or more (a lamp's shade and base, its pole opened away), ``obs`` with each view the
    opening changes cut to its largest part (:func:`sqfit.views.opening.main_part`: the shade, its corners kept);
    else None (module docstring, "Parts apart")."""
    shares = np.array([split_share(o) for o in obs.observations])
    if int(np.sum(shares >= SPLIT_SHARE)) < SPLIT_VIEWS:
        return None
    return bulk_observations(obs, part=main_part)  # not None: the views that split are cut


def thickness_candidates(x, axis, factors):
    """``(len(factors), 11)``: ``x`` with its half-axis ``axis`` times each factor, the rest as it is."""
    X = np.repeat(np.asarray(x, dtype=np.float64)[None], len(factors), axis=0)
    X[:, axis] *= factors
    return X


def slab_thickness(x, obs, before, options):
    """``(x, message)``: the slab ``x`` ``(11,)`` with its thin half-axis scaled by the factor of
    :data:`THICKNESS_FACTORS` whose silhouettes have the highest mean :func:`weighted_ious` with the
    masks opened (:func:`sqfit.fitting.least_volume.bulk_observations`: a table's legs, a monitor's
    stand gone), where that is higher than ``x``'s; else ``x`` itself and why (``message``: what was
    done, for the stage's message). Acts only where ``x`` is a slab
    (:func:`sqfit.geometry.slab.thin_section`) that leaves a part out of the outline (stage 3TP's test,
    :func:`sqfit.fitting.parts.leaves_a_part` on the outline rays of ``options.n_contour`` per view: a
    table's legs, which pulled it thick) and the opening changed a view. Where ``before`` (the stage's
    input) is a slab that stage 3V squared (:func:`sqfit.fitting.least_volume.is_squared_slab`), its thickness is the volume's, not the outline's, and too thin rather than too thick:
    :func:`squared_thickness` instead (module docstring, "Slabs")."""
    section = thin_section(x)
    if section is None:
        return x, None
    ev = stretches(np.asarray(x, dtype=np.float64), outline_rays(obs, options.n_contour), options.penalty_analytic)
    if not leaves_a_part(ev):
        return x, f"no part left out of the outline ({ev.stretch} outlier rays in stretches of {ev.views} views): " \
                  "thickness kept"
    bulk = bulk_observations(obs)
    if bulk is None:
        return x, "no thin part opened away: thickness kept"
    if is_squared_slab(before):
        return squared_thickness(x, section[0], obs, bulk)
    X = thickness_candidates(x, section[0], THICKNESS_FACTORS)
    scores = weighted_ious(X, bulk).mean(axis=1)
    best, kept = int(np.argmax(scores)), int(np.flatnonzero(THICKNESS_FACTORS == 1.0)[0])
    if not scores[best] > scores[kept]:
        return x, f"thickness kept (opened masks {scores[kept]:.3f} at its best)"
    return X[best], (f"thickness x {THICKNESS_FACTORS[best]:.2f} (opened masks {scores[kept]:.3f} -> "
                     f"{scores[best]:.3f})")


def squared_thickness(x, axis, obs, bulk):
    """``(x, message)``: a slab whose input 3V squared at equal volume (:func:`slab_thickness`), with its thin
    half-axis ``axis`` times the smaller of the two factors of :data:`SQUARED_FACTORS` whose silhouettes match
    the mask contours best, the full ones and those of the opened masks ``bulk`` (mean IoU, 3T's measure,
    :func:`sqfit.fitting.outline.contour_score`), where that is above 1: both masks ask for it thicker (module
    docstring, "Slabs"); else ``x`` and why."""
    X = thickness_candidates(x, axis, SQUARED_FACTORS)
    candidates = [to_superquadric(v) for v in X]
    picks = [int(np.argmax(r_iou_m(candidates, masks, OUTLINE_POLYGON))) for masks in (obs, bulk)]
    full, opened = SQUARED_FACTORS[picks]
    pick = min(picks)  # the factors ascend: the smaller pick
    factor = SQUARED_FACTORS[pick]
    if not factor > 1.0:
        return x, (f"its input a squared slab, the masks ask for x {full:.2f} (full) and x {opened:.2f} (opened): "
                   "thickness kept")
    return X[pick], (
        f"its input a squared slab: thickness x {factor:.2f} (the masks ask for x {full:.2f} full, x {opened:.2f} "
        "opened)")


@register("3W")
def weighted_overlap_stage(state, obs, options):
    """Stage 3W: where :func:`gate` lets it, the fit of the highest mean excess-weighted overlap
    with the mask contours from the input's and the cylinder-like starts about its axes, where it is
    a slab with the thickness of :func:`slab_thickness` (module docstring); elsewhere the input."""
    why = gate(state, obs)
    if why is not None:
        return replace(state, message=f"3W: {why}: kept the input")
    apart = parts_apart(obs)
    target = obs if apart is None else apart
    screened, failed = {}, []  # start's name -> fit_weighted's result; the starts that failed
    for k, start in enumerate([state.xi, *cylinder_starts(state.xi)]):
        name = "the input" if k == 0 else f"the cylinder about axis {k - 1}"
        try:
            screened[name] = fit_weighted(start, target, options.size_min_m, evaluations=SCREEN_EVALUATIONS)
        except (StageError, *NUMERICAL_ERRORS) as exc:
            failed.append(f"{name}: {exc}")
    if "the input" not in screened:
        return replace(state, message=f"3W: the weighted fit failed ({'; '.join(failed)}): kept the input")
    start = max(screened, key=lambda name: screened[name][2])
    before, nfev = screened["the input"][1], sum(t[3] for t in screened.values())
    try:
        x, _, after, more = fit_weighted(screened[start][0], target, options.size_min_m,
                                         evaluations=EVALUATIONS - SCREEN_EVALUATIONS)
        nfev += more
    except (StageError, *NUMERICAL_ERRORS) as exc:  # the screen's result stands
        x, after = screened[start][0], screened[start][2]
        failed.append(f"{start}, continued: {exc}")
    if after > before:
        if failed:
            start += f" ({len(failed)} failed: {'; '.join(failed)})"
        message = f"3W: weighted overlap (w = {EXCESS_WEIGHT:g}) {before:.3f} -> {after:.3f} from {start}"
    else:
        x, message = state.xi, f"3W: weighted overlap {before:.3f}, no better fit found: kept the input"
    if apart is not None:
        message += " (scored on each view's main part: the masks' opening leaves parts apart)"
    try:
        thinned, how = slab_thickness(x, obs, state.xi, options)
    except (StageError, *NUMERICAL_ERRORS) as exc:
        thinned, how = x, f"the slab's thickness not tried: {exc}"
    if how is not None:
        message += f"; {how}"
    if thinned is state.xi:
        return replace(state, nfev=state.nfev + nfev, message=message)
    return FitState(thinned, cost=None, status=state.status, nfev=state.nfev + nfev, message=message)
