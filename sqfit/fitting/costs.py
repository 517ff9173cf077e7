"""Cost functions of the fitter as residual vectors (paper, section III-C and III-D).

Residual conventions (all float64):

- ``xi`` is the ``(11,)`` parameter vector ``[ax, ay, az, e1, e2, px, py, pz, rx, ry, rz]``.
- :func:`penalty` (eq. 7): ``(11,)`` residuals ``c_p * rho_i``, one per state variable (``K`` is the
  state size in eq. 7); only ``a >= 0.1`` and ``0.1 <= e <= 1.9`` are ever non-zero. They are
  appended to every cost, so Levenberg-Marquardt always has at least as many residuals as
  unknowns (three views give 3 + 11 = 14 >= 11 for G2).
- G2 (:func:`riou_residuals`): ``(v + 11,)`` = ``1 - IoU`` per view between the projected
  superquadric (:mod:`sqfit.geometry.silhouette`) and the observation polygon, then the penalty with
  ``c_p = 1``. Minimising ``sum r**2`` is eq. 3 with the penalty of eq. 7 as extra residuals.
  In a view whose mask is cut by the image border (outline labels ``border``) the IoU counts
  only the part of the silhouette inside the image, and (hull polygons) pixels of other
  instances that may hide the object (``Observation.hidden``) count in neither intersection nor
  union (:mod:`sqfit.geometry.visible_iou`); the paper's masks are single objects that never touch the
  border, so the paper's chains are unchanged there.
  The paper differentiates it numerically; :func:`riou_residuals` also gives an analytic
  Jacobian for hull polygons (``jacobian=True``), which the stages use by default
  (``FitOptions.riou_jacobian``).
- G3 (:func:`radial_terms`): the radial distance (eq. 8) of back-projected samples, with its
  analytic Jacobian; G4 = G3 of samples at unknown depths (eq. 10-11); G5 = ``(ax ay az + 1) G4``
  (eq. 12). :func:`g5_residuals` returns ``(n + 11,)`` residuals (samples, then the penalty with
  ``c_p = 100``) and the Jacobian in block form: ``A`` ``(n, 11)`` with respect to ``xi`` and
  ``D`` ``(n,)``, the derivative of each sample's residual with respect to its own depth (the
  depth block of the Jacobian is diagonal: each residual depends on 11 + 1 unknowns).

G3 is differentiated in log space like :func:`sqfit.geometry.superquadric.log_implicit_unit`:
``G3 = S - |y|`` with ``S = exp(log|y| - e1/2 log F)`` the surface radius along the ray, finite
for ``e`` in ``[0.1, 1.9]`` and anywhere but the exact centre.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import constants as C
from ..kernels.backend import compiled
from .._checks import check_shape
from ..geometry.camera import Camera, world_bearings
from ..views.observation import Observation
from ..geometry.polygon import MIN_EDGE, batch_iou, convex_iou_jacobian, half_planes
from .contour_overlap import contour_ious
from ..geometry.silhouette import (DEFAULT_DIRECTIONS, E_RANGE, MAX_NEWTON, NEWTON_TOL, ZNEAR, batch_silhouettes,
                                   camera_arrays, silhouette_gradient)
from ..geometry.superquadric import euler_to_matrix, rotation_and_derivatives
from ..views.visibility import BORDER
from ..geometry.visible_iou import clipped_convex_iou_jacobian, hidden_counts, image_rectangles, points_in_convex

__all__ = ["ObservationSet", "penalty", "penalty_jacobian", "riou_residuals", "silhouettes", "visible_iou", "hidden_at",
           "radial_terms",
           "rotation_and_derivatives",
           "g5_residuals", "LOWER_BOUNDS", "UPPER_BOUNDS"]

#: Soft bounds of eq. 7 per parameter (``-inf`` / ``inf``: unconstrained).
LOWER_BOUNDS = np.array([C.SIZE_MIN] * 3 + [C.SHAPE_BOUNDS[0]] * 2 + [-np.inf] * 6)
UPPER_BOUNDS = np.array([np.inf] * 3 + [C.SHAPE_BOUNDS[1]] * 2 + [np.inf] * 6)
_TINY = 1e-300


@dataclass(eq=False)
class ObservationSet:
    """Observations of one object, with the arrays every cost needs computed once.

    Attributes
    ----------
    observations : list of Observation
    rotations : (v, 3, 3) float
        Camera -> world rotations.
    centers : (v, 3) float
        Camera centres, world frame.
    intrinsics : (v, 4) float
        ``fx, fy, cx, cy``.
    view_of_sample : (n,) int
        View index of each sample (samples of all views concatenated in order).
    rays : (n, 3) float
        World direction of each sample per unit depth: ``R_c @ [(u-cx)/fx, (v-cy)/fy, 1]``.
    origins : (n, 3) float
        Camera centre of each sample's view.
    border_views : (v,) bool
        Views whose outline has ``border`` labels (the R-IOU there counts only the image).
    frames : (v, 4, 2) float
        Image rectangle of each view (:func:`sqfit.geometry.visible_iou.image_rectangles`).
    frame_planes : tuple
        Their :func:`sqfit.geometry.polygon.half_planes`.
    occluded_views : (v,) bool
        Views with pixels that may hide the object (``Observation.hidden`` not empty).
    """

    observations: list
    rotations: np.ndarray = field(init=False)
    centers: np.ndarray = field(init=False)
    intrinsics: np.ndarray = field(init=False)
    view_of_sample: np.ndarray = field(init=False)
    rays: np.ndarray = field(init=False)
    origins: np.ndarray = field(init=False)
    border_views: np.ndarray = field(init=False)
    frames: np.ndarray = field(init=False)
    frame_planes: tuple = field(init=False)
    occluded_views: np.ndarray = field(init=False)

    def __post_init__(self):
        obs = list(self.observations)
        for i, o in enumerate(obs):
            if not isinstance(o, Observation):
                raise TypeError(f"observations[{i}] must be a sqfit.Observation, got {type(o).__name__}")
        self.observations = obs
        self.rotations, self.centers, self.intrinsics = camera_arrays([o.camera for o in obs])
        counts = [len(o.samples) for o in obs]
        self.view_of_sample = np.repeat(np.arange(len(obs)), counts)
        self.rays = np.concatenate([world_bearings(o.camera, o.samples) for o in obs])
        self.origins = self.centers[self.view_of_sample]
        self.border_views = np.array([bool(np.any(o.contour_labels == BORDER)) for o in obs], dtype=bool)
        self.frames = image_rectangles([(o.camera.intrinsics.width, o.camera.intrinsics.height) for o in obs])
        self.frame_planes = half_planes(self.frames)
        self.occluded_views = np.array([len(o.hidden) > 0 for o in obs], dtype=bool)
        self._targets = {}
        self._shapes = self._contour_arrays = None
        self._hidden_in_target = {}

    def __len__(self):
        return len(self.observations)

    def turned(self, corrections):
        """These observations with view ``v``'s camera -> world rotation turned to ``exp([w_v]x) R_v``
        about its centre, ``w_v`` row ``v`` of ``corrections`` ``(v, 3)`` (world-frame rotation vectors,
        radians: :attr:`sqfit.fitting.stages.FitState.camera_corrections`); the masks' caches are shared."""
        from scipy.spatial.transform import Rotation

        w = check_shape(corrections, (len(self), 3), "corrections")
        turns = Rotation.from_rotvec(w).as_matrix()
        moved = []
        for o, turn in zip(self.observations, turns):
            pose = np.array(o.camera.pose, dtype=np.float64)
            pose[:3, :3] = turn @ pose[:3, :3]
            moved.append(o.with_camera(Camera(o.camera.intrinsics, pose)))
        return ObservationSet(moved)

    def targets(self, kind):
        """Observation polygons for :func:`sqfit.geometry.polygon.batch_iou`: ``(targets, convex, planes)``.

        ``hull`` polygons are padded to a common length by repeating their last vertex.
        """
        if kind not in self._targets:
            if kind == "hull":
                polys = [_hull(o) for o in self.observations]
                m = max(len(p) for p in polys)
                padded = np.stack([np.vstack([p, np.repeat(p[-1:], m - len(p), axis=0)]) for p in polys])
                self._targets[kind] = (padded, True, half_planes(padded))
            else:
                self._targets[kind] = ([np.asarray(o.contour) for o in self.observations], False, None)
        return self._targets[kind]

    def contour_shapes(self):
        """Per view, the mask contour (the ``"contour"`` targets) as a valid shapely geometry
        (``shapely.make_valid``), ``(v,) object``: made once per mask, shared by every copy of its
        observation (``Observation.derived``), not per evaluation (a contour of a few hundred
        vertices costs about as much to make valid as to intersect with a silhouette)."""
        if self._shapes is None:
            import shapely

            def valid(o):
                return lambda: shapely.make_valid(shapely.Polygon(np.asarray(o.contour)))

            self._shapes = np.array([o.derived(("contour_shape",), valid(o)) for o in self.observations],
                                    dtype=object)
        return self._shapes

    def contour_arrays(self):
        """The mask contours for :func:`sqfit.kernels.silhouette_kernels.contour_overlaps`:
        ``(stacked, starts, simple, areas)``, the contours ``(M, 2)`` one after the other (view ``t``'s
        at ``starts[t]:starts[t + 1]``), whether each is a simple polygon (valid as it is: its own
        area is its valid geometry's) and each one's area (of :meth:`contour_shapes`)."""
        if self._contour_arrays is None:
            import shapely

            contours = [np.asarray(o.contour, dtype=np.float64) for o in self.observations]
            starts = np.concatenate([[0], np.cumsum([len(c) for c in contours])]).astype(np.int64)

            def is_simple(o):
                return lambda: bool(shapely.is_valid(shapely.Polygon(o.contour)))

            simple = np.array([o.derived(("contour_simple",), is_simple(o)) for o in self.observations], dtype=bool)
            self._contour_arrays = (np.ascontiguousarray(np.concatenate(contours)), starts, simple,
                                    shapely.area(self.contour_shapes()))
        return self._contour_arrays

    def hidden_in_target(self, kind):
        """Per view, ``(k,) bool``: which of ``Observation.hidden`` lie in the observation polygon."""
        if kind not in self._hidden_in_target:
            targets, convex, _ = self.targets(kind)
            kernels = compiled("silhouettes") if convex else None
            out = []
            for j, (o, target) in enumerate(zip(self.observations, targets)):
                if not len(o.hidden):
                    out.append(np.zeros(0, dtype=bool))
                elif kernels is not None:  # the same edge tests, compiled (bit for bit)
                    out.append(kernels.points_in_convex(np.ascontiguousarray(target, dtype=np.float64),
                                                        np.ascontiguousarray(o.hidden, dtype=np.float64)))
                elif convex:
                    out.append(points_in_convex(target, o.hidden))
                else:
                    import shapely

                    out.append(shapely.contains_xy(self.contour_shapes()[j], o.hidden[:, 0], o.hidden[:, 1]))
            self._hidden_in_target[kind] = out
        return self._hidden_in_target[kind]

    def partial_views(self, polys, polygon):
        """Views whose IoU counts only the visible part, for silhouettes ``polys`` ``(b, v, K, 2)``.

        Returns
        -------
        views : (p,) int
        clip : (p,) bool
            Clip the silhouette to the image (border views).
        hidden_inter, hidden_union : (b, p) float
            :func:`sqfit.geometry.visible_iou.hidden_counts` per view.
        """
        views = np.flatnonzero(self.border_views | self.occluded_views)
        kernels = compiled("silhouettes")
        count = hidden_counts if kernels is None else _compiled_hidden_counts(kernels)
        counts = [count(polys[:, j], self.observations[j].hidden, self.hidden_in_target(polygon)[j]) for j in views]
        hi = np.stack([c[0] for c in counts], axis=1) if counts else np.zeros((len(polys), 0))
        hu = np.stack([c[1] for c in counts], axis=1) if counts else np.zeros((len(polys), 0))
        return views, self.border_views[views], hi, hu


