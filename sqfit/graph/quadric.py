"""QuadricSLAM's formulation (Nicholson, Milford and Suenderhauf, "QuadricSLAM: dual quadrics from
object detections as landmarks in object-oriented SLAM", RA-L 2019), re-implemented from the paper
as the baseline of the factor graph (numpy only; the gtsam wrapper is
:func:`sqfit.graph.factors.box_factor`).

- A landmark is a constrained dual quadric, an ellipsoid: a pose ``Z = T_world_quadric`` (4, 4)
  and radii ``r`` (3,), metres; ``Q* = Z diag(r_x^2, r_y^2, r_z^2, -1) Z^T``.
- A camera ``T_world_camera`` projects it to the dual conic ``C* = P Q* P^T`` with
  ``P = K [I | 0] T_world_camera^-1``.
- The box of a dual conic: a vertical line ``u = x`` is ``l = (1, 0, -x)``, tangent iff
  ``l^T C* l = 0``, so ``x = (C_02 +- sqrt(C_02^2 - C_00 C_22)) / C_22``; ``v`` alike with row 1.
- The residual of a detection is ``box(C*) - box_detected`` (4,), pixels, order
  ``[u_min, v_min, u_max, v_max]``; Jacobians by the chain rule through ``C*`` with the pose
  convention of :mod:`sqfit.graph.landmark` (``T' = T Exp([omega, v])``).
- Initialisation (the paper's): each box side back-projects to a plane ``pi = P^T l`` tangent to
  the quadric, ``pi^T Q* pi = 0`` is linear in the 10 entries of ``Q*``; the SVD null vector,
  made an ellipsoid (radii floored at ``SIZE_MIN``), starts the optimisation.

The paper's truncated-box handling is not reproduced: detections touching the image border are
left out by the caller (:mod:`sqfit.graph.solve`).
"""

from __future__ import annotations

import numpy as np

from .. import constants as C
from ..geometry.superquadric import Superquadric, matrix_to_euler

__all__ = ["dual_quadric", "projected_conic", "conic_box", "box_residuals", "initialise_quadric",
           "quadric_to_superquadric", "observation_box"]

#: Floor of the discriminants under the square roots (a degenerate conic gives a finite box).
_DISC_MIN = 1e-12


def _generators():
    G = np.zeros((6, 4, 4))
    for k, (i, j) in enumerate([(1, 2), (2, 0), (0, 1)]):  # [omega]x for omega = e_k
        G[k, i, j], G[k, j, i] = -1.0, 1.0
    for k in range(3):
        G[3 + k, k, 3] = 1.0
    return G


_G = _generators()


def dual_quadric(T_world_quadric, radii):
    """``(4, 4) float``: ``Q* = Z diag(r^2, -1) Z^T``."""
    D = np.diag(np.concatenate([np.asarray(radii, dtype=np.float64) ** 2, [-1.0]]))
    return T_world_quadric @ D @ T_world_quadric.T


def _projection(T_world_camera, K):
    return K @ np.linalg.inv(T_world_camera)[:3]


def projected_conic(T_world_camera, T_world_quadric, radii, K):
    """``(3, 3) float``: the dual conic ``C* = P Q* P^T`` of the quadric in the image."""
    P = _projection(T_world_camera, K)
    return P @ dual_quadric(T_world_quadric, radii) @ P.T


def _box_and_gradient(C_):
    """Box ``[u_min, v_min, u_max, v_max]`` of a dual conic and ``d box / d C`` as (4, 3, 3)."""
    box, grad = np.empty(4), np.zeros((4, 3, 3))
    c22 = C_[2, 2]
    for axis in (0, 1):
        caa, ca2 = C_[axis, axis], C_[axis, 2]
        disc = ca2 * ca2 - caa * c22
        s = np.sqrt(max(disc, _DISC_MIN))
        live = disc > _DISC_MIN
        roots = []
        for sign in (1.0, -1.0):
            x = (ca2 + sign * s) / c22
            g = np.zeros((3, 3))
            ds = 1.0 / (2.0 * s) if live else 0.0  # d s / d disc
            g[axis, 2] = (1.0 + sign * ds * 2.0 * ca2) / c22
            g[axis, axis] = -sign * ds * c22 / c22
            g[2, 2] = (-sign * ds * caa) / c22 - x / c22
            roots.append((x, g))
        lo, hi = sorted(roots, key=lambda t: t[0])
        box[axis], grad[axis] = lo
        box[axis + 2], grad[axis + 2] = hi
    return box, grad


def conic_box(C_):
    """``(4,) float``: the box ``[u_min, v_min, u_max, v_max]`` of a dual conic (pixels)."""
    return _box_and_gradient(np.asarray(C_, dtype=np.float64))[0]


