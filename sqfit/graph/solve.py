"""The factor graph and its baselines on one sequence (inputs: :mod:`sqfit.graph.problem`).

Graph (GTSAM): a ``Pose3`` ``X(i)`` per frame, a ``PriorFactorPose3`` on ``X(0)`` at the first
odometry pose, a ``BetweenFactorPose3`` per frame step from the odometry; per object ``j`` a
landmark pose ``L(j)`` (``Pose3``, superquadric -> world) and a size/shape vector ``S(j)``
(``[ax, ay, az, e1, e2]``) with the bound penalty (eq. 7) as a unary factor; one silhouette factor
per (frame, object) (:func:`sqfit.graph.factors.silhouette_factor`) under a Huber-robust noise
model; with ``GraphOptions.floor_z``, a floor factor per landmark (:mod:`sqfit.graph.floor`). Each
landmark starts from :func:`sqfit.fit` on the first frames that see it, at the current pose
estimates, unless that fit barely overlaps its masks (then it waits for more frames). The graph's
variables and factors are added frame by frame by :mod:`sqfit.graph.growth`; landmarks a solve left
in a poor minimum are re-initialised by :mod:`sqfit.graph.refit`.

Methods (every one returns a :class:`sqfit.graph.problem.SlamResult`):

- ``odometry``: the odometry poses, no objects;
- ``fixed``: per-object :func:`sqfit.fit` on all frames that see the object, at the odometry
  poses (no joint optimisation);
- ``graph``: the graph above, grown frame by frame by iSAM2 as ``graph-isam2`` below
  (``batch_start = "isam2"``; ``"windows"``: batch Levenberg-Marquardt over growing windows of
  ``batch_window`` frames, each solve from the previous solution and the new frames chained by the
  odometry); then the re-fit of landmarks in poor minima, the move to the best scale
  (:mod:`sqfit.graph.scale`) and a last solve to ``final_relative_tolerance``, its floor factors at
  ``final_floor_sigma_m`` for the landmarks that fit their masks (``final_floor_misfit``), frame
  0's prior at ``final_prior_sigma_deg`` and ``final_prior_sigma_m`` and frame 0's silhouettes at
  ``final_first_view_sigma_scale``, after
  which the landmarks are tested again (every landmark's axes, ``axis_check_frames``; overlap; the
  misfit, up to ``misfit_sigma``, only without the axis test) and, where one changed, the graph
  solved once more; with a floor, a solution from iSAM2 far from the
  odometry (``batch_odometry_chi2``) is solved again from windows;
- ``graph-isam2``: the same graph grown frame by frame with iSAM2 (one update per frame; a landmark
  joins once its first frames are enough for its initial fit (``init_frames``, ``init_parallax_deg``),
  or at the last frame if they never are); once both ``isam2_rescale_every`` frames and
  ``isam2_rescale_parallax_deg`` of parallax have passed since the last time (later ones further
  apart, :mod:`sqfit.graph.schedule`), the landmarks in poor minima are re-fitted on the frames so
  far and iSAM2 is rebuilt at the best scale;
- ``quadric``: QuadricSLAM (:mod:`sqfit.graph.quadric`): ellipsoid landmarks ``L(j)``, radii
  ``Q(j)``, one box factor per (frame, object) whose mask does not touch the image border, batch
  Levenberg-Marquardt, initialised by the paper's linear method from all the object's boxes.
"""

from __future__ import annotations

import time
from dataclasses import replace

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, O, Q, S, X

from ..fitting.grazing import OFFSET_UNIT_PX
from .factors import box_factor, with_floor_factors
from .fixedlag import condition_on_past
from .growth import (Growth, initial_fit, landmark_keys, noise_models, pose_factors, pose_matrices, robust_noise,
                     skip_object, with_first_pose_prior)
