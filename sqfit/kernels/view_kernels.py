"""Compiled (numba) kernel of the factor graph's silhouette residuals: posed views of posed superquadrics.

:func:`silhouette_rows` is :func:`sqfit.graph.landmark.batch_silhouette_residuals` without an
outline offset: for ``k`` factors (a camera pose, a landmark pose and a size/shape vector each) and
``n`` camera-frame rays per factor, the 3G ray residuals and their Jacobians with respect to the
camera pose, the landmark pose and the size/shape vector, each ray solved by
:func:`sqfit.kernels.ray_kernels.ray_minimiser` and its gauge differentiated by
:func:`sqfit.kernels.ray_kernels.log_gauge_point`, in one loop. The numpy code evaluates the same
formulas through a dozen vectorised calls (einsums, stackings, a Jacobian call per distinct shape),
whose overhead on a graph's few thousand rays was two thirds of an evaluation; here one call. The
same operations as the numpy code, but where numpy sums through an einsum the loop sums in
index order, so the two agree to rounding (``tests/test_graph.py``: 1e-12).

Importing this module imports numba; :mod:`sqfit.kernels.backend` does that lazily (part
``"views"``). Compiled on first use and cached next to this file.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .ray_kernels import crossing_fix, log_gauge_point, nan_max, nan_min, ray_minimiser, rotation

__all__ = ["silhouette_rows"]

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@njit(**_JIT)
def _clip(x, lo, hi):
    """``np.clip`` of one float (NaN stays NaN)."""
    if x != x:
        return x
    return lo if x < lo else (hi if x > hi else x)


@njit(**_JIT)
def silhouette_rows(T_world_camera, T_world_sq, shape, rows, directions, weights, hinge_in, hinge_out, two_sided,
                    lower, upper, rtol, max_newton, max_warm, grid, znear, warm_bracket, newton_power, crossing_tol,
                    crossing_parallel):
    """:func:`sqfit.graph.landmark.batch_silhouette_residuals` (no offset, no warm start).

    ``T_world_camera``, ``T_world_sq`` ``(k, 4, 4)``; ``shape`` ``(k, 5)``, clipped to ``[lower,
    upper]`` (zero Jacobian columns where clipped); ``rows`` ``(k,)`` int64, each factor's row in the
    ray arrays, which may hold more factors (``(m, n, ...)``, ``m >= k``: a graph's pool, so no
    evaluation copies the rays of the factors it evaluates); ``directions`` ``(m, n, 3)`` camera-frame
    bearings; ``weights`` ``(m, n)``; ``hinge_in``, ``hinge_out``, ``two_sided`` ``(m, n)`` bool;
    the solver's constants as :func:`sqfit.fitting.line_gauge.solver_args` gives them, then
    :func:`sqfit.fitting.raycost.crossing_correction`'s two tolerances. Returns ``r``
    ``(k, n)``, ``J_camera``, ``J_landmark`` ``(k, n, 6)``, ``J_shape`` ``(k, n, 5)``, ``d``
    ``(k, n)``.
    """
    k, n = rows.shape[0], directions.shape[1]
    r, d = np.empty((k, n)), np.empty((k, n))
    J_camera, J_landmark, J_shape = np.empty((k, n, 6)), np.empty((k, n, 6)), np.empty((k, n, 5))
    R0, dR0 = rotation(np.zeros(3))  # the landmark at the identity pose of its own frame
    xi, d_xi, d_g3, d_point = np.zeros(11), np.empty(11), np.empty(11), np.empty(3)
    R_sc, t_sc, dc = np.empty((3, 3)), np.empty(3), np.empty(3)
    clipped, kept = np.empty(5), np.empty(5)
    for f in range(k):
        # the camera in the landmark's frame: R_l^T R_c, R_l^T (t_c - t_l)
        for i in range(3):
            dc[i] = T_world_camera[f, i, 3] - T_world_sq[f, i, 3]
        for i in range(3):
            t_sc[i] = T_world_sq[f, 0, i] * dc[0] + T_world_sq[f, 1, i] * dc[1] + T_world_sq[f, 2, i] * dc[2]
            for j in range(3):
                R_sc[i, j] = (T_world_sq[f, 0, i] * T_world_camera[f, 0, j] + T_world_sq[f, 1, i] * T_world_camera[f, 1, j]
                              + T_world_sq[f, 2, i] * T_world_camera[f, 2, j])
        for j in range(5):
            clipped[j] = _clip(shape[f, j], lower[j], upper[j])
            kept[j] = 1.0 if clipped[j] == shape[f, j] else 0.0
            xi[j] = clipped[j]
        ax, ay, az = clipped[0], clipped[1], clipped[2]
        ratio = nan_max(nan_max(ax, ay), az) / nan_min(nan_min(ax, ay), az)
        e1, e2 = clipped[3], clipped[4]
        log_a = np.log(np.abs(xi[0:3]))
        g = rows[f]
        for i in range(n):
            bx, by, bz = directions[g, i, 0], directions[g, i, 1], directions[g, i, 2]
            lx = R_sc[0, 0] * bx + R_sc[0, 1] * by + R_sc[0, 2] * bz
            ly = R_sc[1, 0] * bx + R_sc[1, 1] * by + R_sc[1, 2] * bz
            lz = R_sc[2, 0] * bx + R_sc[2, 1] * by + R_sc[2, 2] * bz
            di = ray_minimiser(t_sc[0] / ax, t_sc[1] / ay, t_sc[2] / az, lx / ax, ly / ay, lz / az, t_sc[0], t_sc[1],
                               t_sc[2], lx, ly, lz, ratio, e1, e2, 0.0, False, rtol, max_newton, max_warm, grid, znear,
                               warm_bracket, newton_power)
            d[f, i] = di
            yx, yy, yz = t_sc[0] + di * lx, t_sc[1] + di * ly, t_sc[2] + di * lz
            log_m = log_gauge_point(xi, log_a, R0, dR0, yx, yy, yz, d_xi, d_g3, d_point)
            crossing_fix(xi, R0, dR0, yx, yy, yz, lx, ly, lz, d_xi, crossing_tol, crossing_parallel)
            if log_m < 0:  # sqfit.fitting.raycost.gauge_phi
                m = math.exp(log_m)
                phi, dphi = m - 1.0, m
            else:
                phi, dphi = log_m, 1.0
            if hinge_in[g, i]:
                active = phi > 0
            elif hinge_out[g, i]:
                active = phi < 0 and two_sided[g, i]
            else:
                active = True
            scale = weights[g, i] * (1.0 if active else 0.0)
            r[f, i] = scale * phi
            w = scale * dphi
            # d r / d y (moving the centre by p moves every point by -p)
            gx, gy, gz = -(w * d_xi[5]), -(w * d_xi[6]), -(w * d_xi[7])
            J_landmark[f, i, 0] = gy * yz - gz * yy
            J_landmark[f, i, 1] = gz * yx - gx * yz
            J_landmark[f, i, 2] = gx * yy - gy * yx
            J_landmark[f, i, 3], J_landmark[f, i, 4], J_landmark[f, i, 5] = -gx, -gy, -gz
            cx = gx * R_sc[0, 0] + gy * R_sc[1, 0] + gz * R_sc[2, 0]
            cy = gx * R_sc[0, 1] + gy * R_sc[1, 1] + gz * R_sc[2, 1]
            cz = gx * R_sc[0, 2] + gy * R_sc[1, 2] + gz * R_sc[2, 2]
            J_camera[f, i, 0] = di * (by * cz - bz * cy)
            J_camera[f, i, 1] = di * (bz * cx - bx * cz)
            J_camera[f, i, 2] = di * (bx * cy - by * cx)
            J_camera[f, i, 3], J_camera[f, i, 4], J_camera[f, i, 5] = cx, cy, cz
            for j in range(5):
                J_shape[f, i, j] = w * d_xi[j] * kept[j]
    return r, J_camera, J_landmark, J_shape, d
