"""Rigid transforms shared by the pose readers."""

from __future__ import annotations

import numpy as np


def invert(T):
    """Inverse of a rigid transform.

    Parameters
    ----------
    T : (4, 4) float
        ``[[R, t], [0, 0, 0, 1]]`` with ``R`` a rotation (not checked here: the result goes into
        ``sqfit.Camera``, which checks it).

    Returns
    -------
    T_inv : (4, 4) float
        ``[[R.T, -R.T t], [0, 0, 0, 1]]``.
    """
    T = np.asarray(T, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
