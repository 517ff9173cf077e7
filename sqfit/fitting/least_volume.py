"""Stage 3V (in the default chain, before 3W): of the fits that match the outlines alike, the one of least volume.

Four masks leave a superquadric's 3D shape open where no superquadric grazes the outline: on a
monitor, a lamp or a chair, fits of very different 3D IoU against the object match the mask
contours equally (mean silhouette IoU within 0.01, silhouettes inside the masks alike). Which one
stage 3T (:mod:`sqfit.fitting.outline`) ends in depends on where it starts, and it starts from 3G's
fit of the whole outline, stand, pole and legs included. The object lies inside its visual hull,
and of two fits that match the masks as well, the larger claims volume the masks do not ask for:
a superquadric about the whole lamp where one about its shade matches as well.

So ``3V`` runs stage ``3TP`` (:mod:`sqfit.fitting.parts`) and, where 3T's trigger holds (the
input's 3G cost above :data:`~sqfit.fitting.outline.TRIGGER_COST`, its silhouettes' mean IoU with
the mask contours below :data:`~sqfit.fitting.outline.TRIGGER_R_IOU_M`), makes three more candidates:

- the *bulk fit*: stages :data:`BULK_CHAIN` on the masks with their thin parts opened away
  (:func:`bulk_observations`: :func:`sqfit.views.opening.opened`; a view the opening leaves
  alone, or a partial one, keeps its mask), the default's fit of the top, the screen, the shade;
- stage 3A's R-IOU fit (3T's cost) from the bulk fit, against the full mask contours;
- the same against the opened masks' contours, where a monitor's stand no longer pulls it
  (over the first two candidates alone, 20 objects per kind, seeds 0-2: monitors +0.03 to +0.07
  median, lamps and tables within 0.007 either way).

A candidate counts only where what it leaves out of the outline is a part seen in several views,
3TP's gate (:data:`~sqfit.fitting.parts.PART_RAYS` outlier rays in stretches of
:data:`~sqfit.fitting.parts.PART_VIEWS` views): on noisy masks of a true superquadric
(``scenes/paper-noisy.toml``) the trigger holds on a few fits, and there 3A from the bulk fit
scores higher on the contours and lies further from the truth (without the gate, with the first
two candidates: 3 of 7 fits of seeds 0 and 2 worse, one by 0.26), leaving no such stretch. Of
3TP's fit and the candidates that count, those whose contour R-IOU-M lies within :data:`TIE` of
the best tie, and the one of least volume is kept. Elsewhere 3V is 3TP, at no extra cost.

Where a candidate counted, the kept fit is last made square if it is a pinched slab
(:func:`squared_slab`): a screen or a table top fitted thin, with a diamond section across its
thickness (on the monitors below the exponent of that section ended at 1.65-1.92, near its soft
bound 1.9). The four masks show that section only along the slab's edges, a few px across, so they
hardly tell a diamond from a board, and the diamond has nearly half its volume. The square slab of
the same volume replaces it where it matches the mask contours as well (within :data:`TIE`; the
contour score does not single out the better one: on 15 monitors and tables of seeds 0 and 1 made
square it moved by -0.020 to +0.004, whether the 3D IoU rose or fell). Measured per kind (20
objects, seeds 0 / 1 / 2, median 3D IoU): monitors 0.491 / 0.454 / 0.554 -> 0.534 / 0.454 / 0.571,
tables 0.536 / 0.473 / 0.405 -> 0.544 / 0.497 / 0.467 (21 fits changed: 15 better by more than
0.01, up to 0.128; three worse, by 0.011, 0.017 and 0.031); lamps, chairs, laptops and toys
unchanged. Not where no candidate counted: there the masks may be of one pinched superquadric,
noisy (squared there as well, one fit of 100 noisy paper masks lost 0.075 and three of 50 with
20 % dropout up to 0.045, while one monitor gained 0.022). docs/real-objects.md, "Least volume",
has the measurements. Deterministic (the opened masks' area samples are drawn from a fixed seed).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .costs import ObservationSet
from .grazing import outline_rays
from .outline import OUTLINE_POLYGON, triggers
from .parts import leaves_a_part, outline_part_stage
from .stages import NUMERICAL_ERRORS, STAGES, FitState, StageError, default_state, r_iou_m, register, to_superquadric
from .trimmed import stretches
from ..geometry.slab import thin_section
from ..geometry.superquadric import volume
from ..views.opening import opened

__all__ = ["TIE", "BULK_CHAIN", "CANDIDATES", "SQUARE_SHAPE", "least_volume_stage", "bulk_observations",
           "squared_slab", "is_squared_slab"]

#: Candidates whose mean silhouette IoU with the mask contours is within this of the best tie.
TIE = 0.02
#: The stages of the bulk fit, run on the opened masks.
BULK_CHAIN = ("1", "2M", "3H")
#: The candidates besides 3TP's fit, by the names the stage message gives them.
CANDIDATES = ("the bulk fit", "3A from the bulk fit", "3A on the opened masks")
#: Seed of the opened masks' area samples.
SEED = 0
#: The shape exponent :func:`squared_slab` gives a slab's pinched section: a board's (the paper's lower
#: shape bound; the best superquadrics of 60 monitors have 0.17 there, median, 0.04-0.61 10th-90th
#: percentile).
SQUARE_SHAPE = 0.1


def bulk_observations(obs, part=opened):
    """The observations with their thin parts opened away (:func:`sqfit.views.opening.opened`), as
    an :class:`ObservationSet`; a view the opening leaves alone keeps its observation. None when
    no view changes. ``part``: what of each view to keep, ``part(observation, rng=...)`` or None
    (:func:`sqfit.views.opening.main_part` for stage 3W's parts apart)."""
    rng = np.random.default_rng(SEED)
    new = [part(o, rng=rng) for o in obs.observations]
    if all(o is None for o in new):
        return None
    return ObservationSet([o if n is None else n for o, n in zip(obs.observations, new)])


def squared_slab(xi):
    """A slab's pinched section made square at equal volume: ``(11,)`` float, or None where ``xi``
    is no pinched slab.

    ``xi`` is a slab (:func:`sqfit.geometry.slab.thin_section`: its thinnest half-axis below
    :data:`~sqfit.geometry.slab.SLAB_ASPECT` of each of the others). Its section across that axis is
    pinched where the exponent that shapes it is above 1, a diamond or a star; at 2 that halves the
    slab's volume. Such a fit is returned with that exponent at :data:`SQUARE_SHAPE` and the thin
    half-axis shrunk by the ratio of the volumes, the square slab of the same volume: a monitor's
    screen fitted as a diamond of half-thickness 0.084 becomes a board of 0.044. The other exponent
    shapes the slab's face, which the masks show: it is kept.
    """
    x = np.array(xi, dtype=np.float64)
    section = thin_section(x)
    if section is None or x[section[1]] <= 1.0:
        return None
    thin, exponent = section
    before = volume(to_superquadric(x))
    x[exponent] = SQUARE_SHAPE
    x[thin] *= before / volume(to_superquadric(x))
    return x


def is_squared_slab(xi):
    """Whether ``xi`` is a slab as :func:`squared_slab` leaves it: the exponent of its thin section exactly
    :data:`SQUARE_SHAPE`, where no optimiser ends."""
    section = thin_section(xi)
    return section is not None and float(np.asarray(xi, dtype=np.float64)[section[1]]) == SQUARE_SHAPE


def _square(kept, obs):
    """``kept`` (3V's choice where a candidate left a part out) with :func:`squared_slab` where it is
    a pinched slab and the square one matches the mask contours as well (contour R-IOU-M within
    :data:`TIE`); else ``kept``."""
    xi = squared_slab(kept.xi)
    if xi is None:
        return kept
    before, after = r_iou_m([to_superquadric(kept.xi), to_superquadric(xi)], obs, OUTLINE_POLYGON)
    if after < before - TIE:
        return replace(kept, message=f"{kept.message}; its pinched section made square matches the contours less "
                                     f"({after:.3f} against {before:.3f}): kept")
    return FitState(xi, cost=None, status=kept.status, nfev=kept.nfev,  # no optimiser's cost: a closed-form step
                    message=f"{kept.message}; a pinched slab: its section made square at equal volume "
                            f"(contour R-IOU-M {before:.3f} -> {after:.3f})")


def _bulk_candidates(obs, bulk, options):
    """The bulk fit and 3A from it on the full and on the opened contours, each with what it leaves
    out of the full outline (``Stretches``)."""
    state = default_state(bulk)
    for name in BULK_CHAIN:
        state = STAGES[name](state, bulk, options)
    contours = replace(options, polygon=OUTLINE_POLYGON)
    fits = (state, STAGES["3A"](FitState(state.xi.copy()), obs, contours),
            STAGES["3A"](FitState(state.xi.copy()), bulk, contours))
    rays = outline_rays(obs, options.n_contour)
    return [(name, fit, stretches(np.asarray(fit.xi, dtype=np.float64), rays, options.penalty_analytic))
            for name, fit in zip(CANDIDATES, fits)]


@register("3V")
def least_volume_stage(state, obs, options):
    """Stage 3V: stage 3TP, then, where 3T's trigger holds, the least-volume fit among those
    that match the mask contours alike (module docstring)."""
    base = outline_part_stage(state, obs, options)
    tp = base.message
    base = replace(base, message="3V: " + tp)
    if not triggers(state, obs):
        return base
    try:
        bulk = bulk_observations(obs)
        if bulk is None:
            return replace(base, message=base.message + "; no view has a thin part to open")
        bulk_fits = _bulk_candidates(obs, bulk, options)
    except (StageError, *NUMERICAL_ERRORS) as exc:  # an opened outline (ValueError) or a fit that failed
        return replace(base, message=base.message + f"; the bulk fit failed ({exc}): kept 3TP's fit")
    nfev = base.nfev + sum(fit.nfev for _, fit, _ in bulk_fits)
    gate = "; ".join(f"{name}: {ev.stretch} outlier rays in stretches of {ev.views} views" for name, _, ev in bulk_fits)
    candidates = [("3TP's fit", base)] + [(name, fit) for name, fit, ev in bulk_fits if leaves_a_part(ev)]
    if len(candidates) == 1:
        return replace(base, nfev=nfev, message=f"{base.message}; {gate}: no part left out, kept 3TP's fit")
    sqs = [to_superquadric(fit.xi) for _, fit in candidates]
    scores = r_iou_m(sqs, obs, OUTLINE_POLYGON)
    volumes = np.array([volume(sq) for sq in sqs])
    tied = np.flatnonzero(scores >= scores.max() - TIE)
    pick = int(tied[np.argmin(volumes[tied])])
    detail = ", ".join(f"{name} {s:.3f} / {v:.3g}" for (name, _), s, v in zip(candidates, scores, volumes))
    message = f"3V: {gate}; contour R-IOU-M / volume: {detail}: kept {candidates[pick][0]}"
    if pick == 0:
        return _square(replace(base, nfev=nfev, message=f"{message}; {tp}"), obs)
    kept = candidates[pick][1]  # its depths and outline offsets belong to the opened masks: not passed on
    return _square(FitState(kept.xi, cost=kept.cost, status=kept.status, message=message, nfev=nfev), obs)
