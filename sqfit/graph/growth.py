"""Building the superquadric graph (:mod:`sqfit.graph.solve`) as frames arrive: its noise models,
the pose factors, each landmark's initial fit and variables, and one silhouette factor per (frame,
object); :class:`Growth` adds them frame by frame for the batch windows and for iSAM2.

A landmark is initialised by :func:`sqfit.fit` (``GraphOptions.init_chain``) from the first frames
that see it, at the current pose estimates, once they are enough (:func:`sqfit.graph.problem.
ready_to_initialise`). An initial fit whose silhouettes barely overlap its own masks (R-IOU-M below
``GraphOptions.init_min_overlap``: 3G's "far, huge" minimum, a superquadric whose surface passes
through the cameras) is not put in the graph: the landmark waits for its next frame and is fitted
again until a fit is no longer poor (R-IOU-M ``sqfit.constants.POOR_FIT_R_IOU_M`` or more: a fit
between the two pulls the poses where a far, huge one barely acts), at most
``GraphOptions.init_retries`` times, and then (or at its last frame) starts from the best-overlapping
of its fits (:meth:`Growth.add`). A landmark whose best fit after those retries is still far, huge
(below ``init_min_overlap``) is not put in the graph either: it is fitted again each time its frames
have doubled, and at its last frame starts from the best of its fits. (Household sequence seed 0,
sequence 2: an object started at R-IOU-M 0.02 after five retries, and its misfit was 22 at the next
rebuild.)
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import NamedTuple

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, O, S, X

from .. import constants as C
from ..fitting import pipeline
from ..fitting.grazing import OFFSET_UNIT_PX
from .factors import SilhouetteFactors, bounds_factor, floor_factor, silhouette_factor, with_floor_factors
from .landmark import camera_rays, left_grazing, superquadric_to_landmark
from .parallax import ready_to_initialise
from .problem import observation_at
from .shapevar import shape_variable

__all__ = ["LandmarkFit", "Growth", "noise_models", "robust_noise", "pose_factors", "pose_matrices", "skip_object",
           "with_first_pose_prior", "initial_fit", "landmark_fit", "add_landmark", "shape_prior", "view_factor",
           "silhouette_noise", "offset_key", "landmark_keys"]


class LandmarkFit(NamedTuple):
    """A landmark's fit (:func:`landmark_fit`)."""

    #: ``(T_world_sq (4, 4), shape (5,))``, or None when the fit failed
    landmark: tuple | None
    #: why it failed ("" when it did not)
    message: str
    #: the fit had to leave the grazing cost (:func:`sqfit.graph.landmark.left_grazing`)
    mismatched: bool
    #: its R-IOU-M on the observations it was fitted to (0 when it failed)
    overlap: float


def noise_models(options):
    """``{"odometry", "prior", "final_prior"}``: the diagonal noise models of the odometry steps, of
    frame 0's prior and of frame 0's prior in the batch's last solves (``final_prior_sigma_*``)."""
    rot, pos = np.radians(options.odometry_sigma_deg), options.odometry_sigma_m
    prot, ppos = np.radians(options.prior_sigma_deg), options.prior_sigma_m
    frot = prot if options.final_prior_sigma_deg is None else np.radians(options.final_prior_sigma_deg)
    fpos = ppos if options.final_prior_sigma_m is None else options.final_prior_sigma_m
    return {
        "odometry": gtsam.noiseModel.Diagonal.Sigmas(np.array([rot] * 3 + [pos] * 3)),
        "prior": gtsam.noiseModel.Diagonal.Sigmas(np.array([prot] * 3 + [ppos] * 3)),
        "final_prior": gtsam.noiseModel.Diagonal.Sigmas(np.array([frot] * 3 + [fpos] * 3)),
    }


