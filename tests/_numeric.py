"""Shared test helpers (imported by test modules; pytest puts tests/ on sys.path)."""

import numpy as np


def central_difference(f, x, h=1e-6):
    """Jacobian of ``f`` at ``x`` by central differences: ``(m, n)`` for ``f: (n,) -> (m,)``."""
    cols = []
    for k in range(len(x)):
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        cols.append((f(xp) - f(xm)) / (2 * h))
    return np.stack(cols, axis=-1)
