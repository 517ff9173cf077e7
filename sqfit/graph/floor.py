"""A known floor under the landmarks: the one metric cue a sequence of silhouettes can be given.

Silhouettes are scale-free (:mod:`sqfit.graph.scale`), so the graph's scale comes from the odometry
alone. When the caller knows the height ``floor_z`` of the plane the objects stand on, in the world
frame of the poses (a camera at a known height above the floor in a gravity-aligned frame; in a
simulated ``ground`` scene, ``z = 0``), each landmark's lowest point measures that scale: scaling
the map by ``s`` about frame 0's camera moves a point on the floor by ``(s - 1)`` times the camera's
height above it. This is information the images and odometry do not carry; the graph uses it only
when asked (``GraphOptions.floor_z``).

The lowest point of a superquadric: with ``n = R^T e_z`` (world up in the landmark's frame) and
``m = a * n``, the height of its highest point above its centre along ``n`` is the support function
``h = ((|m_x|^q2 + |m_y|^q2)^(q1 / q2) + |m_z|^q1)^(1 / q1)``, ``q_i = 2 / (2 - e_i)`` (the dual of
the superquadric's nested norm with powers ``2 / e_i``; convex shapes, ``e <= 2``), and by symmetry
its lowest point lies ``h`` below the centre. Jacobians follow :mod:`sqfit.graph.landmark`'s pose
convention (``T' = T Exp([omega, v])``): ``n' = n + n x omega``, ``t' = t + R v``.
"""

from __future__ import annotations

from math import copysign

import numpy as np

from .landmark import EVAL_LOWER, N_SHAPE

__all__ = ["lowest_point_height", "floor_residual", "FLOOR_SHAPE_MAX"]

#: The shape exponents are clipped to at most this in the support function (``q = 2 / (2 - e)``
#: grows without bound at ``e = 2``); the bound penalty keeps them below 1.9.
FLOOR_SHAPE_MAX = 1.95
#: Central-difference step of the support function's derivative in the shape exponents.
_E_STEP = 1e-6
#: ``EVAL_LOWER`` as floats (the factor runs on plain floats).
_LOWER = EVAL_LOWER.tolist()


def _support(m, e):
    """``(h, dh/dm)`` of the direction ``m = a * n`` (3 floats) for exponents ``e = (e1, e2)``, in
    plain floats: the floor factor runs this at every evaluation, where numpy's per-call overhead
    on 3-vectors cost ~10 times the arithmetic (``benchmarks/bench_graph.py`` profile)."""
    q1, q2 = 2.0 / (2.0 - e[0]), 2.0 / (2.0 - e[1])
    x0, x1, x2 = abs(m[0]), abs(m[1]), abs(m[2])
    A = x0 ** q2 + x1 ** q2
    h = (A ** (q1 / q2) + x2 ** q1) ** (1.0 / q1)
    if h == 0.0:
        return 0.0, (0.0, 0.0, 0.0)
    c = h ** (1.0 - q1)
    g2 = c * x2 ** (q1 - 1.0)
    if A > 0.0:
        cA = c * A ** (q1 / q2 - 1.0)
        g0, g1 = cA * x0 ** (q2 - 1.0), cA * x1 ** (q2 - 1.0)
    else:
        g0 = g1 = 0.0
    return h, tuple(copysign(g, mi) if mi != 0.0 else 0.0 for g, mi in zip((g0, g1, g2), m))


def lowest_point_height(T_world_sq, shape):
    """World ``z`` of a landmark's lowest point.

    Parameters
    ----------
    T_world_sq : (4, 4) float
        Landmark pose (superquadric -> world, world +z up).
    shape : (5,) float
        ``[ax, ay, az, e1, e2]``; ``a`` clipped below at ``EVAL_LOWER``, ``e`` to
        ``[EVAL_LOWER, FLOOR_SHAPE_MAX]``.

    Returns
    -------
    z : float
    """
    T, shape = np.asarray(T_world_sq, dtype=np.float64), np.asarray(shape, dtype=np.float64)
    a, e = _clipped(shape.tolist())
    n = T[2, :3].tolist()
    return float(T[2, 3] - _support([a[k] * n[k] for k in range(3)], e)[0])


def _clipped(s):
    """Half-axes and exponents of a size/shape list ``s`` (5 floats), clipped as the support function
    needs (:func:`lowest_point_height`), as two lists of floats."""
    lo = _LOWER
    return ([max(s[k], lo[k]) for k in range(3)],
            [min(max(s[3 + k], lo[3 + k]), FLOOR_SHAPE_MAX) for k in range(2)])


def floor_residual(T_world_sq, shape, floor_z):
    """Height of a landmark's lowest point above the floor, and its Jacobians.

    No input checks (runs at every evaluation of the factor, on values GTSAM holds).

    Parameters
    ----------
    T_world_sq : (4, 4) float
    shape : (5,) float
    floor_z : float
        The floor's height, world frame, metres.

    Returns
    -------
    r : (1,) float
        Metres (``> 0``: the landmark floats above the floor).
    J_pose : (1, 6) float
        ``d r / d [omega, v]`` (module docstring).
    J_shape : (1, 5) float
        ``d r / d s``; the exponents' columns by central differences, zero where clipped.
    """
    n = T_world_sq[2, :3].tolist()
    s = shape.tolist()
    lo = _LOWER
    a, e = _clipped(s)
    m = [a[k] * n[k] for k in range(3)]
    h, g = _support(m, e)
    gn = [g[k] * a[k] for k in range(3)]  # dh/dn
    # dh/domega = gn . (n x omega) = (gn x n) . omega; the pose rows are -(gn x n) and n
    J_pose = np.array([[gn[2] * n[1] - gn[1] * n[2], gn[0] * n[2] - gn[2] * n[0], gn[1] * n[0] - gn[0] * n[1],
                        n[0], n[1], n[2]]])
    J_shape = np.zeros((1, N_SHAPE))
    for k in range(3):
        if s[k] >= lo[k]:
            J_shape[0, k] = -g[k] * n[k]
    for k in range(2):
        if lo[3 + k] <= s[3 + k] <= FLOOR_SHAPE_MAX:
            up, down = list(e), list(e)
            up[k] += _E_STEP
            down[k] -= _E_STEP
            J_shape[0, 3 + k] = -(_support(m, up)[0] - _support(m, down)[0]) / (2.0 * _E_STEP)
    return np.array([float(T_world_sq[2, 3]) - h - floor_z]), J_pose, J_shape