def robust_noise(dim, sigma, k):
    """Huber on the factor's whitened norm; ``sigma`` and ``k`` per row (a factor of ``dim`` inlier
    rows has a whitened norm of about ``sqrt(dim)``, so the threshold is ``k sqrt(dim)``). Noise
    models are immutable, so factors with the same three numbers share one (the graph makes one
    per view of every frame, and the same few over and over)."""
    return _robust_noise(int(dim), float(sigma), float(k))


@lru_cache(maxsize=1024)
def _robust_noise(dim, sigma, k):
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k * np.sqrt(dim)),
                                          gtsam.noiseModel.Isotropic.Sigma(dim, sigma))


def pose_factors(problem, noise, frames):
    """Prior on frame 0 and odometry between consecutive frames, for ``frames``."""
    graph, poses = gtsam.NonlinearFactorGraph(), problem.odometry_poses
    for i in frames:
        if i == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(poses[0]), noise["prior"]))
        else:
            delta = gtsam.Pose3(np.linalg.inv(poses[i - 1]) @ poses[i])
            graph.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), delta, noise["odometry"]))
    return graph


def with_first_pose_prior(graph, pose, noise):
    """A copy of ``graph`` whose prior on frame 0's pose (the ``PriorFactorPose3`` on ``X(0)``) is
    replaced by one at ``pose`` ((4, 4)) with ``noise``; the other factors are shared."""
    drop = {k for k in range(graph.size())
            if isinstance(graph.at(k), gtsam.PriorFactorPose3) and tuple(graph.at(k).keys()) == (X(0),)}
    out = _without(graph, drop)
    out.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(pose), noise))
    return out


def pose_matrices(values, n):
    """The poses ``X(0) .. X(n-1)`` of ``values`` as ``(n, 4, 4)``."""
    return np.stack([values.atPose3(X(i)).matrix() for i in range(n)])


def skip_object(result, oid, reason):
    """Record in ``result`` that object ``oid`` has no landmark, and why."""
    result.skipped[oid] = reason
    result.warnings.append(f"object {oid}: skipped, {reason}")


def initial_fit(problem, oid, frames, poses, options, pose_noise_refit=True):
    """:func:`sqfit.fit` of object ``oid`` on ``frames`` at ``poses`` (frame -> (4, 4)): :func:`landmark_fit`."""
    obs = [observation_at(problem.observations[f, oid], poses[f]) for f in frames]
    return landmark_fit(obs, options, pose_noise_refit, f"frames {list(frames)}")


def landmark_fit(obs, options, pose_noise_refit, where, n_contour=None):
    """:func:`sqfit.fit` (chain ``init_chain``) on ``obs`` (observations, or an ObservationSet), as
    a :class:`LandmarkFit`: the landmark ``(T, shape)`` or None and the failure message (naming
    ``where``), whether the fit had to leave the grazing cost
    (:func:`sqfit.graph.landmark.left_grazing`: its silhouette factors are then bounded,
    ``GraphOptions.mismatch_ray_k``) and its R-IOU-M on ``obs``. ``pose_noise_refit``: the fit's
    option of that name; ``n_contour``: its outline rays per view (None: ``fit_n_contour``, the
    first fits'; the re-fits pass theirs, :attr:`Growth.refit_n_contour`). Without 3H's plain 3G
    where its nuisances are idle (``FitOptions.idle_nuisances_plain``): on the issue-23 evaluation
    sequences (seeds 0-3, 3 runs each; measured before its cost condition) it moved all 72 batch
    runs without improving them (ATE median 0.0052 against 0.0053 m, the largest 0.0120 against
    0.0098 m, the largest spreads 0.0038 m / 0.016 against 0.0015 m / 0.007, CPU x1.014)."""
    rays = options.fit_n_contour if n_contour is None else n_contour
    res = pipeline.fit(obs, options.init_chain, options={"pose_noise_refit": bool(pose_noise_refit), "score_stages": False,
                                                         "n_contour": rays, "idle_nuisances_plain": False})
    if not res.ok or res.superquadric is None:
        return LandmarkFit(None, f"initial fit on {where} failed: {res.status}: {res.message}", False, 0.0)
    return LandmarkFit(superquadric_to_landmark(res.superquadric), "", left_grazing(res), float(res.r_iou_m))