from .landmark import N_SHAPE, landmark_to_superquadric
from .options import GraphOptions
from .problem import SlamResult, check_inputs, error_line
from .quadric import initialise_quadric, observation_box, quadric_to_superquadric
from .refit import object_misfits, refit_landmarks, reorient_landmarks
from .scale import best_scale, rescaled, scale_dependent_factors
from .schedule import RebuildSchedule
from .weighting import noise_scales

__all__ = ["METHODS", "run", "odometry_chi2", "relinearize_thresholds", "odometry", "fixed_pose_fits", "superquadric_graph",
           "superquadric_isam2", "quadric_graph"]


#: What the optimisers raise on a bad system (gtsam's indeterminate-system error is a RuntimeError;
#: a factor's non-finite residual a FloatingPointError): the method's result is flagged failed.
_SOLVER_ERRORS = (RuntimeError, FloatingPointError)


class _Clock:
    """Wall and process CPU time since construction."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def elapsed(self):
        return time.perf_counter() - self.wall, time.process_time() - self.cpu


def _offsets(values, oids, options):
    """Each landmark's estimated outline offset, px (empty when not estimated)."""
    if options.outline_offset_sigma_px <= 0:
        return {}
    return {oid: float(values.atVector(O(oid))[0]) * OFFSET_UNIT_PX for oid in oids}