def box_residuals(T_world_camera, T_world_quadric, radii, K, box):
    """QuadricSLAM's box residual of one detection and its Jacobians.

    Parameters
    ----------
    T_world_camera, T_world_quadric : (4, 4) float
    radii : (3,) float
    K : (3, 3) float
    box : (4,) float
        Detected ``[u_min, v_min, u_max, v_max]``, pixels.

    Returns
    -------
    r : (4,) float
        Predicted minus detected box, pixels.
    J_camera, J_quadric : (4, 6) float
        ``d r / d delta`` of the poses (convention of :mod:`sqfit.graph.landmark`).
    J_radii : (4, 3) float
    """
    radii = np.asarray(radii, dtype=np.float64)
    T_inv = np.linalg.inv(T_world_camera)
    P = K @ T_inv[:3]
    Z = T_world_quadric
    D = np.diag(np.concatenate([radii ** 2, [-1.0]]))
    Q = Z @ D @ Z.T
    C_ = P @ Q @ P.T
    box_pred, grad = _box_and_gradient(C_)
    # camera: T^-1 -> Exp(-delta) T^-1, so dP = -K [I|0] G T^-1
    dP = -np.einsum("ij,kjl,lm->kim", K, _G[:, :3, :], T_inv)
    PQ = P @ Q
    dC_cam = np.einsum("kij,jl->kil", dP, PQ.T)
    dC_cam = dC_cam + dC_cam.transpose(0, 2, 1)
    dZ = np.einsum("ij,kjl->kil", Z, _G)  # Z -> Z Exp(delta)
    dQ = np.einsum("kij,jl->kil", dZ, D @ Z.T)
    dQ = dQ + dQ.transpose(0, 2, 1)
    dC_q = np.einsum("ij,kjl,ml->kim", P, dQ, P)
    dQ_r = np.einsum("ik,k,jk->kij", Z[:, :3], 2.0 * radii, Z[:, :3])
    dC_r = np.einsum("ij,kjl,ml->kim", P, dQ_r, P)
    J = lambda dC: np.einsum("bij,kij->bk", grad, dC)  # noqa: E731  (d box / d C : dC)
    return box_pred - np.asarray(box, dtype=np.float64), J(dC_cam), J(dC_q), J(dC_r)


def observation_box(observation):
    """``(4,) float``: the detected box ``[u_min, v_min, u_max, v_max]`` of an observation's mask
    (pixel edges, from its contour)."""
    c = observation.contour
    return np.concatenate([c.min(axis=0), c.max(axis=0)])


def initialise_quadric(T_world_cameras, K, boxes):
    """QuadricSLAM's linear initialisation of an ellipsoid from boxes in several views.

    Parameters
    ----------
    T_world_cameras : (v, 4, 4) float
    K : (3, 3) float
    boxes : (v, 4) float

    Returns
    -------
    T_world_quadric : (4, 4) float or None
    radii : (3,) float or None
        None when the views do not determine a quadric (fewer than 3 views, or the solution's
        centre is not in front of every camera).
    """
    T_world_cameras, boxes = np.asarray(T_world_cameras, float), np.asarray(boxes, float)
    if len(boxes) < 3:
        return None, None
    rows = []
    iu = np.triu_indices(4)
    scale = np.where(iu[0] == iu[1], 1.0, 2.0)
    for T, (u0, v0, u1, v1) in zip(T_world_cameras, boxes):
        P = _projection(T, K)
        for line in ([1.0, 0.0, -u0], [1.0, 0.0, -u1], [0.0, 1.0, -v0], [0.0, 1.0, -v1]):
            pi = P.T @ np.array(line)
            pi /= np.linalg.norm(pi)
            rows.append(scale * np.outer(pi, pi)[iu])
    q = np.linalg.svd(np.array(rows))[2][-1]
    Q = np.zeros((4, 4))
    Q[iu] = q
    Q = Q + Q.T - np.diag(np.diag(Q))
    if abs(Q[3, 3]) < 1e-12:
        return None, None
    Q = -Q / Q[3, 3]
    centre = -Q[:3, 3]
    M = Q[:3, :3] + np.outer(centre, centre)
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    for T in T_world_cameras:
        if (centre - T[:3, 3]) @ T[:3, 2] <= 0:
            return None, None
    Z = np.eye(4)
    Z[:3, :3], Z[:3, 3] = V, centre
    return Z, np.sqrt(np.maximum(w, C.SIZE_MIN ** 2))


def quadric_to_superquadric(T_world_quadric, radii):
    """The ellipsoid as a :class:`sqfit.Superquadric` (``e1 = e2 = 1``), for the same metrics."""
    return Superquadric(np.maximum(np.abs(radii), 1e-6), (1.0, 1.0), T_world_quadric[:3, 3],
                        matrix_to_euler(T_world_quadric[:3, :3]))