def add_landmark(graph, values, problem, oid, frames, landmark, options, batch, rays_cache=None, mismatched=False,
                 scale=1.0):
    """Landmark ``oid``'s variables at ``landmark`` ``(T, shape)``, its priors and its silhouette factors in
    ``frames``; ``mismatched``: its initial fit left the grazing cost (:func:`landmark_fit`): its rays
    are bounded and it gets no floor factor (a table fitted as its top need not touch the floor);
    ``scale``: its silhouette noise scale (:func:`view_factor`)."""
    T, shape = landmark
    variable = shape_variable(options)
    values.insert(L(oid), gtsam.Pose3(T))
    values.insert(S(oid), variable.value(shape))
    graph.add(bounds_factor(S(oid), options.bounds_weight, variable))
    # Weak priors at the initial fit: the rotation of a shape with a symmetry axis (and e.g. e1 of a
    # shape seen only side-on) is not observed, which iSAM2's undamped Gauss-Newton cannot solve.
    rot, pos = np.radians(options.landmark_prior_sigma_deg), options.landmark_prior_sigma_m
    graph.add(gtsam.PriorFactorPose3(L(oid), gtsam.Pose3(T), gtsam.noiseModel.Diagonal.Sigmas(np.array([rot] * 3 + [pos] * 3))))
    graph.add(shape_prior(oid, shape, options.shape_prior_sigma, variable))
    if options.floor_z is not None and not mismatched:
        graph.add(floor_factor(robust_noise(1, options.floor_sigma_m, options.huber_k), L(oid), S(oid), options.floor_z,
                               variable))
    offset = offset_key(oid, options)
    if offset is not None:  # the masks' outline offset, px / OFFSET_UNIT_PX, prior at 0
        values.insert(offset, np.zeros(1))
        graph.add(gtsam.PriorFactorVector(offset, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(
            1, options.outline_offset_sigma_px / OFFSET_UNIT_PX)))
    for f in frames:
        graph.add(view_factor(problem, f, oid, options, batch, rays_cache, mismatched, scale))


def shape_prior(oid, shape, sigma, variable):
    """A prior on landmark ``oid``'s size/shape at ``shape`` of ``sigma`` (units of ``shape``) per
    entry; ``variable``: the graph's :class:`sqfit.graph.shapevar.ShapeVariable` (the prior is on
    the variable, of the same sigma to first order)."""
    shape = np.asarray(shape, dtype=np.float64)
    noise = (gtsam.noiseModel.Isotropic.Sigma(len(shape), sigma) if variable.plain
             else gtsam.noiseModel.Diagonal.Sigmas(variable.prior_sigmas(shape, sigma)))
    return gtsam.PriorFactorVector(S(oid), variable.value(shape), noise)


def view_factor(problem, frame, oid, options, batch, rays_cache=None, bounded=False, scale=1.0):
    """The silhouette factor of ``(frame, oid)``, evaluated with the graph's other ones by ``batch``
    (a :class:`sqfit.graph.factors.SilhouetteFactors`); ``rays_cache`` (a dict) keeps the rays of
    the factors made so far, for the re-fit's factors of the same views. ``bounded``: each ray's
    whitened residual bounded by ``mismatch_ray_k`` (a landmark whose outline one superquadric
    cannot graze, :func:`landmark_fit`). ``scale``: its noise model's :func:`silhouette_noise`
    scale (the landmark's, :mod:`sqfit.graph.weighting`); the ray bound stays at the unscaled sigma."""
    rays = None if rays_cache is None else rays_cache.get((frame, oid))
    if rays is None:
        rays = camera_rays(problem.observations[frame, oid], options.n_contour)
        if rays_cache is not None:
            rays_cache[frame, oid] = rays
    bound = options.mismatch_ray_k * _row_sigma(options, len(rays)) if bounded and options.mismatch_ray_k > 0 else np.inf
    return silhouette_factor(silhouette_noise(options, len(rays), scale), X(frame), L(oid),
                             S(oid), rays, batch, offset_key(oid, options), OFFSET_UNIT_PX, bound)


