"""Compiled (numba) kernels of the visual hull: the carving test and the point-cloud fit's residuals.

Stage ``HULL`` (:mod:`sqfit.fitting.hull`), and stage 3R's starts from the visual hull
(:func:`sqfit.fitting.trimmed.hull_starts`), spend their time in two loops over many points:

- :func:`carve_view`, one view's part of :func:`sqfit.views.carving.carve`: project each point,
  carve it where its pixel's background clearance exceeds the reach of the ball around it, count
  the views whose image holds it. The numpy code makes a dozen temporary arrays of all the points
  per view (up to ~10^6 voxel centres at the fine level);
- :func:`radial_residuals`, :func:`sqfit.fitting.pointcloud.radial_residuals` (EMS's radial
  distances and their Jacobian, on up to 1500 points, at every step of every M-step); with numpy
  (its ``einsum`` for the rotation's derivatives included) they were about half of EMS's time in a
  pyinstrument profile (the pybullet mug, 5 fits).

``benchmarks/bench_hull.py`` measures both (README, "Fitter speed").

The same formulas in the same order as the numpy code, without ``fastmath``; the elementary functions
(numpy's ``exp``, ``log``, ``logaddexp`` against libm's) and the order of the 3-term sums may differ in
the last bit, so the two paths agree to rounding (``tests/test_hull_kernels.py``: the same carvings,
residuals within 1e-12 relative). Importing this module imports numba; :mod:`sqfit.kernels.backend`
does that lazily (part ``"hull"``). Compiled on first use and cached next to this file; it calls
:mod:`sqfit.kernels.ray_kernels`'s ``logaddexp``, whose import refreshes the cache
(:mod:`sqfit.kernels.kernel_cache`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .ray_kernels import logaddexp

__all__ = ["carve_view", "radial_residuals"]

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@njit(**_JIT)
def carve_view(points, center, rotation, fx, fy, cx, cy, width, height, clearance, radius, carved, seen):
    """One view's carving of ``points`` (:func:`sqfit.views.carving.carve`), in place.

    ``carved[i]`` is set where point ``i`` (or the ball of ``radius`` around it) lies behind the
    camera, or projects onto a pixel whose ``clearance`` exceeds the ball's reach in pixels;
    ``seen[i]`` grows by one where the point lies in front of the camera (by more than ``radius``)
    and inside the ``width`` x ``height`` image.
    """
    scale = max(fx, fy)
    for i in range(points.shape[0]):
        x0 = points[i, 0] - center[0]
        x1 = points[i, 1] - center[1]
        x2 = points[i, 2] - center[2]
        lx = x0 * rotation[0, 0] + x1 * rotation[1, 0] + x2 * rotation[2, 0]
        ly = x0 * rotation[0, 1] + x1 * rotation[1, 1] + x2 * rotation[2, 1]
        depth = x0 * rotation[0, 2] + x1 * rotation[1, 2] + x2 * rotation[2, 2]
        if depth + radius <= 0.0:
            carved[i] = True
        if not depth > radius:
            continue
        safe = depth if abs(depth) > 1e-12 else 1e-12
        col = math.floor(fx * lx / safe + cx)
        row = math.floor(fy * ly / safe + cy)
        if not (col >= 0.0 and col < width and row >= 0.0 and row < height):
            continue
        seen[i] += 1
        reach = 0.0 if radius == 0.0 else scale * radius / (depth - radius) + 1.0
        if clearance[int(row), int(col)] > reach:
            carved[i] = True


@njit(**_JIT)
def radial_residuals(xi, points, rotation, d_rotation, jacobian, d, J):
    """:func:`sqfit.fitting.pointcloud.radial_residuals` into ``d`` (and ``J`` where ``jacobian``).

    ``rotation`` and ``d_rotation`` are :func:`sqfit.geometry.superquadric.rotation_and_derivatives`
    of ``xi[8:11]``; ``J`` is ``(n, 11)`` (not read or written without ``jacobian``).
    """
    a0, a1, a2 = abs(xi[0]), abs(xi[1]), abs(xi[2])
    e1, e2 = xi[3], xi[4]
    la_a = (math.log(a0), math.log(a1), math.log(a2))
    sign = (np.sign(xi[0]), np.sign(xi[1]), np.sign(xi[2]))
    t = np.empty(3)
    off = np.empty(3)
    la = np.empty(3)
    safe = np.empty(3)
    dl = np.empty(3)
    dd_dt = np.empty(3)
    for n in range(points.shape[0]):
        for j in range(3):
            off[j] = points[n, j] - xi[5 + j]
        sq = 0.0
        for i in range(3):
            t[i] = off[0] * rotation[0, i] + off[1] * rotation[1, i] + off[2] * rotation[2, i]
            sq += t[i] * t[i]
            at = abs(t[i])
            la[i] = (math.log(at) if at > 0.0 else -math.inf) - la_a[i]
            safe[i] = la[i] if math.isfinite(la[i]) else 0.0
        norm = max(math.sqrt(sq), 1e-300)
        xy = logaddexp((2.0 / e2) * la[0], (2.0 / e2) * la[1])
        log_f = logaddexp((e2 / e1) * xy, (2.0 / e1) * la[2])
        ratio = math.exp(-0.5 * e1 * log_f)
        d[n] = norm * (ratio - 1.0)
        if not jacobian:
            continue
        s = math.exp((e2 / e1) * xy - log_f)
        g = math.exp((2.0 / e2) * la[0] - xy)
        dl[0] = 2.0 * s * g / e1
        dl[1] = 2.0 * s * (1.0 - g) / e1
        dl[2] = 2.0 * (1.0 - s) / e1
        dxy_de2 = -(2.0 / e2**2) * (g * safe[0] + (1.0 - g) * safe[1])
        dlf_de2 = s * (xy / e1 + (e2 / e1) * dxy_de2)
        dlf_de1 = -s * e2 * xy / e1**2 - (1.0 - s) * 2.0 * safe[2] / e1**2
        surface = norm * ratio
        k = -0.5 * e1 * surface
        for i in range(3):
            inv_t = 1.0 / t[i] if t[i] != 0.0 else 0.0
            dd_dt[i] = (k * dl[i]) * inv_t + (t[i] / norm) * (ratio - 1.0)
        J[n, 0] = -(k * dl[0]) / a0 * sign[0]
        J[n, 1] = -(k * dl[1]) / a1 * sign[1]
        J[n, 2] = -(k * dl[2]) / a2 * sign[2]
        J[n, 3] = surface * (-0.5 * log_f) + k * dlf_de1
        J[n, 4] = k * dlf_de2
        for j in range(3):  # t = R^T (x - p)
            J[n, 5 + j] = -(dd_dt[0] * rotation[j, 0] + dd_dt[1] * rotation[j, 1] + dd_dt[2] * rotation[j, 2])
        for q in range(3):  # dt_i / dr_q = (dR_q^T offset)_i
            acc = 0.0
            for i in range(3):
                acc += dd_dt[i] * (d_rotation[q, 0, i] * off[0] + d_rotation[q, 1, i] * off[1]
                                   + d_rotation[q, 2, i] * off[2])
            J[n, 8 + q] = acc