def _compiled_hidden_counts(kernels):
    """:func:`sqfit.geometry.visible_iou.hidden_counts` by the compiled kernel (same numbers)."""
    def count(S, points, in_q):
        if not len(points):
            return np.zeros(len(S)), np.zeros(len(S))
        return kernels.hidden_counts(np.ascontiguousarray(S, dtype=np.float64),
                                     np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(in_q))
    return count


def _hull(observation):
    """Convex hull of the samples, CCW: the same polygon as ``Observation.polygon("hull")`` (up to
    collinear points and the first vertex), by the compiled monotone chain
    (:func:`sqfit.kernels.silhouette_kernels.convex_hull`, ~5 us) or qhull (~0.1 ms; both ~50x faster
    than the pure-Python hull there); collinear samples fall back to that hull."""
    samples = np.ascontiguousarray(observation.samples, dtype=np.float64)
    kernels = compiled("silhouettes")
    if kernels is not None:
        index = kernels.convex_hull(samples) if len(samples) else np.zeros(0, dtype=np.int64)
        return samples[index] if len(index) >= 3 else np.asarray(observation.polygon("hull"))
    from scipy.spatial import ConvexHull, QhullError

    try:
        return samples[ConvexHull(samples).vertices]
    except (QhullError, ValueError):
        return np.asarray(observation.polygon("hull"))


