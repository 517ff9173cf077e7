"""Re-initialising the landmarks a solve left in a poor minimum (:func:`refit_landmarks`, used by the
batch after its solves and by iSAM2 at its rebuilds, :mod:`sqfit.graph.solve`; :func:`reorient_landmarks`,
the batch's last check of every landmark's axes), and the per-object misfit and overlap they decide by."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, S

from .. import constants as C
from ..fitting import pipeline
from ..fitting.axis_screen import SCREEN_ITERATIONS, axis_candidates, batch_levenberg_marquardt
from ..fitting.restarts import screen_rays
from ..fitting.stages import r_iou_m
from .factors import SilhouetteFactors
from .fixedlag import evenly_spread
from .growth import landmark_fit, pose_matrices, view_factor
from .landmark import landmark_to_superquadric, left_grazing, superquadric_to_landmark
from .problem import observation_at
from .shapevar import PLAIN, shape_variable

__all__ = ["RETRY_MISFIT", "RETRY_FRAMES", "OVERLAP_FRAMES", "REORIENT_CHAIN", "REORIENT_MARGIN", "refit_landmarks",
           "reorient_landmarks", "object_misfits", "landmark_overlap", "observation_set", "frames_before"]


def object_misfits(problem, values, oids, options, rays_cache=None, bounded=frozenset(), n=None, most=0):
    """RMS whitened ray residual of each object's silhouette factors at ``values`` (1: a typical ray
    one ``silhouette_sigma`` off), ``{oid: float}``; the factors of all ``oids`` evaluated together
    (those of the landmarks in ``bounded`` bounded, as in the graph), in frames ``0 .. n-1`` (all
    with None), at most ``most`` of them per object, evenly spread
    (:func:`sqfit.graph.fixedlag.evenly_spread`; 0: all)."""
    batch, factors = SilhouetteFactors(shape_variable(options)), {}
    for oid in oids:
        factors[oid] = [view_factor(problem, f, oid, options, batch, rays_cache, oid in bounded)
                        for f in evenly_spread(frames_before(problem, oid, n), most)]
    return {oid: float(np.sqrt(2.0 * sum(factor.error(values) for factor in fs) / (len(fs) * options.n_contour)))
            for oid, fs in factors.items()}


def frames_before(problem, oid, n):
    """The frames of object ``oid`` before frame ``n`` (all with None)."""
    return [f for f in problem.frames[oid] if n is None or f < n]


def observation_set(problem, oid, poses, frames):
    """Object ``oid``'s observations in ``frames`` at ``poses``, as one
    :class:`sqfit.fitting.costs.ObservationSet` (its caches shared by the overlap tests and the fit)."""
    from ..fitting.costs import ObservationSet

    return ObservationSet([observation_at(problem.observations[f, oid], poses[f]) for f in frames])


def landmark_overlap(values, oid, obs, variable=PLAIN):
    """R-IOU-M of object ``oid``'s landmark at ``values`` against ``obs`` (an ObservationSet): how
    much its silhouettes overlap its masks (``sqfit.fitting.stages.r_iou_m``; 3G's "far, huge"
    minimum has a low misfit but almost no overlap); ``variable``: the graph's size/shape variable
    (:mod:`sqfit.graph.shapevar`)."""
    sq = landmark_to_superquadric(values.atPose3(L(oid)).matrix(), variable.shape(values.atVector(S(oid))))
    return float(r_iou_m([sq], obs)[0])


#: A landmark whose re-fit was not kept is tried again only once its misfit has grown by this
#: factor or its frames by :data:`RETRY_FRAMES` since (:func:`refit_landmarks`).
RETRY_MISFIT = 1.2
#: See :data:`RETRY_MISFIT`.
RETRY_FRAMES = 2.0
#: The overlap test of :func:`refit_landmarks` (R-IOU-M below ``POOR_FIT_R_IOU_M``: 3G's far, huge
#: minimum) uses at most this many of the landmark's frames, evenly spread; the fit up to
#: ``GraphOptions.refit_max_frames``. The test runs on every landmark at every call.
OVERLAP_FRAMES = 4


def refit_landmarks(problem, values, oids, options, result, rays_cache=None, overlap_only=False, bounded=frozenset(), n=None,
                    pose_noise_refit=None, rejected=None, misfit_cap=np.inf, misfit_threshold=None, n_contour=None):
    """Re-initialise the landmarks left in a poor minimum by :func:`sqfit.fit` on all their frames at
    the solved poses: those whose silhouettes disagree (misfit above ``refit_misfit``; a refit is
    kept if its misfit is lower and its R-IOU-M not below ``sqfit.constants.POOR_FIT_R_IOU_M``) and
    those whose silhouettes barely overlap their masks (R-IOU-M below
    ``sqfit.constants.POOR_FIT_R_IOU_M``, 3G's "far, huge" minimum, whose misfit is low; a refit is
    kept if it overlaps more). The overlap uses at most :data:`OVERLAP_FRAMES` of the
    landmark's frames, the misfit and the fit at most ``refit_max_frames`` (evenly spread,
    :func:`sqfit.graph.fixedlag.evenly_spread`), so a call's cost does not grow with the sequence.
    ``overlap_only``: only the second kind. Returns the landmarks re-initialised, ``{oid: whether
    the re-fit left the grazing cost}`` (:func:`sqfit.graph.growth.landmark_fit`; empty, so false,
    when none was; :meth:`sqfit.graph.growth.Growth.refitted` takes them into the graph).
    ``rays_cache``: :func:`view_factor`; ``bounded``: the landmarks whose
    silhouette factors are bounded (their misfits measured so, :func:`object_misfits`). ``n``: only
    frames ``0 .. n-1`` are in ``values`` (iSAM2, mid-sequence; None: all). ``pose_noise_refit``:
    :func:`landmark_fit`'s (None: ``batch_pose_noise_refit``). ``rejected``: a dict kept between
    calls, ``{oid: (misfit, frames)}`` of the landmarks whose re-fit for a high misfit was not kept;
    such a landmark is not re-fitted for its misfit again until it has grown by
    :data:`RETRY_MISFIT` or its frames by :data:`RETRY_FRAMES` (a converged landmark a little above
    ``refit_misfit`` was otherwise re-fitted, in vain, at every call: 13 of 23 fits on an
    evaluation sequence). ``misfit_cap``: a landmark whose misfit is above it is not re-fitted
    for its misfit (its outline taken for the model's, not a poor minimum's; the batch's last check
    passes ``misfit_sigma``, :mod:`sqfit.graph.weighting`), only for its overlap.
    ``misfit_threshold``: the misfit above which a landmark is re-fitted (None: ``refit_misfit``;
    the batch's iSAM2 rebuilds pass ``batch_rebuild_refit_misfit``); with ``refit_misfit`` 0 none is.
    ``n_contour``: the fits' outline rays per view (None: ``batch_refit_n_contour``; iSAM2 passes
    its :attr:`sqfit.graph.growth.Growth.refit_n_contour`)."""
    if options.refit_misfit <= 0:
        return {}
    threshold = options.refit_misfit if misfit_threshold is None else misfit_threshold
    poses = pose_matrices(values, problem.n_frames if n is None else n)
    if pose_noise_refit is None:
        pose_noise_refit = options.batch_pose_noise_refit
    if n_contour is None:
        n_contour = options.batch_refit_n_contour
    most, variable = options.refit_max_frames, shape_variable(options)
    misfits = {} if overlap_only else object_misfits(problem, values, oids, options, rays_cache, bounded, n, most)
    changed = {}
    for oid in oids:
        seen = frames_before(problem, oid, n)
        tested = observation_set(problem, oid, poses, evenly_spread(seen, OVERLAP_FRAMES))
        overlap = landmark_overlap(values, oid, tested, variable)
        disjoint = overlap < C.POOR_FIT_R_IOU_M
        if overlap_only and not disjoint:
            continue
        if oid not in misfits:
            misfits.update(object_misfits(problem, values, [oid], options, rays_cache, bounded, n, most))
        before = misfits[oid]
        if (before <= threshold or before > misfit_cap) and not disjoint:
            continue
        last = None if rejected is None or disjoint else rejected.get(oid)
        if last is not None and before < RETRY_MISFIT * last[0] and len(seen) < RETRY_FRAMES * last[1]:
            continue
        frames = evenly_spread(seen, most)
        fit = landmark_fit(observation_set(problem, oid, poses, frames), options, pose_noise_refit,
                           f"frames {list(frames)}", n_contour)
        landmark = fit.landmark
        if landmark is None:
            continue
        trial = _put_landmark(gtsam.Values(values), oid, landmark, variable)
        after = object_misfits(problem, trial, [oid], options, rays_cache, bounded, n, most)[oid]
        overlap_after = landmark_overlap(trial, oid, tested, variable)
        # a lower misfit is no gain where the re-fit's silhouettes leave the masks (3G's far, huge
        # minimum, whose misfit is low): on a household sequence a landmark re-fitted at a rebuild
        # went from R-IOU-M 0.54 to 0.01 (misfit 2.6 -> 0.8) and stayed there until the next one
        kept = (overlap_after > overlap) if disjoint else (after < before and overlap_after >= C.POOR_FIT_R_IOU_M)
        if rejected is not None and not disjoint:
            if kept:
                rejected.pop(oid, None)
            else:
                rejected[oid] = (before, len(seen))
        if kept:
            _put_landmark(values, oid, landmark, variable)
            result.warnings.append(f"object {oid}: re-initialised from {len(frames)} of its {len(problem.frames[oid])} frames "
                                   f"{'' if n is None else f'(at frame {n}) '}"
                                   f"(misfit {before:.2f} -> {after:.2f}, R-IOU-M {overlap:.2f} -> "
                                   f"{overlap_after:.2f})")
            changed[oid] = fit.mismatched
    return changed


#: The fit of :func:`reorient_landmarks` from the screen's best candidate: stage 3G (its plain run, then
#: the run with per-camera pose corrections), as 3H refines its screen's best.
REORIENT_CHAIN = "3G"
#: :func:`reorient_landmarks` re-fits a landmark only when another axis choice screens below this
#: fraction of its own axes' screen cost. On eight evaluation sequences 1.0 replaced 11 landmarks
#: and 0.9 nine of them (the two others' misfits moved by 0.00-0.01), in 0.15 s per sequence
#: against 0.18 s (docs/slam-history.md, "Issue 23, twenty-first pass").
REORIENT_MARGIN = 0.9


def reorient_landmarks(problem, values, oids, options, result, rays_cache=None, bounded=frozenset(), misfit_cap=np.inf):
    """The batch's last check of every landmark's axes, without a re-fit threshold: stage 3H's
    screen (:func:`sqfit.fitting.axis_screen.batch_levenberg_marquardt` from the landmark and its five
    symmetric re-parametrisations, :func:`sqfit.fitting.axis_screen.axis_candidates`) on up to
    ``axis_check_frames`` of its frames at the solved poses (evenly spread); where another choice
    ends below :data:`REORIENT_MARGIN` of the landmark's own, 3G from that choice
    (:data:`REORIENT_CHAIN`) on up to ``refit_max_frames`` of them replaces it if its misfit
    (:func:`object_misfits`) is lower and its silhouettes still overlap the masks. ``values`` is
    updated in place.

    Why: the graph's landmarks keep the axes their initial fit or re-fit chose, and a wrong choice
    (the section turned by 45 degrees, ``e2`` about ``2 - e2``; or two axes swapped) is a minimum of
    the whole graph that no solve leaves. Such a landmark's misfit need not be high: on the growth
    scene its silhouette error was 1.3-2 times that of the same graph solved from the truth at
    misfits 0.45-0.55, about the re-fits' threshold of 0.5, so whether a run re-fitted it hinged on
    rounding (docs/slam-history.md, "Issue 23, twenty-first pass"). The screen asks every landmark
    whether another basin of the same cost is lower. Landmarks whose silhouette factors are
    bounded (``bounded``: their fit left the grazing cost) are not tested, nor those whose misfit
    is above ``misfit_cap`` (as :func:`refit_landmarks`: their outline is taken for the model's,
    not a poor minimum's, and a lower misfit is no better map). Returns ``{oid: whether the new
    fit left the grazing cost}`` of the landmarks replaced; ``axis_check_frames`` 0: none is tested.
    """
    tested = [oid for oid in oids if oid not in bounded] if options.axis_check_frames > 0 else []
    if not tested:
        return {}
    poses, variable = pose_matrices(values, problem.n_frames), shape_variable(options)
    misfits = object_misfits(problem, values, tested, options, rays_cache, bounded, None, options.refit_max_frames)
    changed = {}
    for oid in (oid for oid in tested if misfits[oid] <= misfit_cap):
        new = _other_axes(problem, values, oid, poses, options, rays_cache, bounded)
        if new is None:
            continue
        fit, landmark, after, frames = new
        if not after < misfits[oid]:
            continue
        _put_landmark(values, oid, landmark, variable)
        result.warnings.append(f"object {oid}: axes re-chosen from {frames} of its {len(problem.frames[oid])} frames "
                               f"(misfit {misfits[oid]:.2f} -> {after:.2f})")
        changed[oid] = left_grazing(fit)
    return changed


def _other_axes(problem, values, oid, poses, options, rays_cache, bounded):
    """Landmark ``oid`` on the axes its screen prefers (:func:`reorient_landmarks`): ``(fit, its
    landmark (T, shape), its misfit, frames fitted)``, or None where its own axes screen lowest, the fit failed or its
    silhouettes leave the masks."""
    variable, seen = shape_variable(options), frames_before(problem, oid, None)
    sq = landmark_to_superquadric(values.atPose3(L(oid)).matrix(), variable.shape(values.atVector(S(oid))))
    screened = observation_set(problem, oid, poses, evenly_spread(seen, options.axis_check_frames))
    ends, costs = batch_levenberg_marquardt(axis_candidates(sq.to_vector()), screen_rays(screened), SCREEN_ITERATIONS)
    best = int(np.argmin(costs))
    if not (best > 0 and costs[best] < REORIENT_MARGIN * costs[0]):  # its own axes hold (or nothing is finite)
        return None
    frames = evenly_spread(seen, options.refit_max_frames)
    fit = pipeline.fit(observation_set(problem, oid, poses, frames), REORIENT_CHAIN, initial=ends[best],
                       options={"pose_noise_refit": False, "score_stages": False, "n_contour": options.fit_n_contour})
    if not fit.ok or fit.superquadric is None:
        return None
    landmark = superquadric_to_landmark(fit.superquadric)
    trial = _put_landmark(gtsam.Values(values), oid, landmark, variable)
    overlap = observation_set(problem, oid, poses, evenly_spread(seen, OVERLAP_FRAMES))
    if landmark_overlap(trial, oid, overlap, variable) < C.POOR_FIT_R_IOU_M:
        return None
    after = object_misfits(problem, trial, [oid], options, rays_cache, bounded, None, options.refit_max_frames)[oid]
    return fit, landmark, after, len(frames)


def _put_landmark(values, oid, landmark, variable):
    """``values`` with landmark ``oid`` set to ``landmark`` ``(T, shape)`` (in place; returned)."""
    values.update(L(oid), gtsam.Pose3(landmark[0]))
    values.update(S(oid), variable.value(landmark[1]))
    return values