def _lm(graph, values, options, max_lambda=None):
    """Levenberg-Marquardt from ``values`` to ``options.relative_tolerance``; ``max_lambda``: the
    damping at which it gives up (GTSAM's default when None). ``(values, iterations)``."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(options.max_iterations))
    params.setRelativeErrorTol(options.relative_tolerance)
    if max_lambda is not None:
        params.setlambdaUpperBound(float(max_lambda))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    out = optimizer.optimize()
    return out, optimizer.iterations()


def _objects(values, oids, variable):
    """The landmarks ``oids`` at ``values`` as superquadrics; ``variable``: the size/shape variable."""
    return {oid: landmark_to_superquadric(values.atPose3(L(oid)).matrix(), variable.shape(values.atVector(S(oid))))
            for oid in oids}


def odometry(intrinsics, odometry_poses, observations, options=None):
    """Baseline: the odometry poses as the trajectory, no objects."""
    clock, problem = _Clock(), check_inputs(intrinsics, odometry_poses, observations)
    wall, cpu = clock.elapsed()
    return SlamResult("odometry", problem.odometry_poses.copy(), seconds=wall, cpu_seconds=cpu,
                      skipped=dict(problem.skipped), warnings=list(problem.warnings))


def fixed_pose_fits(intrinsics, odometry_poses, observations, options=None):
    """Baseline: per-object :func:`sqfit.fit` on every frame that sees it, at the odometry poses."""
    clock, options = _Clock(), GraphOptions.coerce(options)
    problem = check_inputs(intrinsics, odometry_poses, observations)
    result = SlamResult("fixed", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings))
    for oid, frames in problem.frames.items():
        fit = initial_fit(problem, oid, frames, problem.odometry_poses, options)
        if fit.landmark is None:
            skip_object(result, oid, fit.message)
        else:
            result.objects[oid] = landmark_to_superquadric(*fit.landmark)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


def superquadric_graph(intrinsics, odometry_poses, observations, options=None, incremental=False):
    """Joint camera-pose and superquadric optimisation (module docstring): batch Levenberg-Marquardt,
    or iSAM2 frame by frame with ``incremental=True``.

    Parameters
    ----------
    intrinsics : Intrinsics
    odometry_poses : (n, 4, 4) float
        ``T_world_camera`` per frame.
    observations : dict of (int, int) -> Observation
        ``(frame, object_id) -> observation``.
    options : GraphOptions or dict, optional
    incremental : bool

    Returns
    -------
    result : SlamResult
    """
    options = GraphOptions.coerce(options)
    problem = check_inputs(intrinsics, odometry_poses, observations)
    return _isam2(problem, options) if incremental else _batch(problem, options)


def superquadric_isam2(intrinsics, odometry_poses, observations, options=None):
    """:func:`superquadric_graph` with ``incremental=True`` (iSAM2, frame by frame)."""
    return superquadric_graph(intrinsics, odometry_poses, observations, options, incremental=True)


def _batch(problem, options):
    """The whole graph from iSAM2 frame by frame (``batch_start = "isam2"``, :func:`_incremental`)
    or from Levenberg-Marquardt over growing windows (``"windows"``, :func:`_windows`); then the
    re-fit of landmarks in poor minima (:func:`refit_landmarks`) and one solve of the whole graph to
    ``final_relative_tolerance`` (GraphOptions). A batch from iSAM2 that fails (a solver error, e.g.
    GTSAM's indeterminate system in an undamped step) is solved again from windows (a warning names
    the error). With a floor (``floor_z``), a solution from iSAM2
    whose odometry factors' mean chi-square (:func:`odometry_chi2`) exceeds ``batch_odometry_chi2``
    is solved again from windows, and the one with the lower error kept (a warning says so). Where
    landmarks end with a misfit above ``misfit_sigma`` (:mod:`sqfit.graph.weighting`), the whole
    batch runs once more with their silhouette noise scaled from the start, and that is the result
    (a warning names the scales, and whether the first run was solved again from windows). That run
    starts from ``batch_start`` again, whatever the first run kept: starting it from windows where
    the first run kept the windows' solution was measured and left (household seeds 0-3, 2 runs: it
    changed the start of 3 sequences of 24, which ended at ATE 0.07, 0.40 and 0.66 m, the other 21
    at 0.03-0.57 m; docs/slam-history.md, thirteenth pass)."""
    clock = _Clock()
    result, scales, fell_back = _batch_once(problem, options)
    if result.ok and scales:
        second, _, _ = _batch_once(problem, options, scales)
        note = ("solved again with the silhouette noise of the landmarks that fit their masks poorly scaled (misfit "
                f"above {options.misfit_sigma}): " + ", ".join(f"object {oid} x{v:.2f}" for oid, v in sorted(scales.items())))
        if fell_back:
            note += f" (the first run: {fell_back})"
        if second.ok:
            result = second
        else:
            note += f"; that solve failed ({second.message}), kept the first"
        result.warnings.append(note)
    _flag_odometry(result, options)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


def _flag_odometry(result, options):
    """Warn when ``result``'s estimate disagrees with the odometry beyond ``batch_odometry_chi2``
    (``SlamResult.odometry_chi2``): the last word of both graph methods on their estimate, after
    the batch's own fallbacks (a solve again from windows, a run with scaled silhouette noise)."""
    if result.ok and result.odometry_chi2 is not None and result.odometry_chi2 > options.batch_odometry_chi2:
        result.warnings.append(
            f"the estimate disagrees with the odometry (mean chi-square {result.odometry_chi2:.1f} per step, above "
            f"{options.batch_odometry_chi2}): the trajectory and the map have run off, or the odometry noise model "
            "(odometry_sigma_m, odometry_sigma_deg) is tighter than the odometry")


