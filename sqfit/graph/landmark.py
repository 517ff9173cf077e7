"""Superquadric landmarks for the factor graph: the silhouette residual of one (frame, object) and
its analytic Jacobians (numpy only; the gtsam wrappers are in :mod:`sqfit.graph.factors`).

Conventions (stated once, pinned by ``tests/test_graph.py``):

- A landmark is a pose ``T_world_sq`` (``(4, 4)``, superquadric -> world, as
  :attr:`sqfit.Superquadric.pose`) and a size/shape vector ``s = [ax, ay, az, e1, e2]`` (metres,
  unitless): the first five entries of the paper's parameter vector. Position and orientation live
  in the pose, so the graph never sees Euler angles (no gimbal lock).
- Pose perturbations follow GTSAM's ``Pose3`` retraction to first order: ``T' = T Exp(delta)`` with
  ``delta = [omega, v]`` (rotation first, body frame): ``R' = R exp([omega]x)``, ``t' = t + R v``.
  Jacobians with respect to a pose are ``(m, 6)`` in that order.
- Rays are fixed in the camera frame (pixel bearings with unit depth, ``[(u - cx) / fx,
  (v - cy) / fy, 1]``): a silhouette residual is a function of (camera pose, landmark) only.

The residual of a view is :func:`sqfit.fitting.raycost.ray_residuals` evaluated in the landmark's own frame
(rays moved there by ``T_sq_camera``, the superquadric at the identity pose): it is the 3G residual
of the same rays, with the same modes, weights and any per-ray flags the ray set carries (the
function is taken from :mod:`sqfit.fitting.raycost`, not re-derived). By the envelope theorem the residual
depends on a pose only through the point ``y* = o + d* b`` where the ray comes closest to the
superquadric (in gauge), so with ``g = d r / d y`` at that point (landmark frame):

- landmark: ``y' = Exp(-delta) y`` gives ``d r / d omega = g x y``, ``d r / d v = -g``;
- camera: ``y(d) = t_sc + d R_sc b`` with ``R_sc' = R_sc exp([omega]x)``, ``t_sc' = t_sc + R_sc v``
  gives ``d r / d omega = d* (b x g_c)``, ``d r / d v = g_c`` with ``g_c = R_sc^T g``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .. import constants as C
from .._checks import check_shape
from ..fitting.costs import LOWER_BOUNDS, UPPER_BOUNDS
from ..views.observation import Observation
from ..fitting.stages import to_superquadric
from ..kernels.backend import compiled
from ..fitting.line_gauge import gauge_minima, solver_args
from ..fitting.raycost import CROSSING_ARGS, crossing_correction, gauge_phi, batch_log_gauge_jacobian, ray_residuals
from ..views.rays import contour_rays
from ..geometry.superquadric import Superquadric

__all__ = ["N_SHAPE", "camera_rays", "silhouette_residuals", "StackedRays", "stack_rays",
           "batch_silhouette_residuals", "bounds_residuals", "landmark_to_superquadric", "superquadric_to_landmark",
           "relative_pose", "bounded_residuals", "left_grazing", "EVAL_LOWER", "EVAL_UPPER"]

#: Length of the size/shape vector ``[ax, ay, az, e1, e2]``.
N_SHAPE = 5
_SHAPE_LO, _SHAPE_HI = LOWER_BOUNDS[:N_SHAPE], UPPER_BOUNDS[:N_SHAPE]
#: The silhouette residual is evaluated at the size/shape vector clipped to these (metres, unitless;
#: convex shapes with finite powers), with zero Jacobian columns where clipped: an optimiser's trial
#: step outside the bounds meets the bound penalty, not a non-finite residual.
EVAL_LOWER = np.array([0.01, 0.01, 0.01, 0.05, 0.05])
EVAL_UPPER = np.array([np.inf, np.inf, np.inf, 2.0, 2.0])


def camera_rays(observation, n_contour):
    """The 3G rays of one observation, moved into its camera's frame.

    Parameters
    ----------
    observation : Observation
        Only its pixels and its camera's rotation are used: the rays do not depend on where the
        observation's camera was placed.
    n_contour : int
        Contour points (rays), >= 3.

    Returns
    -------
    rays : RaySet
        ``origins`` all zero, ``directions`` the pixel bearings ``(n, 3)`` with unit depth and
        ``offsets`` their change per pixel of outline offset (camera frame); modes, weights, radii
        and any other per-ray arrays as :func:`sqfit.views.rays.contour_rays` gives them.
    """
    if not isinstance(observation, Observation):
        raise TypeError(f"observation must be a sqfit.Observation, got {type(observation).__name__}")
    rays = contour_rays([observation], n_contour)
    rotation = observation.camera.rotation
    directions = rays.directions @ rotation  # R^T d per row
    # checked in contour_rays; products of those arrays with a rotation need no second check (it
    # was a third of this function's time, which iSAM2 pays for every new view)
    return _moved(rays, np.zeros_like(directions), directions, rays.offsets @ rotation)


def relative_pose(T_world_camera, T_world_sq):
    """``T_sq_camera`` as ``(R (3, 3), t (3,))``: the camera in the landmark's frame."""
    R_c, t_c = T_world_camera[:3, :3], T_world_camera[:3, 3]
    R_l, t_l = T_world_sq[:3, :3], T_world_sq[:3, 3]
    return R_l.T @ R_c, R_l.T @ (t_c - t_l)