def _row_sigma(options, n_rays):
    """The standard deviation of one weighted ray row: the ray residuals carry contour_rays'
    weights ``1 / sqrt(n)``."""
    return options.silhouette_sigma / np.sqrt(n_rays)


def silhouette_noise(options, n_rays, scale=1.0):
    """The robust noise model of a silhouette factor of ``n_rays`` rays, its sigma ``scale`` times
    ``silhouette_sigma``."""
    return robust_noise(n_rays, scale * _row_sigma(options, n_rays), options.huber_k)


def offset_key(oid, options):
    """Key of landmark ``oid``'s outline offset, or None when the graph does not estimate offsets."""
    return O(oid) if options.outline_offset_sigma_px > 0 else None


def landmark_keys(oid, options):
    """The keys of landmark ``oid``'s variables: pose, size/shape and, if estimated, outline offset."""
    offset = offset_key(oid, options)
    return (L(oid), S(oid)) + (() if offset is None else (offset,))


def _without(graph, drop):
    """A new graph of ``graph``'s factors but those at the positions ``drop``."""
    out = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        if k not in drop:
            out.add(graph.at(k))
    return out


class Growth:
    """Grows the graph frame by frame (shared by the batch windows and iSAM2): each new frame's pose,
    chained from the current estimate of the previous one by the odometry step, its odometry factor,
    its silhouette factors, and the landmarks whose first frames have become enough for their
    initial fit (at the current pose estimates; ``pose_noise_refit``: :func:`initial_fit`), or whose
    deferred initial fit (module docstring) is tried again. ``scales``: ``{oid: scale}`` of the
    landmarks whose silhouette noise is scaled (:mod:`sqfit.graph.weighting`), 1 where absent.
    ``refit_n_contour``: the outline rays per view of its landmarks' re-fits
    (:func:`sqfit.graph.refit.refit_landmarks`; None: ``fit_n_contour``, the ``graph-isam2``
    method's; the batch passes ``batch_refit_n_contour``)."""

    def __init__(self, problem, options, result, pose_noise_refit=True, scales=None, refit_n_contour=None):
        self.problem, self.options, self.result = problem, options, result
        self.pose_noise_refit = pose_noise_refit
        self.refit_n_contour = options.fit_n_contour if refit_n_contour is None else int(refit_n_contour)
        self.noise = noise_models(options)
        self.by_frame = {}
        for oid, frames in problem.frames.items():
            for f in frames:
                self.by_frame.setdefault(f, []).append(oid)
        self.pending, self.added, self.failed, self.current = {}, [], set(), {}
        self.bounded = set()  # landmarks whose silhouette factors are bounded (landmark_fit; until refitted)
        # landmarks whose last re-fit was not kept: (misfit, frames) then (sqfit.graph.refit)
        self.rejected = {}
        # landmarks whose initial fit was put off (module docstring): how often, and the best fit so far
        self.tries, self.deferred = {}, {}
        # landmarks past their retries whose best fit is still far, huge: the frame count of their next try
        self.next_try = {}
        self.batch, self.rays = SilhouetteFactors(shape_variable(options)), {}
        # each landmark's silhouette noise scale, where not 1 (sqfit.graph.weighting)
        self.scales = {oid: float(v) for oid, v in (scales or {}).items() if v != 1.0}
        # damping priors on new landmarks' size/shape (iSAM2 only): sigma (0: none), their factor
        # indices in iSAM2 by landmark, and the positions in the graph add() returned last
        self.damping_sigma, self.damping, self._damping_new = 0.0, {}, []

    def add(self, frames):
        """``(graph, values)`` of the new factors and variables for ``frames`` (the next frames)."""
        problem, odo = self.problem, self.problem.odometry_poses
        graph, values = pose_factors(problem, self.noise, frames), gtsam.Values()
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
            graph.add(view_factor(self.problem, i, oid, self.options, self.batch, self.rays, oid in self.bounded,
                                  self.scales.get(oid, 1.0)))
            return
        frames = self.pending.setdefault(oid, [])
        frames.append(i)
        last = i == self.problem.n_frames - 1
        final = last or i == self.problem.frames[oid][-1]
        if not (ready_to_initialise(self.problem, oid, frames, self.current, self.options) or (last and len(frames) >= 2)):
            return
        if len(frames) < self.next_try.get(oid, 0) and not final:
            return  # its retries spent in the far, huge minimum: fitted again once its frames have doubled
        fit = initial_fit(self.problem, oid, frames, self.current, self.options, self.pose_noise_refit)
        earlier = self.deferred.get(oid)
        # a landmark put off once waits until a fit is no longer poor (the fitter's own flag)
        wanted = C.POOR_FIT_R_IOU_M if oid in self.tries else self.options.init_min_overlap
        if fit.landmark is not None and fit.overlap < wanted and not final:
            tries, retries = self.tries.get(oid, 0), self.options.init_retries
            best = max(fit.overlap, -1.0 if earlier is None else earlier.overlap)
            # 3G's far, huge minimum (module docstring): wait for the next frame; once the retries
            # are spent, a landmark whose best fit is still that far, huge one waits on
            if tries < retries or (retries > 0 and best < self.options.init_min_overlap):
                self.tries[oid] = tries + 1
                if earlier is None or fit.overlap > earlier.overlap:
                    self.deferred[oid] = fit
                if tries >= retries:
                    self.next_try[oid] = 2 * len(frames)
                return
        if earlier is not None and (fit.landmark is None or earlier.overlap > fit.overlap):
            fit = earlier
        if fit.landmark is None:
            skip_object(self.result, oid, fit.message)
            self.failed.add(oid)
            return
        if oid in self.tries:
            self.result.warnings.append(
                f"object {oid}: initial fit deferred {self.tries[oid]} time(s) (first R-IOU-M below "
                f"{self.options.init_min_overlap}, 3G's far, huge minimum; then waiting for "
                f"{C.POOR_FIT_R_IOU_M}), started at R-IOU-M {fit.overlap:.2f} from {len(frames)} frames")
        if fit.mismatched:
            self.bounded.add(oid)
        add_landmark(graph, values, self.problem, oid, frames, fit.landmark, self.options, self.batch, self.rays,
                     fit.mismatched, self.scales.get(oid, 1.0))
        if self.damping_sigma > 0:
            graph.add(shape_prior(oid, fit.landmark[1], self.damping_sigma, self.batch.variable))
            self._damping_new.append((graph.size() - 1, oid))
        self.added.append(oid)

    def placed(self, update):
        """Take from iSAM2's ``update`` (the ``ISAM2Result`` of the factors add() returned last) the
        indices of the damping priors among them; asks iSAM2 for its indices only when there are."""
        if not self._damping_new:
            return
        indices = update.getNewFactorsIndices()
        for position, oid in self._damping_new:
            self.damping[oid] = int(indices[position])
        self._damping_new = []

    def undamped(self, graph):
        """``graph`` (iSAM2's factors) without the damping priors still in it."""
        if not self.damping:
            return graph
        return _without(graph, set(self.damping.values()))

    def undamped_new(self, graph):
        """``graph`` (the last one add() returned) without its damping priors, which are forgotten:
        iSAM2 is started again without them (:mod:`sqfit.graph.solve`)."""
        drop = {position for position, _ in self._damping_new}
        self._damping_new = []
        return _without(graph, drop)

    def refitted(self, graph, fits):
        """``graph`` with the bounded landmarks that a re-fit found grazing their outline treated as
        :func:`add_landmark` treats a landmark whose initial fit grazes: ``fits`` is
        :func:`sqfit.graph.refit.refit_landmarks`'s ``{oid: whether the re-fit left the grazing
        cost}``; a bounded landmark (its initial fit left it) re-fitted by one that did not is
        unbounded (its silhouette factors' rays, in place:
        :meth:`sqfit.graph.factors.SilhouetteFactors.unbound`) and, with a floor, gets its floor
        factor. Returns a new graph where one was added, else ``graph``.

        Before, such a landmark stayed bounded and without its floor for the rest of the run
        (``scenes/sequence.toml``, 160 frames, seed 3: object 6's initial fit on 12 frames left the
        grazing cost at R-IOU-M 0.36 in two runs of three, its re-fit at frame 27 grazed at 0.86;
        those two runs ended at 0.0128 m, 0.0099 m with this). The other way, bounding a landmark
        whose re-fit left the grazing cost, is not done: on the household sequences it changed 43
        of 60 runs and lowered their pooled object IoU from 0.485 to 0.437 (docs/slam-history.md,
        sixteenth pass)."""
        grazing = [oid for oid, left in fits.items() if not left and oid in self.bounded]
        for oid in grazing:
            self.bounded.discard(oid)
            self.batch.unbound(L(oid))
        if not grazing or self.options.floor_z is None:
            return graph
        # a bounded landmark has no floor factor (add_landmark): each gets add_landmark's
        return with_floor_factors(graph, grazing, robust_noise(1, self.options.floor_sigma_m, self.options.huber_k),
                                  self.options.floor_z, self.batch.variable)

    def resampled(self, graph, n_contour, first_view_scale=1.0):
        """``(graph', evaluator)``: ``graph`` with the silhouette factors of this growth's evaluator
        made again by a new :class:`SilhouetteFactors`, which it returns, those of the landmarks
        that fit their masks with ``n_contour`` rays (``GraphOptions.final_n_contour``) and, in
        frame 0, their noise scaled by ``first_view_scale``
        (``GraphOptions.final_first_view_sigma_scale``), the others as they were; the other factors
        are shared. A landmark fits unless its silhouette factors are bounded (its initial fit left
        the grazing cost) or its noise is scaled by its misfit (:mod:`sqfit.graph.weighting`): there
        the outline's misfit is the model's, not noise, and denser rays or more weight would only
        weigh the wrong outline more."""
        dense = replace(self.options, n_contour=int(n_contour))
        batch, rays, out = SilhouetteFactors(self.batch.variable), {}, gtsam.NonlinearFactorGraph()
        for k in range(graph.size()):
            factor = graph.at(k)
            if not self.batch.holds(factor):
                out.add(factor)
                continue
            keys = factor.keys()
            frame, oid = gtsam.Symbol(keys[0]).index(), gtsam.Symbol(keys[1]).index()
            scale = self.scales.get(oid, 1.0)
            fits = oid not in self.bounded and scale == 1.0
            if fits and frame == 0:
                scale = float(first_view_scale)
            out.add(view_factor(self.problem, frame, oid, dense if fits else self.options, batch,
                                rays if fits else self.rays, oid in self.bounded, scale))
        return out, batch

    def floored(self):
        """The landmarks with a floor factor (:func:`add_landmark`: all but the bounded ones, when
        the graph has a floor)."""
        return [] if self.options.floor_z is None else [oid for oid in self.added if oid not in self.bounded]

    def update(self, estimate, n):
        """Take the estimate of frames ``0 .. n-1``."""
        for f in range(n):
            self.current[f] = estimate.atPose3(X(f)).matrix()

    def finish(self):
        """Record the objects never initialised (too few frames) as skipped."""
        for oid in self.problem.frames:
            if oid not in self.added and oid not in self.result.skipped:
                skip_object(self.result, oid, f"seen in {len(self.pending.get(oid, []))} frames, too few to initialise")