def _batch_once(problem, options, scales=None):
    """:func:`_batch` with the landmarks' silhouette noise ``scales`` (``{oid: scale}``, None: all 1):
    ``(result, scales, note)``, the second the scales its solution asks for (:func:`noise_scales`;
    empty when none differs from those given), the third the warning of a solve again from windows
    (None without one)."""
    note = None
    result, estimated = _batch_from(problem, options, options.batch_start, scales)
    if not result.ok and options.batch_start == "isam2":
        # iSAM2's undamped Gauss-Newton step met a system it cannot solve (a landmark drifted into
        # 3G's far, huge minimum leaves its variables nearly unconstrained: "Indeterminate linear
        # system"); the windows' Levenberg-Marquardt is damped
        fallback, estimated_windows = _batch_from(problem, options, "windows", scales)
        note = f"batch from iSAM2 failed ({result.message}); solved again from windows"
        if fallback.ok:
            result, estimated = fallback, estimated_windows
        else:
            note += f", which failed too ({fallback.message})"
        result.warnings.append(note)
    elif (result.ok and options.batch_start == "isam2" and options.floor_z is not None
          and result.odometry_chi2 > options.batch_odometry_chi2):
        # iSAM2's undamped steps ran off (household sequences with a floor): the windows instead
        fallback, estimated_windows = _batch_from(problem, options, "windows", scales)
        chi2_windows = fallback.odometry_chi2 if fallback.ok else 0.0
        note = (f"batch from iSAM2 inconsistent with the odometry (mean chi-square {result.odometry_chi2:.1f} per step, "
                f"above {options.batch_odometry_chi2}); solved again from windows (chi-square {chi2_windows:.1f})")
        if fallback.ok and fallback.error_final < result.error_final:
            result, estimated = fallback, estimated_windows
        note += f", kept the {'windows' if result is fallback else 'iSAM2'} solution"
        result.warnings.append(note)
    return result, estimated, note


def odometry_chi2(graph, values):
    """Mean chi-square (twice the error) of ``graph``'s odometry factors (``BetweenFactorPose3``) at
    ``values``: about 6 per step when the estimate agrees with the odometry within its noise model."""
    factors = (graph.at(k) for k in range(graph.size()))
    errors = [f.error(values) for f in factors if isinstance(f, gtsam.BetweenFactorPose3)]
    return 2.0 * float(np.mean(errors)) if errors else 0.0


def _batch_from(problem, options, start, scales=None):
    """:func:`_batch` from ``start`` (``GraphOptions.batch_start``) with the silhouette noise
    ``scales``; ``(result, scales asked for)`` (:func:`_batch_once`); an ``ok`` result carries its
    ``odometry_chi2``."""
    clock, n = _Clock(), problem.n_frames
    result = SlamResult("graph", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings))
    growth = Growth(problem, options, result, options.batch_pose_noise_refit, scales, options.batch_refit_n_contour)
    estimated = {}
    try:
        if start == "isam2":
            isam, values, rebuilt = _incremental(growth, options, result, batch=True)
            graph = growth.undamped(isam.getFactorsUnsafe())
            # iSAM2's last rebuild at frame n re-fitted at these values already
            refit = not (options.isam2_refit and rebuilt)
        else:
            graph, values = _windows(growth, options, result)
            refit = True
        if refit:
            graph = growth.refitted(graph, refit_landmarks(problem, values, growth.added, options, result, growth.rays,
                                                           bounded=growth.bounded, rejected=growth.rejected))
        final = replace(options, relative_tolerance=options.final_relative_tolerance)
        floored = growth.floored()
        if options.final_floor_sigma_m is not None and floored:
            misfits = object_misfits(problem, values, floored, options, growth.rays, growth.bounded,
                                     most=options.refit_max_frames)
            floored = [oid for oid in floored if misfits[oid] <= options.final_floor_misfit]
        if options.final_floor_sigma_m is not None and floored:
            graph = with_floor_factors(graph, floored, robust_noise(1, options.final_floor_sigma_m, options.huber_k),
                                       options.floor_z, growth.batch.variable)
        silhouettes = growth.batch
        final_n_contour = options.final_n_contour or options.n_contour
        if final_n_contour != options.n_contour or options.final_first_view_sigma_scale != 1.0:
            graph, silhouettes = growth.resampled(graph, final_n_contour, options.final_first_view_sigma_scale)
        if options.final_prior_sigma_deg is not None or options.final_prior_sigma_m is not None:
            graph = with_first_pose_prior(graph, problem.odometry_poses[0], growth.noise["final_prior"])
        cap = options.misfit_sigma if options.misfit_sigma > 0 else np.inf  # 0: no outline is the model's
        for check in (False, True):
            # the last solve moves the poses and far along the scale valley: its landmarks are tested
            # again, at poses no earlier test saw, so without the memory of re-fits not kept. Every
            # landmark's axes are checked up to misfit_sigma (axis_check_frames; reorient_landmarks);
            # one the solve dropped into 3G's far, huge minimum is re-fitted; and, without the axis
            # check, one whose misfit is above refit_misfit (up to misfit_sigma (cap): above, the
            # outline is not a superquadric's, and a lower misfit is no better map). If any landmark
            # changed, the graph is solved once more
            if check:
                reoriented = reorient_landmarks(problem, values, growth.added, options, result, growth.rays,
                                                bounded=growth.bounded, misfit_cap=cap)
                if not (refit_landmarks(problem, values, growth.added, options, result, growth.rays,
                                        bounded=growth.bounded, misfit_cap=cap,
                                        overlap_only=options.axis_check_frames > 0) or reoriented):
                    break
            if options.rescale:
                values = _rescale(graph, values, n, growth.added, silhouettes)
            result.error_initial = graph.error(values)
            values, iterations = _lm(graph, values, final, options.final_max_lambda)
            result.iterations += iterations
    except _SOLVER_ERRORS as exc:
        result.fail(getattr(exc, "where", "Levenberg-Marquardt"), exc)
    else:
        growth.finish()
        result.error_final = graph.error(values)
        estimated = noise_scales(problem, values, growth.added, options, growth.scales, growth.rays, growth.bounded)
        result.poses, result.objects = pose_matrices(values, n), _objects(values, growth.added, growth.batch.variable)
        result.outline_offsets = _offsets(values, growth.added, options)
        result.odometry_chi2 = odometry_chi2(graph, values)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result, estimated


