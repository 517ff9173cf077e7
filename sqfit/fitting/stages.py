"""The fitting stages of the paper (section III-E), one function each, registered by name.

Every stage is ``stage(state, observations, options) -> state``: it reads a :class:`FitState`
(parameter vector and depths so far), an :class:`sqfit.fitting.costs.ObservationSet` and a
:class:`sqfit.fitting.pipeline.FitOptions`, and returns a new state. A stage that cannot proceed raises
:class:`StageError` with a status code; :func:`sqfit.fit` turns that into a failed result.

=====  =====================================================================================
``1``  Linear triangulation of the mask centroids (eq. 12, QR) and one depth per view.
``2``  PCA initialisation (Algorithm 1): orientation, size, ``e = 1``, one depth per sample.
``3A`` Levenberg-Marquardt on G2 (1 - R-IOU + penalty), all 11 parameters. Analytic Jacobian
       by default, finite differences as in the paper with ``FitOptions.riou_jacobian="numeric"``
       (optionally with a secant estimate of the second-order term: ``FitOptions.hessian_numeric``).
``3B`` As 3A with ``e`` fixed to 1 (9 parameters).
``3C`` LM on G5 with ``e = 1`` and one depth per view (9 + v unknowns), analytic Jacobian.
``3D`` LM on G5 with ``e = 1`` and one depth per sample (9 + n unknowns), analytic, Schur.
``3E`` LM on G5, all 11 parameters and one depth per sample, analytic, Schur.
``3F`` LM on G2 with only ``e`` free (2 parameters), Jacobian as 3A.
=====  =====================================================================================

Boundary labels (:mod:`sqfit.views.visibility`): stages 1 and 2 read them (below), 3A, 3B and 3F
through the R-IOU costs (only the visible part of a view counts, :func:`sqfit.fitting.costs.riou_residuals`);
3C-3E ignore them (their samples lie inside the mask, which is the object either way).

Stages 3B-3D set ``e = (1, 1)`` before optimising ("quadric parameters"). Depths are camera-frame
z (as eq. 10). Depth bookkeeping between stages: a stage that needs one depth per sample and only
has one per view repeats it; a stage that needs one per view and only has one per sample takes the
per-view mean.

Partial visibility: a view whose outline is less than :data:`TRUSTED_SILHOUETTE_FRACTION` true
silhouette (``Observation.silhouette_fraction``: the rest is labelled occluded or truncated, see
:mod:`sqfit.views.visibility`) has a biased centroid, area and sample spread. When at least two views
are trusted, stage 1 weights each view's rows of the triangulation by its silhouette fraction
(floor 0.1) and takes the size from the trusted views only, and stage 2 runs its PCA on the
trusted views' samples only; with fewer than two trusted views all views are used as before.
Measured against dropping the untrusted views from the triangulation and against ignoring the
labels in stages 1-2 (:data:`CUT_VIEWS`): README, "Partial visibility".

Default initial guess (our choice; the paper does not state one), used when a chain starts at
stage 3 or 2: a unit sphere-like quadric ``a = (1, 1, 1)``, ``e = (1, 1)`` at the world origin
with zero rotation; per-view depth = depth of the world origin in that camera; per-sample depth =
depth of the point of the sample's ray nearest to the world origin (the view depth if that point
is behind the camera).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, replace

import numpy as np

from .. import constants as C
from ..geometry.superquadric import Superquadric
from .costs import (g5_residuals, hidden_at, penalty_jacobian, riou_residuals, rotation_and_derivatives, silhouettes,
                    visible_iou)
from .lm import DenseJacobian, SchurJacobian, levenberg_marquardt
from ..geometry.silhouette import NEWTON_TOL, ZNEAR

__all__ = ["FitState", "StageError", "STAGES", "register", "default_state", "view_depths_of", "rotation_to_euler", "trusted_views",
           "TRUSTED_SILHOUETTE_FRACTION", "NUMERICAL_ERRORS", "to_superquadric", "r_iou_m"]

#: Triangulation fails when the condition number of the QR factor R exceeds this.
_MAX_TRIANGULATION_CONDITION = 1e8
#: A stage result with a size above this (metres) or a non-finite value is "diverged".
_MAX_SIZE = 1e4
_QUADRIC = np.array([1.0, 1.0])
_SQ_NO_SHAPE = np.r_[0:3, 5:11]  # the 9 quadric parameters
_ALL = np.arange(C.N_PARAMS)
_SHAPE_ONLY = np.array([3, 4])
#: Silhouette precision (pixels) of the R-IOU stages with the analytic Jacobian: the vertices
#: are then off by ~1e-3 px (area ~1e-5 relative), which saves one Newton step per evaluation.
#: Finite differences (steps of ~1e-2 px) need the default 1e-7 px.
_SILHOUETTE_TOL_ANALYTIC = 1e-3
#: Views whose outline is at least this fraction true silhouette are trusted by stages 1 and 2.
TRUSTED_SILHOUETTE_FRACTION = 0.9
#: How stages 1 and 2 treat untrusted views: "weight" (default: stage 1 rows weighted by the
#: silhouette fraction, floor 0.1), "drop" (stage 1 leaves them out; their depth is that of the
#: triangulated point); both size from and run stage 2 on trusted views only. "all" ignores the labels.
CUT_VIEWS = "weight"


@dataclass(frozen=True)
class FitState:
    """What the stages pass on.

    Attributes
    ----------
    xi : (11,) float
        Current parameter vector.
    view_depths : (v,) float or None
        One depth per view (stage 1, 3C).
    sample_depths : (n,) float or None
        One depth per sample, all views concatenated (stage 2, 3D, 3E).
    cost : float or None
        Final cost of the stage's optimiser (``0.5 * sum r**2``), None for closed-form stages.
    status : str
        Optimiser status (a key of :data:`sqfit.fitting.lm.STATUS`) or ``"ok"``.
    message : str
    nfev : int
        Cost evaluations (a finite-difference Jacobian counts its columns).
    outline_offsets : (g,) float or None
        The masks' outline offsets (px, > 0: the outlines lie outside the silhouettes; one per
        object or per view) estimated together with ``xi`` (stages 3G and 3H), or None. A stage
        that passes its input on (``dataclasses.replace`` without ``xi``) keeps them; a stage
        that moves ``xi`` without estimating offsets sets None, since they belong to a fit that
        is no longer this one.
    camera_corrections : (v, 3) float or None
        Rotation corrections of the given cameras that ``xi`` was fitted with, as world-frame
        rotation vectors ``w_v`` (radians; camera -> world rotation ``exp([w_v]x) R_v``), where 3G or
        3H found that the cameras disagree and its fit grazes the outline
        (:func:`sqfit.fitting.grazing.silhouette_fit`); else None. Stage 3R re-fits under those
        cameras too (:mod:`sqfit.fitting.trimmed`); a stage that passes its input on keeps them.
    """

    xi: np.ndarray
    view_depths: np.ndarray | None = None
    sample_depths: np.ndarray | None = None
    cost: float | None = None
    status: str = "ok"
    message: str = ""
    nfev: int = 0
    outline_offsets: np.ndarray | None = None
    camera_corrections: np.ndarray | None = None


class StageError(Exception):
    """A stage cannot continue; ``status`` is a short failure code."""

    def __init__(self, status, message):
        super().__init__(message)
        self.status = status
        self.message = message


#: Errors a stage's numerics may raise on a degenerate input: the chain stops there with status
#: "failed" and the last good snapshot (:func:`sqfit.fitting.pipeline.fit`), a screen skips the candidate.
NUMERICAL_ERRORS = (np.linalg.LinAlgError, FloatingPointError, ArithmeticError, ValueError)


def to_superquadric(xi):
    """A valid :class:`Superquadric` from an optimiser's vector.

    ``|a|`` is used (F depends on ``|t / a|`` only), with a floor of 1e-6 m, and ``e`` is clipped to
    ``constants.SHAPE_DOMAIN`` (the soft bounds of eq. 7 may be slightly exceeded).
    """
    xi = np.array(xi, dtype=np.float64)
    xi[0:3] = np.maximum(np.abs(xi[0:3]), 1e-6)
    xi[3:5] = np.clip(xi[3:5], *C.SHAPE_DOMAIN)
    return Superquadric.from_vector(xi)


def r_iou_m(superquadrics, obs, polygon="hull"):
    """R-IOU-M of several superquadrics at once: ``(b,) float`` mean over views of the IoU.

    Scores are remembered per observation set (while it lives) by exact parameter vector, so a
    superquadric scored twice -- 3H's rescue check and then :func:`sqfit.fit`'s per-stage
    R-IOU-M of the same snapshot -- is evaluated once; the others are evaluated as one batch
    (:func:`sqfit.fitting.costs.silhouettes`). On the numpy path a batch's silhouette solver stops
    when its slowest member converged, so a score can differ from the same superquadric's score in
    another batch by rounding (measured <= 1e-15); the compiled path stops each vertex on its own.
    """
    xi = np.stack([sq.to_vector() for sq in superquadrics])
    memo = _R_IOU_M_MEMO.get(obs)
    if memo is None or len(memo) > _R_IOU_M_MEMO_SIZE:
        memo = _R_IOU_M_MEMO[obs] = {}
    keys = [(polygon, x.tobytes()) for x in xi]
    todo = [i for i, key in enumerate(keys) if key not in memo]
    if todo:
        polys, valid = silhouettes(xi[todo], obs)
        for i, score in zip(todo, visible_iou(polys, valid, obs, polygon).mean(axis=1)):
            memo[keys[i]] = score
    return np.array([memo[key] for key in keys], dtype=np.float64)


#: Remembered R-IOU-M scores per observation set (see :func:`r_iou_m`); at most this many each.
_R_IOU_M_MEMO_SIZE = 64
_R_IOU_M_MEMO = weakref.WeakKeyDictionary()

STAGES = {}


def register(name):
    """Decorator: add a stage function to :data:`STAGES` under ``name``."""
    def wrap(fn):
        STAGES[name] = fn
        return fn
    return wrap


def default_state(obs):
    """The documented default starting point (see the module docstring)."""
    xi = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    view = np.einsum("vj,vj->v", -obs.centers, obs.rotations[:, :, 2])
    d = -np.einsum("nj,nj->n", obs.origins, obs.rays) / np.einsum("nj,nj->n", obs.rays, obs.rays)
    d = np.where(d > ZNEAR, d, view[obs.view_of_sample])
    return FitState(xi, view_depths=view, sample_depths=d)


def view_depths_of(state, obs):
    """``(v,) float``: the state's depth per view, else its per-sample depths averaged per view, else
    the default state's."""
    if state.view_depths is not None:
        return state.view_depths
    if state.sample_depths is not None:
        return np.bincount(obs.view_of_sample, state.sample_depths) / np.bincount(obs.view_of_sample)
    return default_state(obs).view_depths


