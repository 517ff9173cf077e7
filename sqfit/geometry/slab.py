"""Slabs: superquadrics thin along one axis, and the shape exponent of the section across it.

A superquadric is a *slab* where its thinnest half-axis is below :data:`SLAB_ASPECT` of each of the
others: a book, a monitor's screen, a table top. The exponent ``e2`` shapes the sections through the
``x`` and ``y`` axes (the ``xy`` plane), ``e1`` the sections through ``z``. So the section across a
slab's thin axis is shaped by ``e2`` where that axis is ``x`` or ``y``, by ``e1`` where it is ``z``;
the other exponent shapes the slab's face. Seen from a few metres, that section shows only along
the slab's edges, a few pixels across, so masks hardly tell whether it is square, rounded or pinched
(a diamond); the fitting stages that give slabs a square section (:mod:`sqfit.fitting.least_volume`,
:mod:`sqfit.fitting.axis_screen`) find it here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SLAB_ASPECT", "aspect", "thin_section"]

#: A superquadric is a slab where its thinnest half-axis is below this fraction of each of the others.
SLAB_ASPECT = 0.5


def aspect(xi):
    """The thinnest half-axis of ``xi`` (11 parameters, or at least the 3 of size) over its middle one,
    signs ignored: below :data:`SLAB_ASPECT` on a slab with positive half-axes, as :func:`thin_section`
    tests it; NaN where the middle half-axis is 0."""
    a = np.sort(np.abs(np.asarray(xi, dtype=np.float64)[:3]))
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(a[0] / a[1]) if a[1] > 0 else float("nan")


def thin_section(xi):
    """``(axis, exponent)`` of a slab ``xi`` (11 parameters, or at least the 5 of size and shape):
    the index of its thinnest half-axis (0-2) and that of the shape exponent of the section across
    it in ``xi`` (4, ``e2``, for ``x`` and ``y``; 3, ``e1``, for ``z``); None where ``xi`` is no slab."""
    a = np.asarray(xi, dtype=np.float64)[:3]
    axis = int(np.argmin(a))
    if not np.all(a[axis] < SLAB_ASPECT * np.delete(a, axis)):
        return None
    return axis, (4 if axis < 2 else 3)