def _windows(growth, options, result):
    """Levenberg-Marquardt over growing windows of ``batch_window`` frames, each solve started from
    the previous one's solution, to ``window_relative_tolerance``; the windows before the last solve
    with the past held fixed (``batch_free_frames``, :func:`_window_solve`), the last one the whole
    graph. ``(graph, values)``."""
    n = growth.problem.n_frames
    graph, values, by_key = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
    window = options.batch_window or n
    for start in range(0, n, window):
        end = min(start + window, n)
        new_graph, new_values = growth.add(range(start, end))
        for k in range(new_graph.size()):
            for key in new_graph.at(k).keys():
                by_key.setdefault(key, []).append(graph.size())
            graph.add(new_graph.at(k))
        values.insert(new_values)
        if end >= n:
            values, iterations = _lm(graph, values, replace(options, relative_tolerance=options.window_relative_tolerance))
        else:
            iterations = _window_solve(graph, by_key, values, growth, end, options)
        result.iterations += iterations
        growth.update(values, end)
    return graph, values


def _rescale(graph, values, n, oids, batch):
    """``values`` moved along the scale direction to the best scale about frame 0's camera
    (:mod:`sqfit.graph.scale`; the silhouette factors, those ``batch`` (a
    :class:`~sqfit.graph.factors.SilhouetteFactors`) holds, do not change with it)."""
    centre = values.atPose3(X(0)).translation()
    keys = ([X(i) for i in range(n)], [L(oid) for oid in oids], [S(oid) for oid in oids])
    changing = scale_dependent_factors(graph, batch.holds)
    return rescaled(values, centre, best_scale(changing, values, centre, *keys, batch.variable), *keys, batch.variable)