def penalty(xi, weight, lower=LOWER_BOUNDS, upper=UPPER_BOUNDS):
    """Constraint penalty residuals of eq. 7.

    Parameters
    ----------
    xi : (11,) or (b, 11) float
    weight : float
        ``c_p``.
    lower, upper : (11,) float
        Soft bounds (default those of eq. 7; stage 3G allows flatter shapes, see
        ``constants.SILHOUETTE_SHAPE_BOUNDS``).

    Returns
    -------
    rho : (11,) or (b, 11) float
        ``c_p * (max(0, lo - x) + max(0, x - hi))`` per parameter.
    """
    xi = np.asarray(xi, dtype=np.float64)
    return weight * (np.maximum(lower - xi, 0.0) + np.maximum(xi - upper, 0.0))


def penalty_jacobian(xi, weight, lower=LOWER_BOUNDS, upper=UPPER_BOUNDS):
    """``(11,) float``: diagonal of the Jacobian of :func:`penalty` (``-c_p``, ``0`` or ``c_p``)."""
    xi = np.asarray(xi, dtype=np.float64)
    return weight * ((xi > upper).astype(float) - (xi < lower).astype(float))


def riou_residuals(xi, obs, polygon="hull", weight=C.PENALTY_RIOU, n_directions=DEFAULT_DIRECTIONS,
                   start=None, jacobian=False, tol=NEWTON_TOL, hidden=None):
    """G2 residuals for one or several parameter vectors.

    Parameters
    ----------
    xi : (b, 11) float
    obs : ObservationSet
    polygon : {"hull", "contour"}
        Observation polygon: convex hull of the samples (paper) or the mask contour.
    weight : float
        ``c_p`` of the penalty.
    n_directions : int
        Silhouette vertices (see :func:`sqfit.geometry.silhouette.batch_silhouettes`).
    start : SilhouetteStart, optional
        Warm start of the silhouette solve (the ``start`` returned for a nearby ``xi``, see
        :func:`sqfit.geometry.silhouette.batch_silhouettes`).
    jacobian : bool
        Also return the analytic derivative of the view residuals (``polygon="hull"`` only):
        :func:`sqfit.geometry.polygon.convex_iou_jacobian` (the IoU's gradient in the vertices) pulled
        back through :func:`sqfit.geometry.silhouette.silhouette_gradient` (the vertices' velocities, as
        :func:`sqfit.geometry.silhouette.vertex_velocities`). It is the derivative of the IoU of the
        silhouette polygon whose vertices move with the touching points. Finite differences of
        the residuals also see the vertices slide along the silhouette, an effect of the
        discretisation: they agree to a few percent at 48 vertices, except for the shape
        columns of pointed superquadrics (``e`` near 1.9, nearly every vertex on a corner),
        which can differ by a third there and agree as ``n_directions`` grows.
    tol : float
        Precision of the silhouette solve, pixels (see :func:`sqfit.geometry.silhouette.batch_silhouettes`).
    hidden : tuple, optional
        Hidden-pixel counts to use instead of counting (:func:`hidden_at` of a nearby point;
        not with ``jacobian``): finite-difference columns then see the counts constant, as the
        analytic Jacobian does, instead of a jump of a whole pixel over a tiny step.

    Returns
    -------
    r : (b, v + 11) float
        ``1 - IoU`` per view (1 where the silhouette does not exist), then the penalty.
    start : SilhouetteStart
        Silhouette directions and support values, to warm-start a nearby evaluation.
    d_views : callable
        Only if ``jacobian``: ``d_views()`` returns ``d (1 - IoU) / d xi`` per view,
        ``(b, v, 11) float`` (0 where the silhouette does not exist or does not overlap the
        observation: the R-IOU has no gradient there). Lazy: a rejected trial point never pays
        for it.
    """
    xi = np.atleast_2d(np.asarray(xi, dtype=np.float64))
    if not jacobian:
        polys, valid, start = batch_silhouettes(xi, obs.rotations, obs.centers, obs.intrinsics, n_directions,
                                                start, tol=tol)
        if polygon != "hull":
            # Measured (README "Partial visibility"): with the contour polygon (finite differences,
            # non-convex) leaving hidden pixels out made 1-2-3D-3A worse; only the border clip stays.
            hidden = (0.0, 0.0)
        iou = visible_iou(polys, valid, obs, polygon, hidden)
        return np.concatenate([1.0 - iou, penalty(xi, weight)], axis=1), start
    targets, convex, planes = obs.targets(polygon)
    if not convex:
        raise ValueError(f"the analytic R-IOU Jacobian needs convex observation polygons ('hull'), got {polygon!r}")
    polys, valid, start, unit_points, points = batch_silhouettes(xi, obs.rotations, obs.centers, obs.intrinsics,
                                                                 n_directions, start, touching=True, tol=tol)
    iou, weights = convex_iou_jacobian(polys, targets[None], planes)
    cut, clip, hi, hu = obs.partial_views(polys, polygon)
    if len(cut):
        clipped, clipped_weights = clipped_convex_iou_jacobian(polys[:, cut], targets[None, cut], obs.frames[None, cut],
                                                               tuple(p[cut] for p in planes), clip=clip,
                                                               hidden_inter=hi, hidden_union=hu)
        iou = iou.copy()
        iou[:, cut] = clipped
    iou = np.where(valid & np.isfinite(iou), iou, 0.0)

    def d_views():
        W = weights()
        if len(cut):
            W[:, cut] = clipped_weights()
        gradient = silhouette_gradient(xi, W, unit_points, points, obs.rotations, obs.intrinsics)
        return np.where(valid[..., None], -gradient, 0.0)

    return np.concatenate([1.0 - iou, penalty(xi, weight)], axis=1), start, d_views