def silhouette_residuals(T_world_camera, T_world_sq, shape, rays, d0=None):
    """3G residuals of one view of one landmark, and their Jacobians.

    No input checks: this runs at every evaluation of every factor, on values GTSAM holds; the rays
    are checked where they are made (:func:`camera_rays`).

    Parameters
    ----------
    T_world_camera : (4, 4) float
        Camera pose (camera -> world).
    T_world_sq : (4, 4) float
        Landmark pose (superquadric -> world).
    shape : (5,) float
        ``[ax, ay, az, e1, e2]``; clipped to ``[EVAL_LOWER, EVAL_UPPER]`` (zero Jacobian columns
        where clipped).
    rays : RaySet
        Camera-frame rays (:func:`camera_rays`).
    d0 : (n,) float, optional
        Warm start of the ray minimisers (camera depths), e.g. from the previous call.

    Returns
    -------
    r : (n,) float
        Weighted ray residuals (:func:`sqfit.fitting.raycost.ray_residuals`).
    J_camera : (n, 6) float
        ``d r / d delta`` of the camera pose (module convention).
    J_landmark : (n, 6) float
        ``d r / d delta`` of the landmark pose.
    J_shape : (n, 5) float
        ``d r / d s``.
    d : (n,) float
        Ray minimisers (camera depths along the bearings).
    """
    R_sc, t_sc = relative_pose(T_world_camera, T_world_sq)
    b = rays.directions
    local = _moved(rays, np.broadcast_to(t_sc, b.shape), b @ R_sc.T)
    clipped = np.clip(shape, EVAL_LOWER, EVAL_UPPER)
    xi = np.concatenate([clipped, np.zeros(C.N_PARAMS - N_SHAPE)])
    r, J, d = ray_residuals(xi, local, 0.0, d0)
    n = len(rays)
    r, J = r[:n], J[:n]
    g = -J[:, C.POSITION]  # d r / d y (moving the centre by p moves every point by -p)
    y = local.origins + d[:, None] * local.directions
    J_landmark = np.hstack([_cross(g, y), -g])
    g_c = g @ R_sc
    J_camera = np.hstack([d[:, None] * _cross(b, g_c), g_c])
    J_shape = J[:, :N_SHAPE] * (clipped == shape)
    return r, J_camera, J_landmark, J_shape, d


@dataclass(frozen=True)
class StackedRays:
    """The camera-frame rays of ``k`` silhouette factors with ``n`` rays each, stacked for
    :func:`batch_silhouette_residuals` (made by :func:`stack_rays`).

    Attributes
    ----------
    directions : (k, n, 3) float
        Pixel bearings, camera frame.
    weights : (k, n) float
    hinge_in : (k, n) bool
        Rays whose residual only counts when positive (``INSIDE``, and one-sided ``CONTOUR``).
    hinge_out : (k, n) bool
        ``OUTSIDE`` rays (count only when negative).
    two_sided : (k, n) bool
    offsets : (k, n, 3) float
        Change of each bearing per pixel of outline offset (camera frame; ``RaySet.offsets``).
    radii : (k, n) float
        Distance of each outline point from its mask's centroid along the normal, px
        (``RaySet.radii``).
    """

    directions: np.ndarray
    weights: np.ndarray
    hinge_in: np.ndarray
    hinge_out: np.ndarray
    two_sided: np.ndarray
    offsets: np.ndarray
    radii: np.ndarray

    def __len__(self):
        return len(self.directions)