def _window_solve(graph, by_key, values, growth, end, options):
    """Solve a window before the last (frames ``0 .. end-1`` in ``graph``) to
    ``window_relative_tolerance``, updating ``values`` in place: only the poses of the last
    ``batch_free_frames`` frames and the landmarks they see move (all of them with 0), the older
    views of those landmarks at most ``batch_past_views`` per landmark
    (:func:`sqfit.graph.fixedlag.condition_on_past`). ``by_key``: the positions in ``graph`` of
    the factors on each variable. Returns the iterations."""
    coarse = replace(options, relative_tolerance=options.window_relative_tolerance)
    first = end - options.batch_free_frames
    if options.batch_free_frames == 0 or first <= 0:
        out, iterations = _lm(graph, values, coarse)
        values.update(out)
        return iterations
    active = {X(f) for f in range(first, end)}
    active |= {key for f in range(first, end) for oid in growth.by_frame.get(f, []) if oid in growth.added
               for key in landmark_keys(oid, options)}
    touching = sorted({k for key in active for k in by_key.get(key, ())})
    sub_graph, sub_values = condition_on_past([graph.at(k) for k in touching], values, active,
                                              options.batch_past_views)
    out, iterations = _lm(sub_graph, sub_values, coarse)
    values.update(out)
    return iterations


def _isam2(problem, options):
    if options.floor_z is not None and options.final_floor_sigma_m is not None:
        # no last solve follows: the floor is the last solves' from the first frame (GraphOptions)
        options = replace(options, floor_sigma_m=options.final_floor_sigma_m)
    clock, n = _Clock(), problem.n_frames
    result = SlamResult("graph-isam2", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings), frame_seconds=np.zeros(n), frame_cpu_seconds=np.zeros(n))
    growth = Growth(problem, options, result)
    try:
        isam, estimate, _ = _incremental(growth, options, result)
    except _SOLVER_ERRORS as exc:
        result.fail(getattr(exc, "where", "iSAM2"), exc)
        result.seconds, result.cpu_seconds = clock.elapsed()
        return result
    growth.finish()
    result.iterations = n
    factors = isam.getFactorsUnsafe()
    result.error_final = factors.error(estimate)
    result.odometry_chi2 = odometry_chi2(factors, estimate)
    _flag_odometry(result, options)
    result.poses, result.objects = pose_matrices(estimate, n), _objects(estimate, sorted(growth.added), growth.batch.variable)
    result.outline_offsets = _offsets(estimate, sorted(growth.added), options)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


def _incremental(growth, options, result, batch=False):
    """iSAM2 over the sequence, one update per frame, rebuilt (:func:`_isam2_rescaled`) when
    :class:`sqfit.graph.schedule.RebuildSchedule` says; ``(isam, estimate, rebuilt)``, the last
    whether it was rebuilt after the last frame. ``batch``: the batch's start (its relinearisation
    thresholds, :func:`relinearize_thresholds`). An update that fails with a solver error is
    replaced by a restart (:func:`_restarted`, a warning names the error); a solver error there, or
    at the first frame, is raised with the attribute ``where`` naming the frame. Each frame's wall
    and CPU time goes to ``result.frame_seconds`` and ``result.frame_cpu_seconds`` when those are
    arrays."""
    params = gtsam.ISAM2Params()
    if options.isam2_dogleg:
        params.setOptimizationParams(gtsam.ISAM2DoglegParams())
    params.setRelinearizeThreshold(relinearize_thresholds(options, batch))
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    schedule, rebuilt = RebuildSchedule(growth.problem, options), False
    growth.damping_sigma = options.batch_landmark_damping_sigma if batch else 0.0
    # iSAM2's factors as given to it, in its order (its indices): a failed update leaves iSAM2's own
    # copy in an unknown state
    factors = gtsam.NonlinearFactorGraph()
    for i in range(growth.problem.n_frames):
        step = _Clock()
        try:
            new = growth.add([i])
            try:
                growth.placed(isam.update(*new))
                estimate = isam.calculateEstimate()
                factors.push_back(new[0])
            except _SOLVER_ERRORS as exc:
                if i == 0:
                    raise
                isam, estimate, factors = _restarted(factors, estimate, new, params, i + 1, growth, options, result, exc)
            rebuilt = schedule.due(estimate, i) and bool(growth.added)
            if rebuilt:
                isam, estimate, factors = _isam2_rescaled(isam, factors, estimate, params, i + 1, growth, options, result,
                                                          batch)
        except _SOLVER_ERRORS as exc:
            exc.where = f"iSAM2 update at frame {i}"
            raise
        growth.update(estimate, i + 1)
        if result.frame_seconds is not None:
            result.frame_seconds[i], result.frame_cpu_seconds[i] = step.elapsed()
    return isam, estimate, rebuilt


