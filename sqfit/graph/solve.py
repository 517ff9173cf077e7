"""The factor graph and its baselines on one sequence (inputs: :mod:`sqfit.graph.problem`).

Graph (GTSAM): a ``Pose3`` ``X(i)`` per frame, a ``PriorFactorPose3`` on ``X(0)`` at the first
odometry pose, a ``BetweenFactorPose3`` per frame step from the odometry; per object ``j`` a
landmark pose ``L(j)`` (``Pose3``, superquadric -> world) and a size/shape vector ``S(j)``
(``[ax, ay, az, e1, e2]``) with the bound penalty (eq. 7) as a unary factor; one silhouette factor
per (frame, object) (:func:`sqfit.graph.factors.silhouette_factor`) under a Huber-robust noise
model; with ``GraphOptions.floor_z``, a floor factor per landmark (:mod:`sqfit.graph.floor`). Each
landmark starts from :func:`sqfit.fit` on the first frames that see it, at the current pose
estimates.

Methods (every one returns a :class:`sqfit.graph.problem.SlamResult`):

- ``odometry``: the odometry poses, no objects;
- ``fixed``: per-object :func:`sqfit.fit` on all frames that see the object, at the odometry
  poses (no joint optimisation);
- ``graph``: the graph above, batch Levenberg-Marquardt over growing windows of ``batch_window``
  frames, each solve from the previous solution and the new frames chained by the odometry; then
  the re-fit of landmarks in poor minima, the move to the best scale (:mod:`sqfit.graph.scale`) and
  a last solve to ``final_relative_tolerance``;
- ``graph-isam2``: the same graph grown frame by frame with iSAM2 (one update per frame; a landmark
  joins once its first frames are enough for its initial fit (``init_frames``, ``init_parallax_deg``),
  or at the last frame if they never are); every ``isam2_rescale_every`` frames the landmarks in
  poor minima are re-fitted on the frames so far and iSAM2 is rebuilt at the best scale;
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

from .. import constants as C
from ..fitting import pipeline
from ..fitting.grazing import OFFSET_UNIT_PX
from ..fitting.stages import r_iou_m
from .factors import SilhouetteFactors, bounds_factor, box_factor, floor_factor, silhouette_factor
from .fixedlag import condition_on_past, evenly_spread
from .landmark import camera_rays, landmark_to_superquadric, left_grazing, superquadric_to_landmark
from .problem import GraphOptions, SlamResult, check_inputs, observation_at, ready_to_initialise
from .quadric import initialise_quadric, observation_box, quadric_to_superquadric
from .scale import best_scale, rescaled, scale_dependent_factors

__all__ = ["METHODS", "run", "odometry", "fixed_pose_fits", "superquadric_graph", "superquadric_isam2",
           "quadric_graph"]


#: What the optimisers raise on a bad system (gtsam's indeterminate-system error is a RuntimeError;
#: a factor's non-finite residual a FloatingPointError): the method's result is flagged failed.
_SOLVER_ERRORS = (RuntimeError, FloatingPointError)


class _Clock:
    """Wall and process CPU time since construction."""

    def __init__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def elapsed(self):
        return time.perf_counter() - self.wall, time.process_time() - self.cpu


def _noise(options):
    rot, pos = np.radians(options.odometry_sigma_deg), options.odometry_sigma_m
    prot, ppos = np.radians(options.prior_sigma_deg), options.prior_sigma_m
    return {
        "odometry": gtsam.noiseModel.Diagonal.Sigmas(np.array([rot] * 3 + [pos] * 3)),
        "prior": gtsam.noiseModel.Diagonal.Sigmas(np.array([prot] * 3 + [ppos] * 3)),
    }


def _robust(dim, sigma, k):
    """Huber on the factor's whitened norm; ``sigma`` and ``k`` per row (a factor of ``dim`` inlier
    rows has a whitened norm of about ``sqrt(dim)``, so the threshold is ``k sqrt(dim)``)."""
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k * np.sqrt(dim)),
                                          gtsam.noiseModel.Isotropic.Sigma(dim, sigma))


def _pose_factors(problem, noise, frames):
    """Prior on frame 0 and odometry between consecutive frames, for ``frames``."""
    graph, poses = gtsam.NonlinearFactorGraph(), problem.odometry_poses
    for i in frames:
        if i == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(poses[0]), noise["prior"]))
        else:
            delta = gtsam.Pose3(np.linalg.inv(poses[i - 1]) @ poses[i])
            graph.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), delta, noise["odometry"]))
    return graph


def _poses(values, n):
    return np.stack([values.atPose3(X(i)).matrix() for i in range(n)])


def _initial_fit(problem, oid, frames, poses, options, pose_noise_refit=True):
    """:func:`sqfit.fit` of object ``oid`` on ``frames`` at ``poses`` (frame -> (4, 4)): :func:`_landmark_fit`."""
    obs = [observation_at(problem.observations[f, oid], poses[f]) for f in frames]
    return _landmark_fit(obs, options, pose_noise_refit, f"frames {list(frames)}")


def _landmark_fit(obs, options, pose_noise_refit, where):
    """:func:`sqfit.fit` (chain ``init_chain``) on ``obs`` (observations, or an ObservationSet);
    ``(landmark, message, mismatched)``: a landmark ``(T, shape)`` or None and the failure message
    (naming ``where``), and whether the fit had to leave the grazing cost
    (:func:`sqfit.graph.landmark.left_grazing`: its silhouette factors are then bounded,
    ``GraphOptions.mismatch_ray_k``). ``pose_noise_refit``: the fit's option of that name."""
    res = pipeline.fit(obs, options.init_chain, options={"pose_noise_refit": bool(pose_noise_refit)})
    if not res.ok or res.superquadric is None:
        return None, f"initial fit on {where} failed: {res.status}: {res.message}", False
    return superquadric_to_landmark(res.superquadric), "", left_grazing(res)


