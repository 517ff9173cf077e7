"""Compiled (numba) image velocities of silhouette vertices (stage 3U's union gradient).

:func:`vertex_velocities` is :func:`sqfit.geometry.silhouette.vertex_velocities` per vertex: the
derivative of each vertex's projection by the 11 parameters, its touching point held fixed in the
superquadric's parametrisation. Stage 3U (:func:`sqfit.fitting.two_parts.union_gradient`) takes them
about 2400 times per object where it fits two parts; the numpy version's stacked ``(2, v, K, 2, 3)``
matrix products take 0.20 ms per call on a lamp's union, nearly all per-call overhead, this loop 0.03 ms
(``benchmarks/bench_union.py``, 6 lamps).

Sums run in index order (numpy's matmul may round differently: the velocities agree to 1e-10
relative, tested). No ``fastmath``. Importing this module imports numba; :mod:`sqfit.kernels.backend` does
that lazily, and the kernels are cached next to this file (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["vertex_velocities"]

_TINY = 1e-300
_JIT = dict(cache=True, error_model="numpy", nogil=True)


@njit(**_JIT)
def _shape_derivatives(s0, s1, s2, e1, e2, ds):
    """``sqfit.geometry.silhouette._unit_point_shape_derivatives`` of one unit point into ``ds`` ``(2, 3)``:
    ``ds[j] = d s / d e_(j+1)`` at fixed angles of the parametrisation."""
    a0, a1, a2 = abs(s0), abs(s1), abs(s2)
    big = max(a0, a1)
    t = min(a0, a1) / (big + _TINY)
    log_a = math.log(big + _TINY) + 0.5 * e2 * math.log1p(t ** (2.0 / e2))
    slog0 = s0 * math.log(a0 + _TINY) if a0 > 0 else 0.0
    slog1 = s1 * math.log(a1 + _TINY) if a1 > 0 else 0.0
    slog2 = s2 * math.log(a2 + _TINY) if a2 > 0 else 0.0
    ds[0, 0], ds[0, 1], ds[0, 2] = s0 * log_a / e1, s1 * log_a / e1, slog2 / e1
    ds[1, 0], ds[1, 1], ds[1, 2] = (slog0 - s0 * log_a) / e2, (slog1 - s1 * log_a) / e2, 0.0


@njit(**_JIT)
def vertex_velocities(xi, R_sq, dR, unit_points, points, rotations, intrinsics, e_min, e_max):
    """:func:`sqfit.geometry.silhouette.vertex_velocities`: ``xi`` ``(b, 11)``, ``R_sq`` ``(b, 3, 3)`` and
    ``dR`` ``(b, 3, 3, 3)`` (``rotation_and_derivatives`` of each row's angles), the touching points
    ``unit_points`` and ``points`` ``(b, v, K, 3)`` (:func:`sqfit.kernels.silhouette_kernels.touching_silhouettes`),
    cameras as ``camera_arrays``, the exponents' range -> ``(b, v, K, 2, 11)``."""
    b, v, k = points.shape[0], points.shape[1], points.shape[2]
    out = np.empty((b, v, k, 2, 11))
    rows, rows_w, rows_sq = np.empty((2, 3)), np.empty((2, 3)), np.empty((2, 3))
    ds, local, dx = np.empty((2, 3)), np.empty(3), np.empty((3, 3))
    a, sign, inside = np.empty(3), np.empty(3), np.empty(2)
    for s in range(b):
        for j in range(3):
            a[j] = abs(xi[s, j])
            sign[j] = -1.0 if xi[s, j] < 0 else 1.0
        e1 = min(max(xi[s, 3], e_min), e_max)
        e2 = min(max(xi[s, 4], e_min), e_max)
        inside[0] = 1.0 if e1 == xi[s, 3] else 0.0
        inside[1] = 1.0 if e2 == xi[s, 4] else 0.0
        for t in range(v):
            fx, fy = intrinsics[t, 0], intrinsics[t, 1]
            for m in range(k):
                px, py, iz = points[s, t, m, 0], points[s, t, m, 1], 1.0 / points[s, t, m, 2]
                rows[0, 0], rows[0, 1], rows[0, 2] = fx * iz, 0.0, -fx * px * iz ** 2
                rows[1, 0], rows[1, 1], rows[1, 2] = 0.0, fy * iz, -fy * py * iz ** 2
                for r in range(2):  # d pi / d p (world frame: rows R^T of the camera), then the superquadric's
                    for c in range(3):
                        rows_w[r, c] = (rows[r, 0] * rotations[t, c, 0] + rows[r, 1] * rotations[t, c, 1]
                                        + rows[r, 2] * rotations[t, c, 2])
                    for c in range(3):
                        rows_sq[r, c] = (rows_w[r, 0] * R_sq[s, 0, c] + rows_w[r, 1] * R_sq[s, 1, c]
                                         + rows_w[r, 2] * R_sq[s, 2, c])
                u0, u1, u2 = unit_points[s, t, m, 0], unit_points[s, t, m, 1], unit_points[s, t, m, 2]
                _shape_derivatives(u0, u1, u2, e1, e2, ds)
                for j in range(3):
                    local[j] = unit_points[s, t, m, j] * a[j]
                for g in range(3):  # d x / d r_g = dR_g (a * s)
                    for c in range(3):
                        dx[g, c] = dR[s, g, c, 0] * local[0] + dR[s, g, c, 1] * local[1] + dR[s, g, c, 2] * local[2]
                for r in range(2):
                    for j in range(3):
                        out[s, t, m, r, j] = rows_sq[r, j] * (unit_points[s, t, m, j] * sign[j])
                    for j in range(2):
                        acc = 0.0
                        for c in range(3):
                            acc += rows_sq[r, c] * (ds[j, c] * a[c] * inside[j])
                        out[s, t, m, r, 3 + j] = acc
                    for c in range(3):
                        out[s, t, m, r, 5 + c] = rows_w[r, c]
                    for g in range(3):
                        out[s, t, m, r, 8 + g] = (rows_w[r, 0] * dx[g, 0] + rows_w[r, 1] * dx[g, 1]
                                                  + rows_w[r, 2] * dx[g, 2])
    return out
