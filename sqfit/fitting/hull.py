"""Stage ``HULL``: a visual-hull baseline -- carve the masks, fit a superquadric to the hull's surface.

1. Stage 1's triangulated point (:func:`sqfit.fitting.stages.triangulate`) centres a carving cube
   of half-size :data:`BOX_MARGIN` times the largest back-projected reach of any view's outline
   from its centroid (grown when the hull touches it, :func:`sqfit.views.carving.visual_hull`).
2. Voxel carving, 48^3 then 96^3 over the region that survived, honouring the outline labels: a
   voxel is carved only where it projects onto known background of the object
   (:mod:`sqfit.views.carving`).
3. The faces between kept and carved voxels are the hull's surface points; an outlier-tolerant
   point-cloud fit (:func:`sqfit.fitting.pointcloud.fit_points`, the EMS mixture model) gives the
   superquadric. Parts of the hull that no superquadric follows (a mug's handle, a bulge left
   behind an occluder, the cone of a view-starved side) become outliers rather than dragging it.

The chain ``HULL`` (alias ``hull``, :data:`HULL_CHAIN`) is the baseline of issue 21; ``HULL-3H``
starts the default's last stage (axis screen + 3G) from it instead of stage 2's ellipsoid. The
stage computes its start from the masks alone (it discards an ``initial`` superquadric). The
next stage gets closed-form depths per sample on the fitted quadric
(:func:`sqfit.fitting.stages.ellipsoid_depths`).

Measured (``sqsim experiment SCENE --trials 30 --chains default,hull,HULL-3H --seed S --workers 1``,
household ``--trials 24``; seeds 0 / 1; median 3D IoU; median wall time per object of the whole
chain, a loaded 2-core machine):

==========  ===============  ===============  ===============  ==================
scene       default 1-2-3H   hull             HULL-3H          time (default/hull)
==========  ===============  ===============  ===============  ==================
paper       0.993 / 0.994    0.704 / 0.647    0.993 / 0.993    12 / 361-395 ms
boxes       0.971 / 0.970    0.681 / 0.661    0.968 / 0.970    15 / 371-375 ms
cylinders   0.977 / 0.979    0.759 / 0.797    0.979 / 0.977    16 / 389-391 ms
household   0.563 / 0.648    0.580 / 0.597    0.555 / 0.654    14 / 395-402 ms
==========  ===============  ===============  ===============  ==================

As a start for 3H (``HULL-3H``) where stage 2's ellipsoid is poor (its 3D IoU < 0.5: 13-19 of
30 trials on paper, boxes, cylinders): the hull start is better (median IoU 0.43-0.75 against
0.21-0.36) but the refined fits are not: paper seed 0 median / 10th percentile 0.965 / 0.639
against the default's 0.979 / 0.889, seed 1 0.987 / 0.771 against 0.975 / 0.600; boxes and
cylinders within 0.01 of the default's medians, with more trials worse by > 0.01 than better
(4 / 5 / 2 worse against 2 / 3 / 0 better on boxes s0, s1, cylinders s1). 3H's own axis screen
already repairs a poor ellipsoid; ``HULL-3H`` costs the hull's ~0.4 s. Not the default's start.

Deterministic; no random numbers.
"""

from __future__ import annotations

import numpy as np

from ..views.carving import FINE_CELLS, visual_hull
from .pointcloud import fit_points
from .stages import FitState, StageError, default_state, ellipsoid_depths, register, triangulate

__all__ = ["HULL_CHAIN", "BOX_MARGIN", "object_hull", "hull_stage"]

#: The visual-hull baseline chain.
HULL_CHAIN = "HULL"
#: Half-size of the first carving cube, as a multiple of the largest back-projected outline reach.
BOX_MARGIN = 1.5
#: Fewest surface points the fit accepts (one per parameter).
_MIN_POINTS = 11


def object_hull(obs, options=None, fine=FINE_CELLS):
    """The visual hull of one object's observations (steps 1-2 of the module docstring).

    Parameters
    ----------
    obs : sqfit.fitting.costs.ObservationSet
    options : FitOptions, optional
        Passed to stage 1 (which reads none of them today).
    fine : int
        Voxels across the largest extent of the fine carving
        (:func:`sqfit.views.carving.visual_hull`; stage ``HULL``: the default).

    Returns
    -------
    hull : sqfit.views.carving.VoxelHull

    Raises
    ------
    StageError
        From stage 1 (``singular_triangulation``, ``triangulation_behind_camera``).
    """
    start = triangulate(default_state(obs), obs, options)
    centre, depths = start.xi[5:8], start.view_depths
    reach = []
    for o, depth in zip(obs.observations, depths):
        k = o.camera.intrinsics
        offset = np.abs(o.contour - o.centroid) / np.array([k.fx, k.fy])
        reach.append(float(np.max(np.linalg.norm(offset, axis=1))) * depth)
    return visual_hull(obs.observations, centre, BOX_MARGIN * max(reach), fine=fine)


@register("HULL")
def hull_stage(state, obs, options):
    """Stage HULL: visual hull, then the EMS point-cloud fit to its surface (module docstring).

    Raises :class:`StageError` ``empty_hull`` when fewer than 11 surface points survive the
    carving (masks that no common volume explains, e.g. wrong poses).
    """
    hull = object_hull(obs, options)
    points = hull.surface_points()
    if len(points) < _MIN_POINTS:
        raise StageError("empty_hull", f"stage HULL: the carving kept {len(points)} surface points (< "
                         f"{_MIN_POINTS}): the masks share no common volume")
    fit = fit_points(points)
    message = (f"hull of {int(hull.occupied.sum())} voxels ({hull.voxel:.3g} m), {len(points)} surface points; "
               f"EMS: {fit.iterations} EM iterations, {fit.switches} switches, inlier scale {fit.sigma:.3g} m, "
               f"{np.mean(fit.inlier > 0.5):.0%} inliers")
    return FitState(fit.xi, sample_depths=ellipsoid_depths(fit.xi, obs), cost=fit.cost, message=message,
                    nfev=fit.iterations)