def _add_landmark(graph, values, problem, oid, frames, landmark, options, batch, rays_cache=None, mismatched=False):
    """Landmark ``oid``'s variables at ``landmark`` ``(T, shape)``, its priors and its silhouette factors in
    ``frames``; ``mismatched``: its initial fit left the grazing cost (:func:`_landmark_fit`): its rays
    are bounded and it gets no floor factor (a table fitted as its top need not touch the floor)."""
    T, shape = landmark
    shape = np.asarray(shape, dtype=np.float64)
    values.insert(L(oid), gtsam.Pose3(T))
    values.insert(S(oid), shape)
    graph.add(bounds_factor(S(oid), options.bounds_weight))
    # Weak priors at the initial fit: the rotation of a shape with a symmetry axis (and e.g. e1 of a
    # shape seen only side-on) is not observed, which iSAM2's undamped Gauss-Newton cannot solve.
    rot, pos, size = np.radians(options.landmark_prior_sigma_deg), options.landmark_prior_sigma_m, options.shape_prior_sigma
    graph.add(gtsam.PriorFactorPose3(L(oid), gtsam.Pose3(T), gtsam.noiseModel.Diagonal.Sigmas(np.array([rot] * 3 + [pos] * 3))))
    graph.add(gtsam.PriorFactorVector(S(oid), shape, gtsam.noiseModel.Isotropic.Sigma(len(shape), size)))
    if options.floor_z is not None and not mismatched:
        graph.add(floor_factor(_robust(1, options.floor_sigma_m, options.huber_k), L(oid), S(oid), options.floor_z))
    offset = _offset_key(oid, options)
    if offset is not None:  # the masks' outline offset, px / OFFSET_UNIT_PX, prior at 0
        values.insert(offset, np.zeros(1))
        graph.add(gtsam.PriorFactorVector(offset, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(
            1, options.outline_offset_sigma_px / OFFSET_UNIT_PX)))
    for f in frames:
        graph.add(_silhouette(problem, f, oid, options, batch, rays_cache, mismatched))