def stack_rays(ray_sets):
    """Stack the :class:`sqfit.views.rays.RaySet` of ``k`` factors (each from :func:`camera_rays`, all of
    the same length) into a :class:`StackedRays`."""
    ray_sets = list(ray_sets)
    if not ray_sets:
        raise ValueError("ray_sets must not be empty")
    lengths = sorted({len(r) for r in ray_sets})
    if len(lengths) > 1:
        raise ValueError(f"ray_sets must all have the same number of rays, got lengths {lengths}")
    hinge_in, hinge_out = [], []
    for r in ray_sets:
        inside, outside = np.zeros(len(r), dtype=bool), np.zeros(len(r), dtype=bool)
        inside[r._hinge_in], outside[r._hinge_out] = True, True
        hinge_in.append(inside)
        hinge_out.append(outside)
    return StackedRays(np.stack([r.directions for r in ray_sets]), np.stack([r.weights for r in ray_sets]),
                       np.stack(hinge_in), np.stack(hinge_out), np.stack([r.two_sided for r in ray_sets]),
                       np.stack([r.offsets for r in ray_sets]), np.stack([r.radii for r in ray_sets]))


def batch_silhouette_residuals(T_world_camera, T_world_sq, shape, rays, d0=None, offset=None, start="nearest", rows=None):
    """:func:`silhouette_residuals` of ``k`` factors at once (one vectorised ray solve).

    The same residuals and Jacobians (``tests/test_graph.py`` compares them), computed on all the
    factors' rays together: a single factor's evaluation is dominated by numpy's per-call overhead
    on 32 rays, so a graph's factors evaluated together cost little more than one of them.

    Parameters
    ----------
    T_world_camera, T_world_sq : (k, 4, 4) float
        Each factor's camera and landmark poses.
    shape : (k, 5) float
        Clipped to ``[EVAL_LOWER, EVAL_UPPER]`` (zero Jacobian columns where clipped).
    rays : StackedRays
        ``k`` factors of ``n`` rays (:func:`stack_rays`).
    d0 : (k, n) float, optional
        Warm start of the ray minimisers; NaN rows (or entries): no warm start there.
    offset : (k,) float, optional
        Each factor's outline offset δ, px (> 0: the mask is too big): every outline ray goes
        through its outline point moved by ``-δ`` along the normal (bearing ``b + δ offsets``), and
        for ``δ < 0`` its residual is weighted ``exp(-δ / radius)``: the 3G/3H residual with the
        offset as estimated there (:func:`sqfit.fitting.raycost.posed_ray_residuals`; README "Real
        masks"), so a superquadric grown by as much cannot buy a lower relative cost.
    start : str
        Where a ray without a warm start begins its solve (:func:`sqfit.fitting.line_gauge.gauge_minima`):
        ``"nearest"`` (the default) at the line's point nearest the landmark's centre, ``"grid"``
        at the best point of a grid over its bracket, as the fitter's stages do. Both find the
        one minimum along the line (to ~1e-10 relative in depth); "nearest" costs one evaluation
        where the grid costs 24: on the evaluation scenes the ray solves were a fifth of the
        graph's CPU time with the grid (docs/slam-history.md "Issue 23, seventh pass").
    rows : (k,) int, optional
        The factors' rows in ``rays``, which then holds ``m >= k`` factors (a graph's rays, stacked
        once: :class:`sqfit.graph.factors.SilhouetteFactors`); default: ``rays`` holds exactly the
        ``k`` factors. The compiled kernel reads the rows in place; gathering them per evaluation
        cost the factor graph's batch about 6 % of its CPU (docs/slam-history.md, thirtieth pass).

    Returns
    -------
    r : (k, n) float
    J_camera, J_landmark : (k, n, 6) float
    J_shape : (k, n, 5) float
    d : (k, n) float
    J_offset : (k, n) float
        ``d r / d δ`` (per px); only when ``offset`` is given.
    """
    k, gather = len(T_world_camera), rows is not None
    rows = np.asarray(rows if gather else np.arange(len(rays)), dtype=np.int64)
    if rows.shape != (k,) or (k and (rows.min() < 0 or rows.max() >= len(rays))):
        raise ValueError(f"rows must be {k} indices into the {len(rays)} factors of rays, got {rows.tolist()}")
    kernels = compiled("views") if offset is None and d0 is None else None
    if kernels is not None:  # the same numbers in one compiled loop (sqfit.kernels.view_kernels)
        f = np.ascontiguousarray
        return kernels.silhouette_rows(f(T_world_camera, dtype=np.float64), f(T_world_sq, dtype=np.float64),
                                       f(shape, dtype=np.float64), rows, f(rays.directions, dtype=np.float64),
                                       f(rays.weights, dtype=np.float64), f(rays.hinge_in), f(rays.hinge_out),
                                       f(rays.two_sided), EVAL_LOWER, EVAL_UPPER, *solver_args(start=start),
                                       *CROSSING_ARGS)
    if gather:
        rays = StackedRays(*(getattr(rays, field.name)[rows] for field in fields(StackedRays)))
    R_c, t_c = T_world_camera[:, :3, :3], T_world_camera[:, :3, 3]
    R_l, t_l = T_world_sq[:, :3, :3], T_world_sq[:, :3, 3]
    R_sc = np.einsum("kji,kjl->kil", R_l, R_c)  # R_l^T R_c
    t_sc = np.einsum("kji,kj->ki", R_l, t_c - t_l)
    b = rays.directions
    if offset is not None:
        offset = np.asarray(offset, dtype=np.float64)
        b = b + offset[:, None, None] * rays.offsets
    k, n = b.shape[:2]
    ul = np.einsum("kij,knj->kni", R_sc, b)  # landmark-frame directions
    origins = np.broadcast_to(t_sc[:, None, :], (k, n, 3))
    clipped = np.clip(shape, EVAL_LOWER, EVAL_UPPER)
    a = np.repeat(clipped[:, :3], n, axis=0)
    rel0, ul_flat = origins.reshape(k * n, 3), ul.reshape(k * n, 3)
    ratio = np.repeat(clipped[:, :3].max(axis=1) / clipped[:, :3].min(axis=1), n)
    e1, e2 = np.repeat(clipped[:, 3], n), np.repeat(clipped[:, 4], n)
    # the landmark sits at the identity pose in its own frame: ray_minima's solver on the unit-size
    # coordinates directly, each ray with its own factor's size and powers
    d, _ = gauge_minima(np.ascontiguousarray((rel0 / a).T), np.ascontiguousarray((ul_flat / a).T), rel0, ul_flat,
                         ratio, e1, e2, None if d0 is None else np.reshape(d0, k * n), start=start)
    d = d.reshape(k, n)
    y = origins + d[..., None] * ul
    # the factors of one landmark share its shape: one Jacobian call per distinct shape, not per factor
    log_m, d_log_m = np.empty((k, n)), np.empty((k, n, C.N_PARAMS))
    shapes, which = np.unique(clipped, axis=0, return_inverse=True)
    for j, sj in enumerate(shapes):
        rows = np.flatnonzero(which.ravel() == j)
        xi = np.zeros((1, C.N_PARAMS))
        xi[0, :N_SHAPE] = sj
        lm, dlm = batch_log_gauge_jacobian(xi, y[rows].reshape(1, -1, 3))
        crossing_correction(xi, y[rows].reshape(1, -1, 3), ul[rows].reshape(1, -1, 3), dlm)
        log_m[rows], d_log_m[rows] = lm.reshape(len(rows), n), dlm.reshape(len(rows), n, C.N_PARAMS)
    phi, dphi = gauge_phi(log_m)
    active = np.where(rays.hinge_in, phi > 0, np.where(rays.hinge_out, (phi < 0) & rays.two_sided, True))
    scale = rays.weights * active
    r = scale * phi
    J = (scale * dphi)[..., None] * d_log_m
    g = -J[..., C.POSITION]
    J_landmark = np.concatenate([_cross(g, y), -g], axis=-1)
    g_c = np.einsum("kni,kij->knj", g, R_sc)
    J_camera = np.concatenate([d[..., None] * _cross(b, g_c), g_c], axis=-1)
    J_shape = J[..., :N_SHAPE] * (clipped == shape)[:, None, :]
    if offset is None:
        return r, J_camera, J_landmark, J_shape, d
    # envelope theorem again: d r / d b = d* g_c, and b moves by `offsets` per px
    J_offset = d * np.einsum("kni,kni->kn", g_c, rays.offsets)
    inward = np.minimum(offset, 0.0)[:, None]
    factor = np.exp(-inward / rays.radii)
    r = r * factor
    J_camera, J_landmark, J_shape = (a * factor[..., None] for a in (J_camera, J_landmark, J_shape))
    J_offset = J_offset * factor - np.where(inward < 0, r / rays.radii, 0.0)
    return r, J_camera, J_landmark, J_shape, d, J_offset