def hidden_at(xi, obs, polygon="hull", n_directions=DEFAULT_DIRECTIONS, tol=NEWTON_TOL):
    """Hidden-pixel counts ``(h_n, h_u)``, each ``(1, p)``, of the silhouette of one parameter vector
    ``xi`` ``(1, 11)`` in the views :meth:`ObservationSet.partial_views` lists."""
    polys = batch_silhouettes(np.atleast_2d(xi), obs.rotations, obs.centers, obs.intrinsics, n_directions,
                              tol=tol)[0]
    return obs.partial_views(polys, polygon)[2:]


def silhouettes(xi, obs):
    """Silhouette polygons ``(b, v, K, 2)`` and ``valid`` ``(b, v)`` of parameter vectors ``xi``
    ``(b, 11)`` in the cameras of ``obs``, as :func:`sqfit.geometry.silhouette.batch_silhouettes` with
    its defaults (no warm start): compiled (:func:`sqfit.kernels.silhouette_kernels.silhouettes`) when
    the kernels are (:mod:`sqfit.kernels.backend`)."""
    xi = np.ascontiguousarray(np.atleast_2d(xi), dtype=np.float64)
    kernels = compiled("silhouettes")
    if kernels is None:
        return batch_silhouettes(xi, obs.rotations, obs.centers, obs.intrinsics)[:2]
    R = np.ascontiguousarray(euler_to_matrix(xi[:, 8:11]).reshape(len(xi), 3, 3))
    return kernels.silhouettes(xi, R, obs.rotations, obs.centers, obs.intrinsics, DEFAULT_DIRECTIONS,
                               NEWTON_TOL, MAX_NEWTON, ZNEAR, *E_RANGE)