def _sample_depths(state, obs):
    if state.sample_depths is not None:
        return state.sample_depths
    if state.view_depths is not None:
        return state.view_depths[obs.view_of_sample]
    return default_state(obs).sample_depths


def trusted_views(obs):
    """``(v,) bool``: views whose outline is mostly true silhouette (see the module docstring);
    all True when fewer than two views qualify."""
    fractions = np.array([o.silhouette_fraction for o in obs.observations])
    trusted = fractions >= TRUSTED_SILHOUETTE_FRACTION
    if CUT_VIEWS == "all" or trusted.sum() < 2:
        return np.ones(len(fractions), dtype=bool)
    return trusted


def _view_weights(obs):
    if CUT_VIEWS == "weight":
        return np.maximum([o.silhouette_fraction for o in obs.observations], 0.1)
    return trusted_views(obs).astype(np.float64)


@register("1")
def triangulate(state, obs, options):
    """Stage 1: triangulate the mask centroids (eq. 12) and give one depth per view.

    ``A x = b`` with rows ``[I, -v_i]`` and ``b_i`` the camera centres, ``v_i = R_c Bp(c_i, 1)``,
    solved by QR; ``x = [p, d_1 .. d_v]`` so the ``d_i`` are camera-frame depths. The snapshot is
    a sphere (``e = 1``, zero rotation) at ``p`` whose radius is the mean over views of the
    equivalent-disc radius of the mask, ``sqrt(area / pi) / sqrt(fx fy)``, back-projected at
    ``d_i`` (floor 0.1 m), so R-IOU-M is meaningful.

    Raises :class:`StageError` ``singular_triangulation`` (near-parallel rays) or
    ``triangulation_behind_camera`` (a depth <= 0).
    """
    v = len(obs)
    centroids = np.stack([o.centroid for o in obs.observations])
    k = obs.intrinsics
    rays = np.stack([(centroids[:, 0] - k[:, 2]) / k[:, 0], (centroids[:, 1] - k[:, 3]) / k[:, 1],
                     np.ones(v)], axis=1)
    bearing = np.einsum("vij,vj->vi", obs.rotations, rays)
    weight = _view_weights(obs)
    used = np.flatnonzero(weight > 0)
    u = len(used)
    A = np.zeros((3 * u, 3 + u))
    A[:, :3] = np.tile(np.eye(3), (u, 1))
    for j, i in enumerate(used):
        A[3 * j:3 * j + 3, 3 + j] = -bearing[i]
    row_weight = np.repeat(weight[used], 3)
    Q, R = np.linalg.qr(A * row_weight[:, None])
    diag = np.abs(np.diag(R))
    if diag.min() <= diag.max() / _MAX_TRIANGULATION_CONDITION or not np.all(np.isfinite(R)):
        raise StageError("singular_triangulation", "triangulation is ill-conditioned: the centroid rays "
                         "are (nearly) parallel")
    sol = np.linalg.solve(R, Q.T @ (obs.centers[used].reshape(-1) * row_weight))
    p = sol[:3]
    # Views left out: the depth of the triangulated point along their centroid ray.
    depths = np.einsum("vj,vj->v", p - obs.centers, bearing) / np.einsum("vj,vj->v", bearing, bearing)
    depths[used] = sol[3:]
    if np.any(depths <= ZNEAR):
        raise StageError("triangulation_behind_camera",
                         f"triangulated point is behind camera(s) {np.flatnonzero(depths <= ZNEAR).tolist()}")
    area = np.array([o.area_px for o in obs.observations], dtype=float)
    radius = np.sqrt(area / np.pi) / np.sqrt(k[:, 0] * k[:, 1]) * depths
    sized = trusted_views(obs)
    r = max(float(radius[sized].mean()), C.SIZE_MIN)
    xi = np.array([r, r, r, 1.0, 1.0, *p, 0.0, 0.0, 0.0])
    return FitState(xi, view_depths=depths, sample_depths=None)