def _restarted(factors, estimate, new, params, n, growth, options, result, exc):
    """iSAM2 started again after its update with frame ``n - 1``'s factors and variables ``new``
    failed with ``exc`` (GTSAM's indeterminate system: an undamped Gauss-Newton step where a
    landmark has drifted into 3G's far, huge minimum, its variables then barely constrained): the
    graph so far (``factors``, iSAM2's before the update, and ``new``, less the damping priors) from
    the last ``estimate`` and the new variables, its landmarks that barely overlap their masks
    re-fitted (:func:`refit_landmarks`, overlap test only), solved by Levenberg-Marquardt (damped),
    and a new iSAM2 linearised there. ``(isam, estimate, factors)``; a warning names the error."""
    result.warnings.append(f"iSAM2 update at frame {n - 1} failed ({type(exc).__name__}: {error_line(exc)}); started again from "
                           "Levenberg-Marquardt on the graph so far")
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(growth.undamped(factors))
    graph.push_back(growth.undamped_new(new[0]))
    growth.damping.clear()
    values = gtsam.Values(estimate)
    values.insert(new[1])
    graph = growth.refitted(graph, refit_landmarks(growth.problem, values, growth.added, options, result, growth.rays,
                                                   overlap_only=True, bounded=growth.bounded, n=n,
                                                   pose_noise_refit=growth.pose_noise_refit,
                                                   n_contour=growth.refit_n_contour))
    values, _ = _lm(graph, values, options)
    fresh = gtsam.ISAM2(params)
    fresh.update(graph, values)
    return fresh, fresh.calculateEstimate(), graph


def relinearize_thresholds(options, batch=False):
    """iSAM2's relinearisation thresholds per kind of variable (``gtsam.ISAM2ThresholdMap``): the
    camera poses ``isam2_relinearize_threshold``, the landmarks' pose, size/shape and outline offset
    ``isam2_landmark_relinearize_threshold`` (the ``graph-isam2`` method) or, with ``batch`` (the
    batch's iSAM2 start), ``batch_landmark_relinearize_threshold`` (GraphOptions). Every kind of
    variable in the graph must be in the map: GTSAM looks a variable's kind up without a default."""
    landmark = options.batch_landmark_relinearize_threshold if batch else options.isam2_landmark_relinearize_threshold
    thresholds, landmark = gtsam.ISAM2ThresholdMap(), float(landmark)
    for key, dim, value in ((X(0), 6, float(options.isam2_relinearize_threshold)), (L(0), 6, landmark),
                            (S(0), N_SHAPE, landmark), (O(0), 1, landmark)):
        thresholds.insert((chr(gtsam.Symbol(key).chr()), np.full(dim, value)))
    return thresholds