def visible_iou(polys, valid, obs, polygon="hull", hidden=None):
    """IoU of batched silhouettes with the observation polygons, over the visible image part.

    As :func:`sqfit.geometry.polygon.batch_iou`, but in ``obs.border_views`` only the part of each
    silhouette inside the image counts, and in ``obs.occluded_views`` the pixels that may hide the
    object count in neither intersection nor union (:mod:`sqfit.geometry.visible_iou`).

    Parameters
    ----------
    polys : (b, v, K, 2) float
    valid : (b, v) bool
    obs : ObservationSet
    polygon : {"hull", "contour"}
    hidden : tuple, optional
        ``(h_n, h_u)`` broadcastable to ``(b, p)`` (:func:`hidden_at`) instead of counting.

    Returns
    -------
    iou : (b, v) float
    """
    targets, convex, planes = obs.targets(polygon)
    partial = obs.border_views | obs.occluded_views
    kernels = compiled("silhouettes") if convex else None
    if kernels is not None:  # the views seen in part are scored by clipped_iou below, not twice
        iou = kernels.convex_iou(np.ascontiguousarray(polys, dtype=np.float64), np.ascontiguousarray(valid & ~partial),
                                 targets, *planes, MIN_EDGE)
    elif convex:
        iou = batch_iou(polys, valid, targets, convex, planes)
    else:
        whole = np.flatnonzero(~partial)
        iou = np.zeros(valid.shape)
        iou[:, whole] = contour_ious(polys, valid, obs, whole, np.zeros(len(whole), dtype=bool), 0.0, 0.0)
    if not partial.any():
        return iou
    if hidden is None:
        cut, clip, hi, hu = obs.partial_views(polys, polygon)
    else:
        cut = np.flatnonzero(partial)
        clip = obs.border_views[cut]
        hi, hu = (np.broadcast_to(h, (len(polys), len(cut))) for h in hidden)
    if kernels is not None:  # the same clipping, compiled
        f64 = np.float64
        nr, cross_r, _ = obs.frame_planes
        iou[:, cut] = kernels.clipped_iou(
            np.ascontiguousarray(polys[:, cut], dtype=f64), np.ascontiguousarray(valid[:, cut]),
            np.ascontiguousarray(targets[cut], dtype=f64), *(np.ascontiguousarray(p[cut], dtype=f64) for p in planes),
            np.ascontiguousarray(obs.frames[cut]), np.ascontiguousarray(nr[cut]), np.ascontiguousarray(cross_r[cut]),
            np.ascontiguousarray(clip), np.ascontiguousarray(hi, dtype=f64), np.ascontiguousarray(hu, dtype=f64),
            MIN_EDGE)
        return iou
    iou = iou.copy()
    if convex:
        clipped = clipped_convex_iou_jacobian(polys[:, cut], targets[None, cut], obs.frames[None, cut],
                                              tuple(p[cut] for p in planes), clip=clip,
                                              hidden_inter=hi, hidden_union=hu)[0]
    else:
        clipped = contour_ious(polys, valid, obs, cut, clip, hi, hu)
    iou[:, cut] = np.where(valid[:, cut] & np.isfinite(clipped), clipped, 0.0)
    return iou


