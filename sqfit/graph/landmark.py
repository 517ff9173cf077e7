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

The residual of a view is :func:`sqfit.raycost.ray_residuals` evaluated in the landmark's own frame
(rays moved there by ``T_sq_camera``, the superquadric at the identity pose): it is the 3G residual
of the same rays, with the same modes, weights and any per-ray flags the ray set carries (the
function is taken from :mod:`sqfit.raycost`, not re-derived). By the envelope theorem the residual
depends on a pose only through the point ``y* = o + d* b`` where the ray comes closest to the
superquadric (in gauge), so with ``g = d r / d y`` at that point (landmark frame):

- landmark: ``y' = Exp(-delta) y`` gives ``d r / d omega = g x y``, ``d r / d v = -g``;
- camera: ``y(d) = t_sc + d R_sc b`` with ``R_sc' = R_sc exp([omega]x)``, ``t_sc' = t_sc + R_sc v``
  gives ``d r / d omega = d* (b x g_c)``, ``d r / d v = g_c`` with ``g_c = R_sc^T g``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import constants as C
from .._checks import check_shape
from ..costs import LOWER_BOUNDS, UPPER_BOUNDS
from ..observation import Observation
from ..pipeline import to_superquadric
from ..raycost import ray_residuals
from ..rays import contour_rays
from ..superquadric import Superquadric

__all__ = ["N_SHAPE", "camera_rays", "silhouette_residuals", "bounds_residuals", "landmark_to_superquadric",
           "superquadric_to_landmark", "relative_pose", "EVAL_LOWER", "EVAL_UPPER"]

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
        ``origins`` all zero, ``directions`` the pixel bearings ``(n, 3)`` with unit depth (camera
        frame); modes, weights and any other per-ray arrays as :func:`sqfit.rays.contour_rays`
        gives them.
    """
    if not isinstance(observation, Observation):
        raise TypeError(f"observation must be a sqfit.Observation, got {type(observation).__name__}")
    rays = contour_rays([observation], n_contour)
    directions = rays.directions @ observation.camera.rotation  # R^T d per row
    return replace(rays, origins=np.zeros_like(directions), directions=directions)


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
        Weighted ray residuals (:func:`sqfit.raycost.ray_residuals`).
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


def _moved(rays, origins, directions):
    """``rays`` with new origins and directions and every other per-ray array kept (e.g. a
    visibility flag), without re-running RaySet's validation: the arrays are checked once, where the
    rays are made, and this runs at every evaluation of every factor (measured: validation was a
    tenth of a batch solve)."""
    moved = object.__new__(type(rays))
    moved.__dict__.update(rays.__dict__, origins=origins, directions=directions)
    return moved


def _cross(a, b):
    """Row-wise cross product of ``(n, 3)`` arrays (``np.cross`` costs more in overhead here)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


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
    from ..superquadric import matrix_to_euler

    T = check_shape(T_world_sq, (4, 4), "T_world_sq")
    shape = check_shape(shape, (N_SHAPE,), "shape")
    xi = np.concatenate([shape, T[:3, 3], matrix_to_euler(T[:3, :3])])
    return to_superquadric(xi)


def superquadric_to_landmark(sq):
    """``(T_world_sq (4, 4), shape (5,))`` of a :class:`sqfit.Superquadric`."""
    if not isinstance(sq, Superquadric):
        raise TypeError(f"sq must be a sqfit.Superquadric, got {type(sq).__name__}")
    return sq.pose, np.concatenate([sq.size, sq.shape])