def bounded_residuals(r, jacobians, scale):
    """Ray residuals bounded by ``scale``: ``r' = r / sqrt(1 + (r / c)^2)``, and their Jacobians.

    For landmarks whose outline one superquadric cannot graze (a table's legs, a lamp's stand: the
    initial fit's stage 3T left the grazing cost, :func:`sqfit.graph.solve`): a ray the part sticks
    out along pulls with at most ``c``, so it cannot drag the landmark to it (a Geman-McClure-like
    loss, ``r'^2 = r^2 / (1 + r^2 / c^2)``); small residuals are unchanged to second order. Exact
    Jacobians (``d r' / d r = (1 + (r / c)^2)^(-3/2)``), so the factor stays a smooth function.

    Parameters
    ----------
    r : (k, n) float
        Ray residuals of ``k`` factors.
    jacobians : sequence of (k, n, ...) float
        Their Jacobians (any number; rows first).
    scale : (k,) float
        ``c`` per factor, > 0; ``inf``: that factor's rows unchanged.

    Returns
    -------
    r : (k, n) float
    jacobians : list of (k, n, ...) float
    """
    ratio = r / np.asarray(scale, dtype=np.float64)[:, None]
    grow = 1.0 + ratio * ratio
    slope = grow ** -1.5
    return r / np.sqrt(grow), [J * slope.reshape(slope.shape + (1,) * (J.ndim - 2)) for J in jacobians]