def _silhouette(problem, frame, oid, options, batch, rays_cache=None, bounded=False):
    """The silhouette factor of ``(frame, oid)``, evaluated with the graph's other ones by ``batch``
    (a :class:`sqfit.graph.factors.SilhouetteFactors`); ``rays_cache`` (a dict) keeps the rays of
    the factors made so far, for the re-fit's factors of the same views. ``bounded``: each ray's
    whitened residual bounded by ``mismatch_ray_k`` (a landmark whose outline one superquadric
    cannot graze, :func:`_landmark_fit`)."""
    rays = None if rays_cache is None else rays_cache.get((frame, oid))
    if rays is None:
        rays = camera_rays(problem.observations[frame, oid], options.n_contour)
        if rays_cache is not None:
            rays_cache[frame, oid] = rays
    # the ray residuals carry contour_rays' weights 1 / sqrt(n): sigma per weighted row
    sigma = options.silhouette_sigma / np.sqrt(len(rays))
    bound = options.mismatch_ray_k * sigma if bounded and options.mismatch_ray_k > 0 else np.inf
    return silhouette_factor(_robust(len(rays), sigma, options.huber_k), X(frame), L(oid),
                             S(oid), rays, batch, _offset_key(oid, options), OFFSET_UNIT_PX, bound)


def _offset_key(oid, options):
    """Key of landmark ``oid``'s outline offset, or None when the graph does not estimate offsets."""
    return O(oid) if options.outline_offset_sigma_px > 0 else None


def _landmark_keys(oid, options):
    """The keys of landmark ``oid``'s variables: pose, size/shape and, if estimated, outline offset."""
    offset = _offset_key(oid, options)
    return (L(oid), S(oid)) + (() if offset is None else (offset,))


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


def _objects(values, oids):
    return {oid: landmark_to_superquadric(values.atPose3(L(oid)).matrix(), values.atVector(S(oid))) for oid in oids}


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
        landmark, message, _ = _initial_fit(problem, oid, frames, problem.odometry_poses, options)
        if landmark is None:
            _skip(result, oid, message)
        else:
            result.objects[oid] = landmark_to_superquadric(*landmark)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


def _skip(result, oid, reason):
    result.skipped[oid] = reason
    result.warnings.append(f"object {oid}: skipped, {reason}")


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


class _Growth:
    """Grows the graph frame by frame (shared by the batch windows and iSAM2): each new frame's pose,
    chained from the current estimate of the previous one by the odometry step, its odometry factor,
    its silhouette factors, and the landmarks whose first frames have become enough for their
    initial fit (at the current pose estimates; ``pose_noise_refit``: :func:`_initial_fit`)."""

    def __init__(self, problem, options, result, pose_noise_refit=True):
        self.problem, self.options, self.result = problem, options, result
        self.pose_noise_refit = pose_noise_refit
        self.noise = _noise(options)
        self.by_frame = {}
        for oid, frames in problem.frames.items():
            for f in frames:
                self.by_frame.setdefault(f, []).append(oid)
        self.pending, self.added, self.failed, self.current = {}, [], set(), {}
        self.bounded = set()  # landmarks whose silhouette factors are bounded (_landmark_fit)
        self.batch, self.rays = SilhouetteFactors(), {}

    def add(self, frames):
        """``(graph, values)`` of the new factors and variables for ``frames`` (the next frames)."""
        problem, odo = self.problem, self.problem.odometry_poses
        graph, values = _pose_factors(problem, self.noise, frames), gtsam.Values()
        for i in frames:
            T = odo[0] if i == 0 else self.current[i - 1] @ np.linalg.inv(odo[i - 1]) @ odo[i]
            values.insert(X(i), gtsam.Pose3(T))
            self.current[i] = T
            for oid in self.by_frame.get(i, []):
                self._observe(graph, values, i, oid)
        return graph, values

    def _observe(self, graph, values, i, oid):
        if oid in self.failed:
            return
        if oid in self.added:
            graph.add(_silhouette(self.problem, i, oid, self.options, self.batch, self.rays, oid in self.bounded))
            return
        frames = self.pending.setdefault(oid, [])
        frames.append(i)
        last = i == self.problem.n_frames - 1
        if not (ready_to_initialise(self.problem, oid, frames, self.current, self.options) or (last and len(frames) >= 2)):
            return
        landmark, message, mismatched = _initial_fit(self.problem, oid, frames, self.current, self.options,
                                                     self.pose_noise_refit)
        if landmark is None:
            _skip(self.result, oid, message)
            self.failed.add(oid)
            return
        if mismatched:
            self.bounded.add(oid)
        _add_landmark(graph, values, self.problem, oid, frames, landmark, self.options, self.batch, self.rays,
                      mismatched)
        self.added.append(oid)

    def update(self, estimate, n):
        """Take the estimate of frames ``0 .. n-1``."""
        for f in range(n):
            self.current[f] = estimate.atPose3(X(f)).matrix()

    def finish(self):
        for oid in self.problem.frames:
            if oid not in self.added and oid not in self.result.skipped:
                _skip(self.result, oid, f"seen in {len(self.pending.get(oid, []))} frames, too few to initialise")


