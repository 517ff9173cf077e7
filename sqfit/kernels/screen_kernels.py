"""Compiled (numba) kernel of stage 3H's screen: Levenberg-Marquardt steps for several starts at once.

:func:`screen_lm` is :func:`sqfit.fitting.axis_screen.batch_levenberg_marquardt`, each start solved
on its own with the 3G rows of :mod:`sqfit.kernels.ray_kernels` (:func:`~sqfit.kernels.ray_kernels.ray_rows`,
:func:`~sqfit.kernels.ray_kernels.ray_block`). The same damping, acceptance and pruning as the numpy
code; the numpy code solves the active starts' ``11 x 11`` systems as one stack, so the two agree to
rounding (``tests/test_kernels.py``).

Importing this module imports numba; :mod:`sqfit.kernels.backend` does that lazily (part
``"screen"``). Compiled on first use and cached next to this file; :mod:`sqfit.kernels.kernel_cache`
clears the cache when a kernel it calls changed.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .ray_kernels import penalty_rows, ray_block, ray_rows

__all__ = ["screen_lm"]

_JIT = dict(cache=True, error_model="numpy", nogil=True)


@njit(**_JIT)
def _normal(J, r, H, g):
    m, k = J.shape
    for i in range(k):
        acc = 0.0
        for row in range(m):
            acc += J[row, i] * r[row]
        g[i] = acc
        for j in range(i, k):
            acc = 0.0
            for row in range(m):
                acc += J[row, i] * J[row, j]
            H[i, j] = acc
            H[j, i] = acc


@njit(**_JIT)
def _all_finite(A):
    for v in A.ravel():
        if not np.isfinite(v):
            return False
    return True


@njit(**_JIT)
def screen_lm(X0, origins, directions, weights, kind, iterations, rtol, max_newton, max_warm, grid, znear,
              warm_bracket, newton_power, crossing_tol, crossing_parallel, weight, lower, upper, lambda0, lambda_max,
              prune_after, prune_ratio):
    """:func:`sqfit.fitting.axis_screen.batch_levenberg_marquardt` (``prune_after < 0``: never) -> best
    points ``(b, 11)`` and costs ``(b,)``. Each start is solved on its own (the numpy code solves
    the active starts' ``11 x 11`` systems as one stack)."""
    b, n, k = X0.shape[0], origins.shape[0], 11
    X = X0.copy()
    r, J, d = ray_rows(X, origins, directions, weights, kind, X, False, rtol, max_newton, max_warm, grid, znear,
                       warm_bracket, newton_power, crossing_tol, crossing_parallel, weight, lower, upper)
    cost, lam, nu = np.empty(b), np.empty(b), np.full(b, 2.0)
    ok = np.empty(b, dtype=np.bool_)
    H, g = np.empty((b, k, k)), np.empty((b, k))
    for s in range(b):
        cost[s] = 0.5 * np.dot(r[s], r[s])
        ok[s] = np.isfinite(cost[s]) and _all_finite(J[s])
        if not ok[s]:
            cost[s] = np.inf
        _normal(J[s], r[s], H[s], g[s])
        lam[s] = lambda0 * max(np.max(np.diag(H[s])), 1e-12)
    r_new, J_new, d_new = np.empty(n + k), np.zeros((n + k, k)), np.empty(n)
    trial, dx, Jdx = np.empty(k), np.empty(k), np.empty(n + k)
    for it in range(iterations):
        if it == prune_after:
            lowest = np.min(cost)
            for s in range(b):
                ok[s] = ok[s] and cost[s] <= prune_ratio * lowest
        any_active = False
        for s in range(b):
            if not (ok[s] and lam[s] < lambda_max):
                continue
            any_active = True
            A = H[s] + lam[s] * np.eye(k)
            try:
                dx[:] = -np.linalg.solve(A, g[s])
            except Exception:  # singular or not finite: as a non-finite step
                dx[:] = np.nan
            finite = _all_finite(dx)
            for j in range(k):
                trial[j] = X[s, j] + dx[j] if finite else X[s, j]
                if not finite:
                    dx[j] = 0.0
            ray_block(trial, origins, directions, weights, kind, d[s], True, rtol, max_newton, max_warm, grid, znear,
                       warm_bracket, newton_power, crossing_tol, crossing_parallel, r_new, J_new, d_new)
            penalty_rows(trial, weight, lower, upper, r_new, J_new, n)
            cost_new = 0.5 * np.dot(r_new, r_new)
            Jdx[:] = J[s] @ dx
            predicted = -np.dot(g[s], dx) - 0.5 * np.dot(Jdx, Jdx)
            rho = (cost[s] - cost_new) / predicted if predicted > 0 else -1.0
            if finite and np.isfinite(cost_new) and rho > 0 and _all_finite(J_new):
                X[s], r[s], J[s], d[s], cost[s] = trial, r_new, J_new, d_new, cost_new
                _normal(J[s], r[s], H[s], g[s])
                lam[s] *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu[s] = 2.0
            else:
                lam[s] *= nu[s]
                nu[s] *= 2.0
        if not any_active:
            break
    return X, cost