def sample_points(obs, depths):
    """``(n, 3) float``: world points of the samples at camera-frame depths ``(n,)`` (eq. 10)."""
    return obs.origins + obs.rays * np.asarray(depths, dtype=np.float64)[:, None]


def radial_terms(xi, points):
    """Radial distance G3 (eq. 8) of world points and its analytic derivatives.

    Parameters
    ----------
    xi : (11,) float
    points : (n, 3) float
        World coordinates.

    Returns
    -------
    g3 : (n,) float
        ``S - |y|``: positive inside, negative outside, 0 on the surface (metres); equals
        :func:`sqfit.geometry.superquadric.radial_distance`.
    d_xi : (n, 11) float
        ``d g3 / d xi``.
    d_point : (n, 3) float
        ``d g3 / d point`` (world frame).
    """
    kernels = compiled()
    if kernels is not None:
        return kernels.radial_rows(np.ascontiguousarray(xi, dtype=np.float64),
                                   np.ascontiguousarray(points, dtype=np.float64))
    R, dR = rotation_and_derivatives(xi[8:11])
    g3, d_xi, d_point = _radial_core(np.asarray(xi, dtype=np.float64)[None], R[None], dR.reshape(1, 3, 9),
                                     np.asarray(points, dtype=np.float64)[None])
    return g3[0], d_xi[0], d_point[0]


