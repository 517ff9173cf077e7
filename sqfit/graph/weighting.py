"""How much each landmark's silhouettes count: a landmark no superquadric follows gets a wider noise.

``silhouette_sigma`` is the spread of a ray residual where the object *is* a superquadric and the
masks are good. Where it is not (a table's legs, a chair, a monitor on its stand, a mug's handle),
the rays miss by the model's error, not by the masks' noise: far more than ``silhouette_sigma``,
correlated along the outline and from frame to frame. At ``silhouette_sigma`` those rays outweigh
the odometry, and the poses bend to make a superquadric graze what it cannot.

So each landmark's noise is estimated from its own residuals, as in variance-component estimation:
its misfit ``m`` (RMS whitened ray residual at ``silhouette_sigma``,
:func:`sqfit.graph.refit.object_misfits`) was below 1 for every landmark at the end of the batch
on the evaluation scenes (72 runs), and 1.2-8 on the household sequences (the highest on tables). A landmark whose misfit exceeds ``GraphOptions.misfit_sigma`` by more than
:data:`RESCALE_STEP` gets its silhouette factors' sigma scaled by ``m / misfit_sigma``
(:func:`noise_scales`), so its rays count by the spread they show; the others keep
``silhouette_sigma`` exactly. The batch estimates the scales from its solution and, where any
landmark needs one, solves the whole sequence again with them from the first frame
(:mod:`sqfit.graph.solve`). Re-estimating them as the graph grows was tried and not kept: early in a
sequence the poses are still off and every landmark's misfit is high, so the scales chased the pose
error and one household sequence's trajectory error went from 0.25 to 0.66 m.

Measured on 15 household sequences (``scenes/sequence-household.toml``, seeds 0-4, 3 sequences
each, the floor and the scene's odometry noise given, docs/slam-history.md "Issue 23, seventh pass"): median
object IoU over all their objects 0.336 without, 0.390 with the second solve (quadrics from boxes:
0.257), median trajectory error 0.082 -> 0.075 m, at the commit that introduced it; with the
graph's factors compiled since (the same model, other rounding), two runs 1e-9 apart gave 0.498 and
0.398 (README "Household objects in a sequence"). The evaluation scenes never ask for it.
"""

from __future__ import annotations

import numpy as np

from .refit import object_misfits

__all__ = ["RESCALE_STEP", "noise_scales"]

#: A landmark's noise scale is changed only when the new estimate differs from the current scale by
#: more than this factor (either way).
RESCALE_STEP = 1.1


def noise_scales(problem, values, oids, options, current, rays_cache=None, bounded=frozenset()):
    """The landmarks of ``oids`` whose silhouette noise scale changes at ``values``, ``{oid: scale}``.

    A landmark's scale is ``max(1, m / misfit_sigma)`` with ``m`` its misfit on at most
    ``refit_max_frames`` of its frames; ``current``: the scales so far (``{oid: scale}``, 1 where
    absent). Only scales that move by more than :data:`RESCALE_STEP` are returned. Empty when
    ``misfit_sigma`` is 0."""
    if options.misfit_sigma <= 0 or not oids:
        return {}
    misfits = object_misfits(problem, values, oids, options, rays_cache, bounded, most=options.refit_max_frames)
    changed = {}
    for oid, m in misfits.items():
        new = max(1.0, m / options.misfit_sigma) if np.isfinite(m) else current.get(oid, 1.0)
        old = current.get(oid, 1.0)
        if new > old * RESCALE_STEP or new < old / RESCALE_STEP:
            changed[oid] = new
    return changed