@register("2")
def pca_init(state, obs, options):
    """Stage 2 (Algorithm 1): PCA of the samples back-projected at one depth per view.

    Orientation: the principal axes (right singular vectors of the centred points), made a proper
    rotation (``det = +1``). Size: half the extent of the points in that frame (floor 0.1 m).
    Shape ``e = 1``; position kept from the input state (stage 1's triangulated point, as the
    paper). Per-sample depth: the closed-form minimiser along each ray (:func:`ellipsoid_depths`).
    """
    depths = view_depths_of(state, obs)
    use = trusted_views(obs)[obs.view_of_sample]
    points = (obs.origins + obs.rays * depths[obs.view_of_sample][:, None])[use]
    centred = points - points.mean(axis=0)
    _, _, Vt = np.linalg.svd(centred / np.sqrt(max(len(points) - 1, 1)), full_matrices=False)
    R = Vt.T.copy()
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    local = centred @ R
    size = np.maximum((local.max(axis=0) - local.min(axis=0)) / 2.0, C.SIZE_MIN)
    xi = np.concatenate([size, _QUADRIC, state.xi[5:8], rotation_to_euler(R)])
    return FitState(xi, view_depths=None, sample_depths=ellipsoid_depths(xi, obs))


def ellipsoid_depths(xi, obs):
    """Per-sample depths on the quadric ``xi`` (``e`` taken as 1), closed form.

    Each ray ``x(d) = o + d w`` in unit-sphere coordinates ``q(d) = q0 + d u`` meets the ellipsoid
    where ``|q0 + d u|^2 = 1``: the near root (visible surface) is taken, or the far root if the
    near one is behind the camera. A ray that misses gets the depth minimising ``|q(d)|^2``, the
    point of the ray where the quadric's implicit function ``F`` is smallest. This is
    ``argmin_d G4^2`` of Algorithm 1 exactly for hits and our closed-form stand-in for misses.

    Returns
    -------
    depths : (n,) float
    """
    R = _rotation(xi)
    a = np.abs(xi[0:3])
    q0 = ((obs.origins - xi[5:8]) @ R) / a
    u = (obs.rays @ R) / a
    A = np.einsum("ij,ij->i", u, u)
    B = np.einsum("ij,ij->i", q0, u)
    Cc = np.einsum("ij,ij->i", q0, q0) - 1.0
    disc = B * B - A * Cc
    root = np.sqrt(np.maximum(disc, 0.0))
    near, far = (-B - root) / A, (-B + root) / A
    hit = np.where(near > ZNEAR, near, far)
    return np.where((disc >= 0) & (hit > ZNEAR), hit, np.maximum(-B / A, ZNEAR))