def _isam2_rescaled(isam, factors, estimate, params, n, growth, options, result, batch=False):
    """iSAM2 moved to the best scale (:func:`_rescale`): iSAM2 relinearises only variables whose
    update exceeds its threshold, one Gauss-Newton step per update, so the scale the first landmarks
    took from the first frames' odometry is never corrected by the later odometry (the whole map
    must move together). With ``isam2_refit``, the landmarks left in a poor minimum are re-fitted
    there as after the batch solve (:func:`refit_landmarks` on frames ``0 .. n-1``): in the two failed runs
    of the evaluation scenes, at frame 10 landmarks sat in 3G's far, huge minimum (R-IOU-M 0.00) or
    far off (misfit 7.7), and their silhouettes then pulled the trajectory away. A new
    iSAM2 on the same factors, less the damping priors of the landmarks added since the last rebuild
    (``batch_landmark_damping_sigma``), linearised at the result; the old one is kept when nothing
    moved. ``factors``: iSAM2's factors, in its order. ``batch``: the batch's start, whose re-fits
    here test the misfit against ``batch_rebuild_refit_misfit`` (GraphOptions). ``(isam, estimate,
    factors)``."""
    graph = growth.undamped(factors)
    moved = _rescale(graph, estimate, n, growth.added, growth.batch)
    refitted = {}
    if options.isam2_refit:
        threshold = options.batch_rebuild_refit_misfit if batch and options.batch_rebuild_refit_misfit > 0 else None
        refitted = refit_landmarks(growth.problem, moved, growth.added, options, result, growth.rays,
                                   bounded=growth.bounded, n=n, pose_noise_refit=growth.pose_noise_refit,
                                   rejected=growth.rejected, misfit_threshold=threshold, n_contour=growth.refit_n_contour)
    graph = growth.refitted(graph, refitted)
    if not refitted and abs(moved.atPose3(X(n - 1)).translation() - estimate.atPose3(X(n - 1)).translation()).max() < 1e-6:
        return isam, estimate, factors
    fresh = gtsam.ISAM2(params)
    fresh.update(graph, moved)
    growth.damping.clear()
    return fresh, fresh.calculateEstimate(), graph


def quadric_graph(intrinsics, odometry_poses, observations, options=None):
    """Baseline: QuadricSLAM's dual quadrics from boxes in the same graph, batch Levenberg-Marquardt."""
    clock, options = _Clock(), GraphOptions.coerce(options)
    problem = check_inputs(intrinsics, odometry_poses, observations)
    result = SlamResult("quadric", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings))
    noise, K = noise_models(options), intrinsics.K
    graph = pose_factors(problem, noise, range(problem.n_frames))
    values = gtsam.Values()
    for i, T in enumerate(problem.odometry_poses):
        values.insert(X(i), gtsam.Pose3(T))
    added = []
    for oid, frames in problem.frames.items():
        frames = [f for f in frames if not problem.observations[f, oid].touches_border]
        boxes = [observation_box(problem.observations[f, oid]) for f in frames]
        Z, radii = initialise_quadric(problem.odometry_poses[frames], K, boxes)
        if Z is None:
            skip_object(result, oid, f"no quadric from the boxes of {len(frames)} untruncated frames")
            continue
        values.insert(L(oid), gtsam.Pose3(Z))
        values.insert(Q(oid), radii)
        for f, box in zip(frames, boxes):
            graph.add(box_factor(robust_noise(4, options.box_sigma_px, options.huber_k), X(f), L(oid), Q(oid), K, box))
        added.append(oid)
    try:
        result.error_initial = graph.error(values)
        out, result.iterations = _lm(graph, values, options)
    except _SOLVER_ERRORS as exc:
        result.fail("Levenberg-Marquardt", exc)
    else:
        result.error_final = graph.error(out)
        result.poses = pose_matrices(out, problem.n_frames)
        result.objects = {oid: quadric_to_superquadric(out.atPose3(L(oid)).matrix(), out.atVector(Q(oid)))
                          for oid in added}
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


#: Every method by name, in table order.
METHODS = {
    "odometry": odometry,
    "fixed": fixed_pose_fits,
    "quadric": quadric_graph,
    "graph": superquadric_graph,
    "graph-isam2": superquadric_isam2,
}


def run(intrinsics, odometry_poses, observations, methods=tuple(METHODS), options=None):
    """Run several methods on one sequence; ``{method: SlamResult}`` in the order given."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; valid: {list(METHODS)}")
    return {m: METHODS[m](intrinsics, odometry_poses, observations, options) for m in methods}