def _batch(problem, options):
    """Levenberg-Marquardt over growing windows of ``batch_window`` frames, each solve started from
    the previous one's solution, to ``window_relative_tolerance``; the windows before the last solve
    with the past held fixed (``batch_free_frames``, :func:`_window_solve`), the last one the whole
    graph. Then the re-fit of landmarks in poor minima (:func:`_refit`) and one solve of the whole
    graph to ``final_relative_tolerance`` (GraphOptions)."""
    clock, n = _Clock(), problem.n_frames
    result = SlamResult("graph", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings))
    growth = _Growth(problem, options, result, options.batch_pose_noise_refit)
    graph, values, by_key = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
    window = options.batch_window or n
    try:
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
        _refit(problem, values, growth.added, options, result, growth.rays, bounded=growth.bounded)
        final = replace(options, relative_tolerance=options.final_relative_tolerance)
        for check in (False, True):
            # the last solve moves far along the scale valley: a landmark it drops into 3G's far,
            # huge minimum is re-fitted (overlap test only) and the graph solved once more
            if check and not _refit(problem, values, growth.added, options, result, growth.rays, overlap_only=True,
                                    bounded=growth.bounded):
                break
            if options.rescale:
                values = _rescale(graph, values, n, growth.added, growth.batch)
            result.error_initial = graph.error(values)
            values, iterations = _lm(graph, values, final, options.final_max_lambda)
            result.iterations += iterations
    except _SOLVER_ERRORS as exc:
        result.fail("Levenberg-Marquardt", exc)
    else:
        growth.finish()
        result.error_final = graph.error(values)
        result.poses, result.objects = _poses(values, n), _objects(values, growth.added)
        result.outline_offsets = _offsets(values, growth.added, options)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


def _rescale(graph, values, n, oids, batch):
    """``values`` moved along the scale direction to the best scale about frame 0's camera
    (:mod:`sqfit.graph.scale`; the silhouette factors, those ``batch`` (a
    :class:`~sqfit.graph.factors.SilhouetteFactors`) holds, do not change with it)."""
    centre = values.atPose3(X(0)).translation()
    keys = ([X(i) for i in range(n)], [L(oid) for oid in oids], [S(oid) for oid in oids])
    changing = scale_dependent_factors(graph, batch.holds)
    return rescaled(values, centre, best_scale(changing, values, centre, *keys), *keys)


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
               for key in _landmark_keys(oid, options)}
    touching = sorted({k for key in active for k in by_key.get(key, ())})
    sub_graph, sub_values = condition_on_past([graph.at(k) for k in touching], values, active,
                                              options.batch_past_views)
    out, iterations = _lm(sub_graph, sub_values, coarse)
    values.update(out)
    return iterations


def _object_misfits(problem, values, oids, options, rays_cache=None, bounded=frozenset(), n=None):
    """RMS whitened ray residual of each object's silhouette factors at ``values`` (1: a typical ray
    one ``silhouette_sigma`` off), ``{oid: float}``; the factors of all ``oids`` evaluated together
    (those of the landmarks in ``bounded`` bounded, as in the graph), in frames ``0 .. n-1`` (all
    with None)."""
    batch, factors = SilhouetteFactors(), {}
    for oid in oids:
        factors[oid] = [_silhouette(problem, f, oid, options, batch, rays_cache, oid in bounded)
                        for f in _frames_before(problem, oid, n)]
    return {oid: float(np.sqrt(2.0 * sum(factor.error(values) for factor in fs) / (len(fs) * options.n_contour)))
            for oid, fs in factors.items()}


def _frames_before(problem, oid, n):
    """The frames of object ``oid`` before frame ``n`` (all with None)."""
    return [f for f in problem.frames[oid] if n is None or f < n]


def _observation_set(problem, oid, poses, frames):
    """Object ``oid``'s observations in ``frames`` at ``poses``, as one
    :class:`sqfit.fitting.costs.ObservationSet` (its caches shared by the overlap tests and the fit)."""
    from ..fitting.costs import ObservationSet

    return ObservationSet([observation_at(problem.observations[f, oid], poses[f]) for f in frames])