def batch_radial_terms(X, points):
    """:func:`radial_terms` of ``b`` superquadrics at once, each at its own points.

    Parameters
    ----------
    X : (b, 11) float
    points : (b, n, 3) float
        World coordinates; row ``i`` belongs to ``X[i]``.

    Returns
    -------
    g3 : (b, n) float
    d_xi : (b, n, 11) float
    d_point : (b, n, 3) float
    """
    X = np.asarray(X, dtype=np.float64)
    RdR = [rotation_and_derivatives(x[8:11]) for x in X]
    R = np.stack([m[0] for m in RdR])
    dR = np.stack([m[1] for m in RdR]).reshape(len(X), 3, 9)
    return _radial_core(X, R, dR, np.asarray(points, dtype=np.float64))


def _radial_core(X, R, dR, points):
    """The formulas of :func:`radial_terms` over a batch: ``X (b, 11)``, ``R (b, 3, 3)``, the
    rotation derivatives ``dR (b, 3, 9)`` and ``points (b, n, 3)``."""
    b, n = points.shape[:2]
    a = X[:, None, 0:3]
    e1, e2 = X[:, 3, None], X[:, 4, None]
    rel = points - X[:, None, 5:8]
    y = rel @ R
    y[y == 0.0] = _TINY  # keeps log finite; the weight of such a coordinate is 0 anyway
    norm2 = (y * y).sum(axis=2)
    la = np.log(np.abs(y)) - np.log(np.abs(a))
    Xl = (2.0 / e2)[..., None] * la[..., :2]
    XY = np.logaddexp(Xl[..., 0], Xl[..., 1])
    wxy = np.exp(Xl - XY[..., None])
    A, Bz = (e2 / e1) * XY, (2.0 / e1) * la[..., 2]
    L = np.logaddexp(A, Bz)
    wA = np.exp(A - L)
    wB = 1.0 - wA
    S = np.exp(0.5 * (np.log(norm2) - e1 * L))
    norm = np.sqrt(norm2)
    g3 = S - norm
    # d L / d log|y_i| (= - d L / d log|a_i|): power-mean weights times 2 / e1.
    dl = np.empty_like(y)
    dl[..., :2] = wxy * wA[..., None]
    dl[..., 2] = wB
    half_S = 0.5 * S
    # d G3 / d y = S y / |y|^2 - (e1 / 2) S dL/dy - y / |y|, with e1 dl / 2 = power-mean weights.
    d_y = ((S - norm) / norm2)[..., None] * y - half_S[..., None] * (2.0 * dl) / y
    d_xi = np.empty((b, n, C.N_PARAMS))
    d_xi[..., 0:3] = S[..., None] * dl / a
    # d G3 / d e1 = -S (L - wA A - wB Bz) / 2; d G3 / d e2 = -S wA (XY - wx X1 - wy X2) / 2.
    with np.errstate(invalid="ignore"):
        de1 = L - wA * A - wB * Bz
        de2 = XY - wxy[..., 0] * Xl[..., 0] - wxy[..., 1] * Xl[..., 1]
    if not (np.isfinite(de1).all() and np.isfinite(de2).all()):  # 0 * -inf (a zero size): 0
        de1 = L - _wmul(wA, A) - _wmul(wB, Bz)
        de2 = XY - _wmul(wxy[..., 0], Xl[..., 0]) - _wmul(wxy[..., 1], Xl[..., 1])
    d_xi[..., 3] = -half_S * de1
    d_xi[..., 4] = -half_S * wA * de2
    d_point = d_y @ R.transpose(0, 2, 1)
    d_xi[..., 5:8] = -d_point
    # y = R^T (x - p): d y_i / d r_k = sum_j dR_k[j, i] rel_j.
    outer = (rel[..., :, None] * d_y[..., None, :]).reshape(b, n, 9)
    d_xi[..., 8:11] = outer @ dR.transpose(0, 2, 1)
    return g3, d_xi, d_point


