"""Stage 3H's plain run: plain 3G from the refinement's fit where its nuisances are idle.

:mod:`sqfit.fitting.axis_screen` (stage 3H) screens the superquadric's axes and refines the best
candidate by 3G with per-camera pose corrections and an outline offset. Where those nuisance unknowns
stay idle and the fit grazes the outline (the test is 3H's, step 3 of its docstring), the fit is
taken from :func:`plain_fit` here: plain 3G (no pose corrections, no offset) from the refinement's
result and from sharp edges, then a slab's section held square (:func:`square_section_fit`) and a box
below the size floor (:func:`below_floor_fit`). What was measured for each step, in the order they
were built:

Where the refinement's nuisance unknowns are idle -- the cameras agree (its pose-noise estimate
at most :data:`sqfit.fitting.grazing.POSE_NOISE_TRIGGER_DEG`) and the outline offset is within
:data:`sqfit.fitting.axis_screen.IDLE_OFFSET_PX` -- and the superquadric grazes the outline (the
refinement's cost at most :data:`sqfit.fitting.outline.TRIGGER_COST`, below 3T's domain), the fit is plain 3G (no pose
corrections, no offset) started at the refinement's result. Those unknowns trade against the
size: an offset of a tenth or two of a pixel and small rotation corrections buy a thicker slab at
nearly the same cost, so on clean masks the refinement stopped with thin axes too thick (a box of
0.03 x 0.16 x 0.23, 20 trials of 4 elevated views: thinnest half-axis 1.02-1.11 times the truth
on 17 of 20, 1.04 at the median, 3D IoU 0.950; without both nuisances throughout the chain 0.967;
the plain cost lower at the truth than at the fit on 4 of 8 trials checked). Plain 3G from there:
0.966.
Measured with the default chain beside the code before (``sqsim experiment``, median / 10th
percentile 3D IoU): paper, 100 trials, seed 0 0.9948 / 0.9036 -> 0.9971 / 0.8989 (9 fits better
by > 0.01, 2 worse, by at most 0.013), seed 1 0.9955 / 0.9325 -> 0.9970 / 0.9464 (12 better, 1
worse); boxes, 30 trials, seeds 0 / 1 0.9809 / 0.9560 -> 0.9861 / 0.9655 and 0.9822 / 0.9527 ->
0.9855 / 0.9595 (none worse); cylinders, seed 0 0.9886 / 0.9810 -> 0.9903 / 0.9856; where the
nuisances are not idle it cannot act: 2 px jitter and 1 deg of rotation (``scenes/paper-noisy.toml``,
seed 0) 1 fit of 100 changed (better, 10th percentile 0.368 -> 0.401), 1 px over-segmentation
(``scenes/paper-bias1.toml``) 6 changed, 2 worse by up to 0.020, median 0.9889 either way.
Not seen while it was built (paper seed 2, boxes seed 2, cylinders seed 1, the occlusion and
truncation scenes): better in median and 10th percentile on each (docs/real-objects.md, "3H without
idle nuisances").
The cost condition keeps it off furniture: without it, household tables, monitors and lamps (20
each, seed 0), whose fits 3T/3TP then take over, changed 19 fits both ways by up to 0.2 (3T
from a slightly other start), and 240 mixed household objects lost 0.045 of median IoU on
tables; with it none of those changes.
It costs one more 3G run where it acts (3-15 evaluations, 1-5 ms): `benchmarks/bench_fit.py`
(20 paper trials, two rounds beside the code before) 16.7 / 14.8 ms against 15.4 / 13.1.
``FitOptions.idle_nuisances_plain = False`` leaves it out (:mod:`sqfit.graph`'s landmark fits).
Where a shape exponent of the refinement's fit is below :data:`SHARP_BELOW`, the plain run starts
a second time with those exponents at the lower bound (:func:`sharp_start`), and the lower cost
is kept. On boxes the cost is nearly flat along a valley from rounded edges and a thicker body to
sharp edges and the true size; the refinement's tolerance
(:data:`sqfit.fitting.axis_screen.REFINE_FTOL`) stops in it, and
a run from its result stays on the rounded side (a box of 0.03 x 0.16 x 0.23, 4 elevated views,
20 trials: thinnest half-axis 1.01-1.11 times the truth on 18, and a plain run from the default's
fit with sharp edges lowered the cost on 17). Measured with the default chain beside the code
before (``sqsim experiment``, median 3D IoU, fits better by more than 0.01 / worse): boxes, 30
trials, seeds 0 / 1 / 2 0.9861 -> 0.9876 (2 / 0; +0.011, +0.035), 0.9855 -> 0.9871 (0 / 0),
0.9859 -> 0.9872 (1 / 0); cylinders seeds 0 / 1 0.9903 -> 0.9904, 0.9907 -> 0.9907 (0 / 0);
paper, 100 trials, seeds 0 / 1 / 2 unchanged in median (2-5 fits changed; seed 2 one better,
+0.080); ``paper-noisy`` and ``paper-bias1`` (seed 0) no fit changed. It costs one more plain 3G
run on such fits: boxes 15.3 -> 17.5-17.9 ms median per object, the paper benchmark 8.0-8.3 ->
8.3 ms.
The plain runs have their own lower bound for the shape exponents, :data:`PLAIN_SHAPE_MIN`
(0.011; the other silhouette stages 0.015): a box's edges are still rounded at 0.015. Beside the
sharp start alone (same command): boxes seeds 0 / 1 / 2 0.9876 -> 0.9904, 0.9871 -> 0.9897,
0.9872 -> 0.9897 (10th percentile 0.9657 -> 0.9734 on seed 0); cylinders 0.9904 -> 0.9922, 0.9907
-> 0.9928; paper unchanged; no fit worse by more than 0.003 anywhere. The same bound for every
silhouette stage (``constants.SILHOUETTE_SHAPE_BOUNDS``) gave boxes as much but made 3 of 100
``paper-noisy`` fits worse (one by 0.22; 10th percentile 0.378 -> 0.359); those never reach the
plain run.
A slab (:func:`sqfit.geometry.slab.thin_section`: a book, a box thin along one axis) whose
section across the thin axis is nearly square (its exponent between :data:`SQUARE_SECTION_ABOVE`
and :data:`SQUARE_SECTION_BELOW`) is run once more with that exponent held at
:data:`PLAIN_SHAPE_MIN` (:func:`square_section_fit`), and that fit is kept where its cost is at
most :data:`SQUARE_SECTION_KEEP` times the plain run's. The masks show that section only along
the slab's edges, a few px across: the plain cost is nearly flat from rounded edges and a thicker
slab to square ones and the true thickness, and the sharp start above does not reach the square
end (the 19 books below that it changed: thinnest half-axis 1.034 times the truth, median, ->
1.020). Measured with the default chain beside the code before (``sqsim experiment``, median /
10th percentile 3D IoU; per kind ``scenes/household.toml`` with
``objects.catalogue`` one kind, 20 trials; seed 2 not looked at until it was built): books, seeds
0 / 1 / 2, median 0.902 / 0.914 / 0.905 -> 0.909 / 0.916 / 0.915 (19 fits changed, 13 better by
more than 0.01, up to 0.046, none worse); boxes, 30 trials, seeds 0 / 1 0.9904 / 0.973 -> 0.9909
/ 0.986 and 0.9897 / 0.963 -> 0.9902 / 0.968 (5 better, none worse); no fit changed on paper
(seeds 0 and 1, 100 trials), ``paper-noisy`` (seeds 0 and 2, 100), 8 px jitter and 20 % dropout
(50 each), cylinders (seed 0, 30), bowls, mugs, bottles, plant pots, cans, lamps, chairs, laptops
and toys (seeds 0-2), monitors and tables (seeds 0 and 1). Bowls are why the section must be
nearly square: without the upper limit one bowl of seed 0 and one of seed 1, sections 0.22 and
0.35, lost 0.026 and 0.053.
Where the thin axis is ``x`` or ``y`` one exponent does not square the section: ``e2`` shapes the
edges through the other in-plane axis, ``e1`` those through ``z`` and the face
(:mod:`sqfit.geometry.slab`). Holding ``e2`` alone left ``e1``'s edges rounded, and such books
stayed thick (of the 20 books of seed 4 those with the thin axis in the plane: thinnest half-axis
1.01-1.16 times the book's, median 1.05; with it along ``z`` 0.97-1.02). So there a second run
starts from the slab re-expressed with its thin axis as ``z``
(:func:`sqfit.geometry.slab.thin_axis_as_z`) and holds ``e1``; the lower cost of the runs
counts. That run stops at the cost tolerance :data:`SQUARE_SECTION_FTOL`, not the refinement's
(:data:`sqfit.fitting.axis_screen.REFINE_FTOL`): from the re-expressed start the first steps gain
little and stopped there
(a book of seed 4, trial 14: no step taken, 2.4 times the plain cost; at 1e-6 0.99 times, 3D
IoU 0.880 -> 0.918). The run holding ``e2`` keeps the refinement's tolerance: at 1e-6 it too
went further, and a bowl of seed 0 whose section (``e1`` 0.197) sits just below
:data:`SQUARE_SECTION_BELOW` became a flat disc (0.252 -> 0.200). Where the box below the size
floor (next) is kept, its section is held square the same way with the lowered floor.
Measured with the default chain beside the code before (same command as below): books, seeds
0 / 4 / 2 / 6 / 8, median 0.913 / 0.912 / 0.915 / 0.924 / 0.920 -> 0.930 / 0.924 / 0.926 /
0.935 / 0.934, 41 fits better by more than 0.01 (up to +0.061), 1 worse (-0.025: a box below
the floor, 0.97 times the book's thickness, thinned to 0.94 by its square section); tables
(through 3V's bulk fit), seeds 0 / 4: 1 better, 3 worse (+0.021; -0.013 to -0.025), medians
the same; on the other ten kinds (seeds 0 and 4) not a fit changed. Books of seeds 10 and
12, never run before: 0.915 / 0.922 -> 0.933 / 0.929, 19 better, none worse. No fit changed on
``paper`` and ``paper-noisy`` (seeds 0 and 1), ``paper-erode1``, ``paper-bias1``, cylinders and the
fourteen noise sweeps (seed 0); on boxes one (10th percentile 0.986 -> 0.987).
Below the size floor: where the plain run's fit has a half-axis at the floor (``FitOptions.size_min_m``, 0.1
m, the paper's prior; within :data:`AT_FLOOR`), plain 3G runs once more with the floor at
:data:`FLOOR_RELEASE` times it, from the fit and from :func:`sharp_start` (:func:`below_floor_fit`), and that
fit is kept where it is a box (both exponents below :data:`BOX_SHAPE`, the sharp edges of
:func:`sharp_start`) and costs less. A box's silhouettes show its corners, and from them its thickness; a
rounded slab's do not, which is why the floor exists (README, "Thin objects": from the paper's level views a
rounded fit below the floor thins too far, ``paper`` trial 43 of seed 0: 0.772 -> 0.562 without the box
test). Books of half-thickness 0.06-0.09 m held at the floor (4 of seed 0) made up for it with rounded edges
(the larger exponent 0.09-0.61) and 1.16-1.57 times the book's volume; below it, boxes of their thickness.
Measured with the default chain beside the code before (``sqsim experiment scenes/household.toml --set
"objects.catalogue=[KIND]" --set experiment.limit=false --trials 20 --seed S --chains default``; set on the
books of seed 0 and the paper fits at the floor, the other seeds run after): books, seeds 0 / 4 / 2 / 6 / 8,
the 9 fits that changed all better (+0.010 to +0.224), 10th percentile 0.724 / 0.834 / 0.765 / 0.887 / 0.818
-> 0.872 / 0.868 / 0.815 / 0.889 / 0.858, median 0.909 -> 0.913 on seed 0, the others the same; tables
through 3V's bulk fit (its top, the legs opened away, is a slab below the floor): 9 fits of 100 changed, 4
better and 4 worse by more than 0.01 (+0.012 to +0.129, -0.022 to -0.059), medians the same or up; the other
ten kinds (seeds 0 and 4) not a fit. The box test was first "both exponents at most 0.4": two fits of the
noise sweeps, a superquadric of half-axes 3.2, 2.8 and 1.2 m fitted as a slab at the floor (``paper`` trial
16 under 1 px of dilation and 5 % dropout, 3D IoU 0.176 and 0.187), went below it with exponents 0.37 and
0.32 and lost 0.021 and 0.076; below 0.25 neither does, and the books' boxes (0.16 at most) are kept. It
never keeps a fit on ``paper`` (seeds 0 and 1, 100 trials; reached once, rounded), ``paper-noisy`` (seeds 0
and 1), ``paper-erode1``, ``paper-bias1``, boxes or cylinders; of the fourteen noise sweeps' fits (seed 0)
3H's plain run ended at the floor on 13 and kept a box below it on one (1 px erosion), whose final fit did
not change.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .grazing import minimise, offset_groups
from .raycost import ray_bounds
from ..geometry.slab import thin_axis_as_z, thin_section

__all__ = ["SHARP_BELOW", "PLAIN_SHAPE_MIN", "SQUARE_SECTION_ABOVE", "SQUARE_SECTION_BELOW", "SQUARE_SECTION_KEEP",
           "SQUARE_SECTION_FTOL", "AT_FLOOR", "FLOOR_RELEASE", "BOX_SHAPE", "plain_fit", "square_section_fit",
           "below_floor_fit", "sharp_start", "offset_from_plain", "at_size_floor"]

#: The plain run starts a second time where a shape exponent of the refinement's fit is below
#: this, with those exponents at the lower bound, and the lower cost is kept (module docstring).
SHARP_BELOW = 0.25
#: Lower bound of the shape exponents in the plain runs (the other silhouette stages:
#: ``constants.SILHOUETTE_SHAPE_BOUNDS[0]``, 0.015): boxes' edges are sharper at it, and noisy masks,
#: whose nuisances are not idle, never reach it (module docstring; ``SHAPE_DOMAIN[0]`` is 0.01).
PLAIN_SHAPE_MIN = 0.011
#: Plain 3G runs once more on a slab whose thin section is nearly square, its exponent above
#: :data:`SQUARE_SECTION_ABOVE` and below :data:`SQUARE_SECTION_BELOW`, with that exponent held at
#: :data:`PLAIN_SHAPE_MIN` (:func:`square_section_fit`), and keeps that fit where its cost is at most
#: :data:`SQUARE_SECTION_KEEP` times the plain run's (module docstring).
SQUARE_SECTION_ABOVE = 2 * PLAIN_SHAPE_MIN
SQUARE_SECTION_BELOW = 0.2
SQUARE_SECTION_KEEP = 1.05
#: Cost tolerance of the held run from a slab re-labelled with its thin axis as ``z``
#: (:func:`square_section_fit`): from there the first steps gain little, and at 3H's refinement tolerance
#: (:data:`sqfit.fitting.axis_screen.REFINE_FTOL`) it stopped before a step (module docstring).
SQUARE_SECTION_FTOL = 1e-6
#: The plain run goes below the size floor where a half-axis sits at it (within this, relative:
#: its bounds are soft) and the fit below it is a box (:func:`below_floor_fit`).
AT_FLOOR = 1e-3
#: The floor there, times ``FitOptions.size_min_m``.
FLOOR_RELEASE = 0.1
#: A box's shape exponents: below this, the sharp edges of :func:`sharp_start` (:func:`below_floor_fit`).
BOX_SHAPE = SHARP_BELOW


def plain_fit(rays, xi, options):
    """Plain 3G on the outline ``rays`` from ``xi`` (3H's refined fit, 11 parameters), as in the module
    docstring: ``(res, nfev, how)``, the kept :class:`sqfit.fitting.lm.LMResult`, the evaluations of every
    run and what was kept (for the stage's message), or None where the first run failed. Where ``xi``
    has a shape exponent below :data:`SHARP_BELOW`, also from :func:`sharp_start`, keeping the lower
    cost; then a slab's section held square (:func:`square_section_fit`, kept up to
    :data:`SQUARE_SECTION_KEEP` times the cost) and a box below the size floor (:func:`below_floor_fit`,
    kept where it costs less; its section then held square the same way)."""
    xi = np.asarray(xi, dtype=np.float64)
    res = minimise(rays, xi, options, 0.0, shape_min=PLAIN_SHAPE_MIN)
    if not np.all(np.isfinite(res.x)):
        return None
    nfev, how = res.nfev, "plain 3G"
    sharp = sharp_start(xi)
    if sharp is not None:
        other = minimise(rays, sharp, options, 0.0, shape_min=PLAIN_SHAPE_MIN)
        nfev += other.nfev
        if np.all(np.isfinite(other.x)) and other.cost < res.cost:
            res, how = other, f"plain 3G from sharp edges (e < {SHARP_BELOW:g} set to {PLAIN_SHAPE_MIN:g})"
    board = square_section_fit(rays, res.x, options)
    if board is not None:
        nfev += board.nfev
        if board.cost <= SQUARE_SECTION_KEEP * res.cost:
            res, how = board, f"{how}, then with the slab's thin section held square (e = {PLAIN_SHAPE_MIN:g})"
    below = below_floor_fit(rays, res.x, options)
    if below is not None:
        nfev += below.nfev
        if below.cost < res.cost:
            lowered = _floor_lowered(options)
            res, how = below, (f"{how}, then a box below the size floor ({options.size_min_m:g} m lowered to "
                               f"{lowered.size_min_m:g} m)")
            board = square_section_fit(rays, res.x, lowered)
            if board is not None:
                nfev += board.nfev
                if board.cost <= SQUARE_SECTION_KEEP * res.cost:
                    res, how = board, f"{how}, its thin section held square"
    return res, nfev, how


def square_section_fit(rays, xi, options):
    """Plain 3G on ``rays`` from the slab ``xi`` with the section across its thin axis
    (:func:`sqfit.geometry.slab.thin_section`) held square (module docstring): an
    :class:`sqfit.fitting.lm.LMResult` (``nfev`` of every run), or None where ``xi`` is no slab whose
    section is nearly square but not square, or every run failed.

    Where the thin axis is ``z``, ``e1`` shapes the whole section: it is held at
    :data:`PLAIN_SHAPE_MIN` where it lies between :data:`SQUARE_SECTION_ABOVE` and
    :data:`SQUARE_SECTION_BELOW`. Where it is ``x`` or ``y``, ``e2`` shapes the section through the
    other in-plane axis and ``e1`` both the section through ``z`` and the slab's face, so no one
    exponent squares it: the run holding ``e2`` (where it lies in that range) is joined by one from
    the same slab re-expressed with its thin axis as ``z`` (:func:`sqfit.geometry.slab.thin_axis_as_z`:
    ``e1`` then shapes the section, ``e2`` the face) holding ``e1``, where ``e2`` is below the range's
    top and either exponent above its bottom, to the cost tolerance :data:`SQUARE_SECTION_FTOL`; the
    lower cost of the two is returned."""
    xi = np.asarray(xi, dtype=np.float64)
    section = thin_section(xi)
    if section is None:
        return None
    thin, e = section
    runs = []
    if SQUARE_SECTION_ABOVE < xi[e] < SQUARE_SECTION_BELOW:
        runs.append(_held(rays, xi, e, options))
    if thin < 2 and xi[4] < SQUARE_SECTION_BELOW and xi[3:5].max() > SQUARE_SECTION_ABOVE:
        runs.append(_held(rays, thin_axis_as_z(xi), 3, replace(options, ftol_analytic=min(options.ftol_analytic,
                                                                                         SQUARE_SECTION_FTOL))))
    return _lowest(runs)


def _lowest(runs):
    """The finite run of ``runs`` (:class:`sqfit.fitting.lm.LMResult`) with the lowest cost, the first of equal
    costs, its ``nfev`` the evaluations of every run; None where none is finite."""
    finite = [res for res in runs if np.all(np.isfinite(res.x))]
    if not finite:
        return None
    return replace(min(finite, key=lambda res: res.cost), nfev=sum(res.nfev for res in runs))


def _held(rays, xi, e, options):
    """Plain 3G on ``rays`` from ``xi`` with its shape exponent ``e`` (3 or 4) held at :data:`PLAIN_SHAPE_MIN`."""
    lower, upper = (np.array(b, dtype=np.float64) for b in ray_bounds(options.size_min_m, shape_min=PLAIN_SHAPE_MIN))
    lower[e] = upper[e] = PLAIN_SHAPE_MIN
    start = np.array(xi, dtype=np.float64)
    start[e] = PLAIN_SHAPE_MIN
    return minimise(rays, start, options, 0.0, bounds=(lower, upper))


def below_floor_fit(rays, xi, options):
    """Plain 3G on ``rays`` from ``xi``, a fit with a half-axis at the size floor (``options.size_min_m``,
    within :data:`AT_FLOOR`), with the floor lowered to :data:`FLOOR_RELEASE` times it, from ``xi`` and
    from :func:`sharp_start`; the lower cost of the two where that fit is a box (both exponents below
    :data:`BOX_SHAPE`), else None (module docstring)."""
    xi = np.asarray(xi, dtype=np.float64)
    if not at_size_floor(xi, options):
        return None
    lowered = _floor_lowered(options)
    runs = [minimise(rays, start, lowered, 0.0, shape_min=PLAIN_SHAPE_MIN)
            for start in (xi, sharp_start(xi)) if start is not None]
    best = _lowest(runs)  # both runs' evaluations counted
    if best is None or best.x[3:5].max() >= BOX_SHAPE:
        return None
    return best


def _floor_lowered(options):
    """``options`` with the size floor lowered to :data:`FLOOR_RELEASE` times it (a box below the floor)."""
    return replace(options, size_min_m=FLOOR_RELEASE * options.size_min_m)


def at_size_floor(xi, options):
    """Whether a half-axis of ``xi`` ``(11,)`` sits at the size floor ``options.size_min_m`` (within
    :data:`AT_FLOOR`, relative: the floor is a soft bound) or below it."""
    return bool(np.abs(np.asarray(xi, dtype=np.float64)[:3]).min() <= options.size_min_m * (1.0 + AT_FLOOR))


def sharp_start(xi):
    """``xi`` ``(11,)`` with its shape exponents below :data:`SHARP_BELOW` set to the plain run's lower
    bound :data:`PLAIN_SHAPE_MIN`, or None when it has none (module docstring: the second
    start of the plain run)."""
    xi = np.array(xi, dtype=np.float64)
    flat = xi[3:5] < SHARP_BELOW
    if not flat.any():
        return None
    xi[3:5] = np.where(flat, PLAIN_SHAPE_MIN, xi[3:5])
    return xi


def offset_from_plain(rays, x, options):
    """The outline offsets (px, one per group of :func:`sqfit.fitting.grazing.offset_groups`) that 3G
    estimates when started at the plain fit ``x`` (11 parameters) with its offsets at 0, and the run's
    evaluations: ``(offsets, nfev)``. No pose corrections; the plain runs' shape bound
    :data:`PLAIN_SHAPE_MIN`, so square edges stay within reach, and the plain fit's own size floor: where
    ``x`` lies below ``options.size_min_m`` (a box below the floor, :func:`below_floor_fit`) the floor
    lowered to :data:`FLOOR_RELEASE` times it, as there (at the floor, the offset would thin the outline of a
    superquadric the floor holds too thick). Used by 3H's idle test (:mod:`sqfit.fitting.axis_screen`):
    whether an offset belongs to the masks or to the refinement's basin."""
    x = np.asarray(x, dtype=np.float64)
    if np.abs(x[:3]).min() < options.size_min_m * (1.0 - AT_FLOOR):
        options = _floor_lowered(options)
    groups = offset_groups(rays, options)
    x0 = np.concatenate([x, np.zeros(int(groups.max()) + 1)])
    res = minimise(rays, x0, options, 0.0, options.outline_offset_sigma_px, groups, shape_min=PLAIN_SHAPE_MIN)
    return res.x[len(x):], res.nfev