def _overlap(values, oid, obs):
    """R-IOU-M of object ``oid``'s landmark at ``values`` against ``obs`` (an ObservationSet): how
    much its silhouettes overlap its masks (``sqfit.fitting.stages.r_iou_m``; 3G's "far, huge"
    minimum has a low misfit but almost no overlap)."""
    sq = landmark_to_superquadric(values.atPose3(L(oid)).matrix(), values.atVector(S(oid)))
    return float(r_iou_m([sq], obs)[0])


def _refit(problem, values, oids, options, result, rays_cache=None, overlap_only=False, bounded=frozenset(), n=None,
           pose_noise_refit=None):
    """Re-initialise the landmarks left in a poor minimum by :func:`sqfit.fit` on all their frames at
    the solved poses: those whose silhouettes disagree (misfit above ``refit_misfit``; a refit is
    kept if its misfit is lower) and those whose silhouettes barely overlap their masks (R-IOU-M
    below ``sqfit.constants.POOR_FIT_R_IOU_M``, 3G's "far, huge" minimum, whose misfit is low; a
    refit is kept if it overlaps more). The overlap and the fit use at most ``refit_max_frames`` of
    the landmark's frames (:func:`sqfit.graph.fixedlag.evenly_spread`). ``overlap_only``: only the second kind. Returns whether
    a landmark changed. ``rays_cache``: :func:`_silhouette`; ``bounded``: the landmarks whose
    silhouette factors are bounded (their misfits measured so, :func:`_object_misfits`). ``n``: only
    frames ``0 .. n-1`` are in ``values`` (iSAM2, mid-sequence; None: all). ``pose_noise_refit``:
    :func:`_landmark_fit`'s (None: ``batch_pose_noise_refit``)."""
    if options.refit_misfit <= 0:
        return False
    poses = _poses(values, problem.n_frames if n is None else n)
    if pose_noise_refit is None:
        pose_noise_refit = options.batch_pose_noise_refit
    misfits = {} if overlap_only else _object_misfits(problem, values, oids, options, rays_cache, bounded, n)
    changed = False
    for oid in oids:
        frames = evenly_spread(_frames_before(problem, oid, n), options.refit_max_frames)
        obs = _observation_set(problem, oid, poses, frames)
        overlap = _overlap(values, oid, obs)
        disjoint = overlap < C.POOR_FIT_R_IOU_M
        if overlap_only and not disjoint:
            continue
        if oid not in misfits:
            misfits.update(_object_misfits(problem, values, [oid], options, rays_cache, bounded, n))
        before = misfits[oid]
        if before <= options.refit_misfit and not disjoint:
            continue
        landmark, _, _ = _landmark_fit(obs, options, pose_noise_refit, f"frames {list(frames)}")
        if landmark is None:
            continue
        trial = gtsam.Values(values)
        trial.update(L(oid), gtsam.Pose3(landmark[0]))
        trial.update(S(oid), np.asarray(landmark[1], dtype=np.float64))
        after = _object_misfits(problem, trial, [oid], options, rays_cache, bounded, n)[oid]
        overlap_after = _overlap(trial, oid, obs)
        if (overlap_after > overlap) if disjoint else (after < before):
            values.update(L(oid), gtsam.Pose3(landmark[0]))
            values.update(S(oid), np.asarray(landmark[1], dtype=np.float64))
            result.warnings.append(f"object {oid}: re-initialised from {len(frames)} of its {len(problem.frames[oid])} frames "
                                   f"{'' if n is None else f'(at frame {n}) '}"
                                   f"(misfit {before:.2f} -> {after:.2f}, R-IOU-M {overlap:.2f} -> "
                                   f"{overlap_after:.2f})")
            changed = True
    return changed