def _wmul(w, x):
    """``w * x`` with ``0 * -inf = 0`` (a zero weight belongs to a zero coordinate)."""
    return np.where(w > 0, w * np.where(np.isfinite(x), x, 0.0), 0.0)


def g5_residuals(xi, depths, obs, weight=C.PENALTY_ANALYTIC, scaled=True):
    """G5 (or G4) residuals of the samples at per-sample depths, with the Jacobian blocks.

    Parameters
    ----------
    xi : (11,) float
    depths : (n,) float
        Camera-frame depth of every sample (all views concatenated, as ``obs.rays``).
    obs : ObservationSet
    weight : float
        ``c_p`` of the penalty.
    scaled : bool
        G5 = ``(ax ay az + 1) G4`` if True (paper, stages 3C-3E), else G4.

    Returns
    -------
    r : (n + 11,) float
        Sample residuals, then the penalty.
    A : (n, 11) float
        ``d r_sample / d xi``.
    D : (n,) float
        ``d r_sample_i / d depth_i``.
    P : (11,) float
        Diagonal of ``d penalty / d xi``.
    """
    xi = np.asarray(xi, dtype=np.float64)
    kernels = compiled()
    if kernels is not None:
        return kernels.g5_rows(np.ascontiguousarray(xi), np.ascontiguousarray(depths, dtype=np.float64),
                               np.ascontiguousarray(obs.origins), np.ascontiguousarray(obs.rays), bool(scaled), float(weight), LOWER_BOUNDS, UPPER_BOUNDS)
    g3, d_xi, d_point = radial_terms(xi, sample_points(obs, depths))
    D = (d_point * obs.rays).sum(axis=1)
    if scaled:
        vol = xi[0] * xi[1] * xi[2]
        scale = vol + 1.0
        d_xi *= scale
        d_xi[:, 0:3] += g3[:, None] * (vol / np.where(xi[0:3] == 0, _TINY, xi[0:3]))
        D *= scale
        g3 = g3 * scale
    r = np.concatenate([g3, penalty(xi, weight)])
    return r, d_xi, D, penalty_jacobian(xi, weight)