def left_grazing(result):
    """Whether a fit's stage 3T (:mod:`sqfit.fitting.outline`) moved it: the grazing cost could not
    be met (legs, a stand, a handle) and the fit is the one that overlaps the mask contours best.

    Parameters
    ----------
    result : sqfit.FitResult

    Returns
    -------
    bool
        False when the chain has no 3T, or 3T kept its input.
    """
    before = None
    for record in result.stages:
        if (record.name == "3T" and before is not None and record.superquadric is not None
                and not np.array_equal(record.superquadric.to_vector(), before.to_vector())):
            return True
        before = record.superquadric
    return False


def _moved(rays, origins, directions, offsets=None):
    """``rays`` with new origins and directions (and ``offsets``, if given) and every other per-ray
    array kept (e.g. a visibility flag), without re-running RaySet's validation: the arrays are
    checked once, where the rays are made, and this runs at every evaluation of every factor
    (measured: validation was a tenth of a batch solve)."""
    moved = object.__new__(type(rays))
    moved.__dict__.update(rays.__dict__, origins=origins, directions=directions)
    if offsets is not None:
        moved.__dict__["offsets"] = offsets
    return moved


def _cross(a, b):
    """Row-wise cross product of ``(..., 3)`` arrays (``np.cross`` costs more in overhead here)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def bounds_residuals(shape, weight=C.PENALTY_ANALYTIC):
    """The paper's bound penalty (eq. 7) on the size/shape vector: ``a >= SIZE_MIN``, ``e`` in
    ``SHAPE_BOUNDS``.

    Parameters
    ----------
    shape : (5,) float
    weight : float
        ``c_p``.

    Returns
    -------
    r : (5,) float
    J : (5, 5) float
    """
    shape = np.asarray(shape, dtype=np.float64)
    r = weight * (np.maximum(_SHAPE_LO - shape, 0.0) + np.maximum(shape - _SHAPE_HI, 0.0))
    J = np.diag(weight * ((shape > _SHAPE_HI).astype(float) - (shape < _SHAPE_LO).astype(float)))
    return r, J


def landmark_to_superquadric(T_world_sq, shape):
    """A :class:`sqfit.Superquadric` from a landmark (``|a|``, ``e`` clipped to the valid domain)."""
    from ..geometry.superquadric import matrix_to_euler

    T = check_shape(T_world_sq, (4, 4), "T_world_sq")
    shape = check_shape(shape, (N_SHAPE,), "shape")
    xi = np.concatenate([shape, T[:3, 3], matrix_to_euler(T[:3, :3])])
    return to_superquadric(xi)


def superquadric_to_landmark(sq):
    """``(T_world_sq (4, 4), shape (5,))`` of a :class:`sqfit.Superquadric`."""
    if not isinstance(sq, Superquadric):
        raise TypeError(f"sq must be a sqfit.Superquadric, got {type(sq).__name__}")
    return sq.pose, np.concatenate([sq.size, sq.shape])