def _isam2(problem, options):
    clock, n = _Clock(), problem.n_frames
    result = SlamResult("graph-isam2", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings), frame_seconds=np.zeros(n), frame_cpu_seconds=np.zeros(n))
    params = gtsam.ISAM2Params()
    if options.isam2_dogleg:
        params.setOptimizationParams(gtsam.ISAM2DoglegParams())
    params.setRelinearizeThreshold(options.isam2_relinearize_threshold)
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    growth = _Growth(problem, options, result)
    every = options.isam2_rescale_every
    for i in range(n):
        step = _Clock()
        try:
            isam.update(*growth.add([i]))
            estimate = isam.calculateEstimate()
            if every and (i + 1) % every == 0 and growth.added:
                isam, estimate = _isam2_rescaled(isam, estimate, params, i + 1, growth, options, result)
        except _SOLVER_ERRORS as exc:
            result.fail(f"iSAM2 update at frame {i}", exc)
            result.seconds, result.cpu_seconds = clock.elapsed()
            return result
        growth.update(estimate, i + 1)
        result.frame_seconds[i], result.frame_cpu_seconds[i] = step.elapsed()
    growth.finish()
    result.iterations = n
    result.error_final = isam.getFactorsUnsafe().error(estimate)
    result.poses, result.objects = _poses(estimate, n), _objects(estimate, sorted(growth.added))
    result.outline_offsets = _offsets(estimate, sorted(growth.added), options)
    result.seconds, result.cpu_seconds = clock.elapsed()
    return result


def _isam2_rescaled(isam, estimate, params, n, growth, options, result):
    """iSAM2 moved to the best scale (:func:`_rescale`): iSAM2 relinearises only variables whose
    update exceeds its threshold, one Gauss-Newton step per update, so the scale the first landmarks
    took from the first frames' odometry is never corrected by the later odometry (the whole map
    must move together). With ``isam2_refit``, the landmarks left in a poor minimum are re-fitted
    there as after the batch solve (:func:`_refit` on frames ``0 .. n-1``): in the two failed runs
    of the evaluation scenes, at frame 10 landmarks sat in 3G's far, huge minimum (R-IOU-M 0.00) or
    far off (misfit 7.7), and their silhouettes then pulled the trajectory away. A new
    iSAM2 on the same factors, linearised at the result; the old one is kept when nothing moved."""
    graph = isam.getFactorsUnsafe()
    moved = _rescale(graph, estimate, n, growth.added, growth.batch)
    refitted = options.isam2_refit and _refit(growth.problem, moved, growth.added, options, result, growth.rays,
                                              bounded=growth.bounded, n=n, pose_noise_refit=growth.pose_noise_refit)
    if not refitted and abs(moved.atPose3(X(n - 1)).translation() - estimate.atPose3(X(n - 1)).translation()).max() < 1e-6:
        return isam, estimate
    fresh = gtsam.ISAM2(params)
    fresh.update(graph, moved)
    return fresh, fresh.calculateEstimate()


def quadric_graph(intrinsics, odometry_poses, observations, options=None):
    """Baseline: QuadricSLAM's dual quadrics from boxes in the same graph, batch Levenberg-Marquardt."""
    clock, options = _Clock(), GraphOptions.coerce(options)
    problem = check_inputs(intrinsics, odometry_poses, observations)
    result = SlamResult("quadric", problem.odometry_poses.copy(), skipped=dict(problem.skipped),
                        warnings=list(problem.warnings))
    noise, K = _noise(options), intrinsics.K
    graph = _pose_factors(problem, noise, range(problem.n_frames))
    values = gtsam.Values()
    for i, T in enumerate(problem.odometry_poses):
        values.insert(X(i), gtsam.Pose3(T))
    added = []
    for oid, frames in problem.frames.items():
        frames = [f for f in frames if not problem.observations[f, oid].touches_border]
        boxes = [observation_box(problem.observations[f, oid]) for f in frames]
        Z, radii = initialise_quadric(problem.odometry_poses[frames], K, boxes)
        if Z is None:
            _skip(result, oid, f"no quadric from the boxes of {len(frames)} untruncated frames")
            continue
        values.insert(L(oid), gtsam.Pose3(Z))
        values.insert(Q(oid), radii)
        for f, box in zip(frames, boxes):
            graph.add(box_factor(_robust(4, options.box_sigma_px, options.huber_k), X(f), L(oid), Q(oid), K, box))
        added.append(oid)
    try:
        result.error_initial = graph.error(values)
        out, result.iterations = _lm(graph, values, options)
    except _SOLVER_ERRORS as exc:
        result.fail("Levenberg-Marquardt", exc)
    else:
        result.error_final = graph.error(out)
        result.poses = _poses(out, problem.n_frames)
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