def _rotation(xi):
    return rotation_and_derivatives(xi[8:11])[0]


def rotation_to_euler(R):
    """``(3,) float`` Euler angles (convention of :mod:`sqfit.geometry.superquadric`) of a proper rotation, closed form."""
    ry = -np.arcsin(np.clip(R[2, 0], -1.0, 1.0))
    if abs(R[2, 0]) < 1.0 - 1e-12:
        return np.array([np.arctan2(R[2, 1], R[2, 2]), ry, np.arctan2(R[1, 0], R[0, 0])])
    # Gimbal lock: only rx - rz (or rx + rz) is defined; put it all in rx.
    return np.array([np.arctan2(-R[1, 2], R[1, 1]), ry, 0.0])


def _check_result(xi, stage):
    if not np.all(np.isfinite(xi)):
        raise StageError("nonfinite", f"stage {stage}: the optimiser produced non-finite parameters")
    if np.max(np.abs(xi[0:3])) > _MAX_SIZE:
        raise StageError("diverged", f"stage {stage}: the optimiser diverged (size > {_MAX_SIZE:g} m)")


# ----------------------------------------------------------------------------------------------
# Numeric R-IOU stages (G2, finite differences)


def _riou_stage(state, obs, options, free, quadric, name):
    """LM on G2 over the parameters ``free``.

    Jacobian: analytic when ``options.riou_jacobian == "analytic"`` (the default) and the
    observation polygons are hulls (:func:`sqfit.fitting.costs.riou_residuals`); otherwise forward
    differences, as in the paper. Either is lazy (see :func:`sqfit.fitting.lm.levenberg_marquardt`): a
    trial point costs one evaluation of G2, and only accepted points pay for the Jacobian. The
    ``len(free)`` difference columns reuse the point's residuals and start their silhouette solves
    from its support values (so Newton needs fewer steps than from the quadric's ellipse); the
    analytic Jacobian costs about half an evaluation's worth of array work. Every accepted
    point's silhouette directions and support values warm-start the next trial's silhouettes
    (:class:`sqfit.geometry.silhouette.SilhouetteStart`: the directions stay until the silhouettes' shape
    drifts, so trials see one smooth cost); with the analytic Jacobian the silhouettes are
    solved to 1e-3 px instead of 1e-7 px, one Newton step fewer. The model Hessian is
    ``options.hessian_numeric`` (with a structured secant term by default, see
    :class:`sqfit.fitting.lm.SecantTerm`, or plain Gauss-Newton); besides ``ftol`` the run stops on a
    crawl (``options.window_numeric``, ``window_ftol_numeric``).
    """
    xi0 = np.array(state.xi, dtype=np.float64)
    if quadric:
        xi0[3:5] = _QUADRIC
    k = len(free)
    steps = options.fd_step * np.maximum(1.0, np.abs(xi0[free]))
    eye = np.eye(k) * steps
    penalty_rows = len(obs) + free
    analytic = options.riou_jacobian == "analytic" and options.polygon == "hull"
    accepted = {}  # the silhouette start of the last point whose Jacobian was built

    def g2(batch, start, jacobian=False, hidden=None):
        return riou_residuals(batch, obs, options.polygon, options.penalty_riou, options.silhouette_directions,
                              start, jacobian=jacobian, tol=_SILHOUETTE_TOL_ANALYTIC if analytic else NEWTON_TOL,
                              hidden=hidden)

    def model(x):
        full = xi0.copy()
        full[free] = x
        if analytic:
            r, start, d_views = g2(full[None], accepted.get("start"), jacobian=True)
        else:
            r, start = g2(full[None], accepted.get("start"))

        def jacobian():
            accepted["start"] = start.refreshed()
            if analytic:
                J = np.zeros((r.shape[1], k))
                J[:len(obs)] = d_views()[0][:, free]
            else:
                batch = np.tile(full, (k, 1))
                batch[:, free] += eye
                # Hidden-pixel counts held at this point's (as the analytic Jacobian does).
                hidden = (hidden_at(full[None], obs, options.polygon, options.silhouette_directions)
                          if obs.occluded_views.any() and options.polygon == "hull" else None)
                J = (g2(batch, start, hidden=hidden)[0] - r).T / steps
                J[len(obs):] = 0.0
            # The penalty is piecewise linear: its exact slope, not a difference across a kink.
            J[penalty_rows, np.arange(k)] = penalty_jacobian(full, options.penalty_riou)[free]
            return DenseJacobian(J)

        return r[0], jacobian

    res = levenberg_marquardt(model, xi0[free], max_iterations=options.max_iterations_numeric,
                              ftol=options.ftol_numeric, xtol=options.xtol, gtol=options.gtol,
                              window=options.window_numeric, window_ftol=options.window_ftol_numeric,
                              scaling=options.damping_numeric, hessian=options.hessian_numeric)
    xi = xi0.copy()
    xi[free] = res.x
    _check_result(xi, name)
    return replace(state, xi=xi, cost=res.cost, status=res.status, message=res.message,
                   nfev=res.nfev + (0 if analytic else res.njev * k), outline_offsets=None,
                   camera_corrections=None)


