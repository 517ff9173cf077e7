"""Stage 3T: where no superquadric grazes the outline, maximise the silhouettes' overlap with the masks.

3G and 3H ask the superquadric to graze every outline ray. On objects with parts one superquadric
cannot follow (a table's legs, a mug's handle, a monitor's stand) that asks for the impossible, and
the fit grows to reach the parts: on ``scenes/household.toml`` tables ended at 3D IoU 0.06 where the
best superquadric reaches 0.76-0.88 (a slab: the top). The masks' area does not ask for that: the
legs are thin, the top fills most of each mask. ``3T`` therefore acts where the grazing cost could
not be met (the input's 3G cost above :data:`TRIGGER_COST`) and its silhouettes miss the masks'
outlines (R-IOU-M against each mask's full ``contour`` polygon, not the samples' hull, which would
span the gaps between legs, below :data:`TRIGGER_R_IOU_M`): it runs stage 3A's R-IOU cost (G2)
against the contours from the input and keeps the result with the higher contour R-IOU-M. Other
inputs pass unchanged at no cost (the contour R-IOU-M is not even evaluated).

The cost gate keeps 3T off noisy masks of true superquadrics, where the higher contour overlap of
G2 is no better a fit: on ``scenes/paper-noisy.toml`` (2 px jitter + 1 degree, 30 trials) G2 on
every fit with contour R-IOU-M below 0.9 lowered the median 3D IoU from 0.773 to 0.725 (12 fits
worse, 3 better). 3G costs of the default's fits (``FitState.cost``): clean paper scene at most
2.7e-3 (60 trials), paper-noisy at most 7.6e-3 (30), household objects a superquadric describes
(book, can) 1.8e-4 to 1.3e-3, mugs and plant pots 5.8e-3 to 1.4e-2, tables, chairs, lamps,
laptops, monitors and toys 3.5e-2 to 0.13 (24 objects). Measured later with the default of then
(``1-2M-3H-3R``), 3T still triggers on 11 of 300 paper-noisy fits (seeds 0-2) and moves them both
ways: the default runs it behind a second gate, stage ``3TP`` (:mod:`sqfit.fitting.parts`: 3T's fit
kept only where what it lets go of the outline is a stretch seen in two views). ``3T`` alone is
ungated (the factor graph's landmarks start from it).

Deterministic; no random numbers.
"""

from __future__ import annotations

from dataclasses import replace

from .stages import NUMERICAL_ERRORS, STAGES, StageError, r_iou_m, register, to_superquadric

__all__ = ["TRIGGER_COST", "TRIGGER_R_IOU_M", "OUTLINE_POLYGON", "outline_stage", "over_cost_trigger", "contour_score",
           "triggers"]

#: The input's 3G cost (``FitState.cost``) above which 3T looks at its outline overlap at all.
TRIGGER_COST = 2e-2
#: ... and refines it when its silhouettes' mean IoU with the mask contours is below this.
TRIGGER_R_IOU_M = 0.9
#: Observation polygon of 3T's cost and decision.
OUTLINE_POLYGON = "contour"


@register("3T")
def outline_stage(state, obs, options):
    """Stage 3T: G2 against the mask contours where the input's silhouettes miss them (module docstring)."""
    if not over_cost_trigger(state):
        cost = "no 3G cost" if state.cost is None else f"3G cost {state.cost:.2e} <= {TRIGGER_COST:g}"
        return replace(state, message=f"3T: {cost}: kept the input")
    before = contour_score(state, obs)
    if before >= TRIGGER_R_IOU_M:
        return replace(state, message=f"3T: outline R-IOU-M {before:.3f} >= {TRIGGER_R_IOU_M}: kept the input")
    try:
        new = STAGES["3A"](state, obs, replace(options, polygon=OUTLINE_POLYGON))
    except (StageError, *NUMERICAL_ERRORS) as exc:
        return replace(state, message=f"3T: outline R-IOU-M {before:.3f}; G2 on the contours failed ({exc}): kept the input")
    after = contour_score(new, obs)
    if after > before:
        return replace(new, message=f"3T: outline R-IOU-M {before:.3f} -> {after:.3f} (G2 on the contours); {new.message}")
    return replace(state, nfev=state.nfev + new.nfev,
                   message=f"3T: outline R-IOU-M {before:.3f}, G2 on the contours reached {after:.3f}: kept the input")


def over_cost_trigger(state, floor=TRIGGER_COST):
    """Whether the input's 3G cost (``FitState.cost``) is above ``floor``, by default :data:`TRIGGER_COST` (False
    without one)."""
    return state.cost is not None and state.cost > floor


def contour_score(state, obs):
    """The state's R-IOU-M against the mask contours (:data:`OUTLINE_POLYGON`), 3T's measure."""
    return float(r_iou_m([to_superquadric(state.xi)], obs, OUTLINE_POLYGON)[0])


def triggers(state, obs, floor=TRIGGER_COST):
    """Whether 3T acts on ``state``: its 3G cost above ``floor`` (3T's :data:`TRIGGER_COST`; stage 3U asks for
    less, :data:`sqfit.fitting.two_parts.TRIGGER_COST`) and its contour R-IOU-M below :data:`TRIGGER_R_IOU_M`
    (the score is not evaluated below the cost floor)."""
    return over_cost_trigger(state, floor) and contour_score(state, obs) < TRIGGER_R_IOU_M