@register("3A")
def riou_all(state, obs, options):
    """Stage 3A: G2 over all 11 parameters."""
    return _riou_stage(state, obs, options, _ALL, False, "3A")


@register("3B")
def riou_quadric(state, obs, options):
    """Stage 3B: G2 over the 9 quadric parameters, ``e = 1``."""
    return _riou_stage(state, obs, options, _SQ_NO_SHAPE, True, "3B")


@register("3F")
def riou_shape(state, obs, options):
    """Stage 3F: G2 over the shape exponents only."""
    return _riou_stage(state, obs, options, _SHAPE_ONLY, False, "3F")


# ----------------------------------------------------------------------------------------------
# Analytic G5 stages


def _g5_stage(state, obs, options, free, quadric, per_sample, name):
    xi0 = np.array(state.xi, dtype=np.float64)
    if quadric:
        xi0[3:5] = _QUADRIC
    k = len(free)
    cp = options.penalty_analytic
    if per_sample:
        d0 = np.array(_sample_depths(state, obs), dtype=np.float64)
    else:
        d0 = np.array(view_depths_of(state, obs), dtype=np.float64)
    view = obs.view_of_sample
    n_views = len(obs)

    def model(x):
        full = xi0.copy()
        full[free] = x[:k]
        depth = x[k:] if per_sample else x[k:][view]
        r, A, D, P = g5_residuals(full, depth, obs, cp)
        Pm = np.zeros((C.N_PARAMS, k))
        Pm[free, np.arange(k)] = P[free]
        if per_sample:
            return r, SchurJacobian(A[:, free], D, Pm)
        J = np.zeros((len(r), k + n_views))
        J[:len(D), :k] = A[:, free]
        J[np.arange(len(D)), k + view] = D
        J[len(D):, :k] = Pm
        return r, DenseJacobian(J)

    x0 = np.concatenate([xi0[free], d0])
    res = levenberg_marquardt(model, x0, max_iterations=options.max_iterations_analytic,
                              ftol=options.ftol_analytic, xtol=options.xtol, gtol=options.gtol,
                              atol=options.atol_analytic)
    xi = xi0.copy()
    xi[free] = res.x[:k]
    _check_result(xi, name)
    depths = res.x[k:]
    common = dict(xi=xi, cost=res.cost, status=res.status, message=res.message, nfev=res.nfev)
    if per_sample:
        return FitState(sample_depths=depths, view_depths=None, **common)
    return FitState(view_depths=depths, sample_depths=None, **common)


@register("3C")
def g5_view_depth(state, obs, options):
    """Stage 3C: G5, ``e = 1``, one depth per view (9 + v unknowns), analytic Jacobian."""
    return _g5_stage(state, obs, options, _SQ_NO_SHAPE, True, False, "3C")


@register("3D")
def g5_sample_depth_quadric(state, obs, options):
    """Stage 3D: G5, ``e = 1``, one depth per sample (9 + n unknowns), analytic, Schur complement."""
    return _g5_stage(state, obs, options, _SQ_NO_SHAPE, True, True, "3D")


@register("3E")
def g5_sample_depth_all(state, obs, options):
    """Stage 3E: G5, all 11 parameters, one depth per sample, analytic, Schur complement."""
    return _g5_stage(state, obs, options, _ALL, False, True, "3E")
