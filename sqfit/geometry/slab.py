"""Slabs: superquadrics thin along one axis, and the shape exponent of the section across it.

A superquadric is a *slab* where its thinnest half-axis is below :data:`SLAB_ASPECT` of each of the
others: a book, a monitor's screen, a table top. The exponent ``e2`` shapes the section in the ``xy``
plane, ``e1`` every section through ``z`` (the ``xz`` and ``yz`` planes). So where a slab's thin axis
is ``z``, ``e1`` shapes its whole section across that axis and ``e2`` its face; where it is ``x`` (or
``y``), ``e2`` shapes the section through the thin axis and ``y`` (``x``), but ``e1`` both the section
through the thin axis and ``z`` and the face: no one exponent squares the section, and a slab with
square edges and round corners (a coin on its rim) has no such form. :func:`thin_axis_as_z` re-labels
the axes of such a slab so that its thin axis is ``z``. Seen from a few metres, that section shows only
along the slab's edges, a few pixels across, so masks hardly tell whether it is square, rounded or
pinched (a diamond); the fitting stages that give slabs a square section
(:mod:`sqfit.fitting.least_volume`, :mod:`sqfit.fitting.plain_run`) find it here.
"""

from __future__ import annotations

import numpy as np

from .. import constants as C
from .._checks import check_shape
from .superquadric import euler_to_matrix, matrix_to_euler

__all__ = ["SLAB_ASPECT", "aspect", "thin_axis_as_z", "thin_section"]

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
    it in ``xi``: 3, ``e1``, for ``z``; 4, ``e2``, for ``x`` and ``y``, where it shapes the section
    through the other axis of the ``xy`` plane, and ``e1`` the one through ``z`` (module docstring;
    :func:`thin_axis_as_z`). None where ``xi`` is no slab."""
    a = np.asarray(xi, dtype=np.float64)[:3]
    axis = int(np.argmin(a))
    if not np.all(a[axis] < SLAB_ASPECT * np.delete(a, axis)):
        return None
    return axis, (4 if axis < 2 else 3)


#: Cyclic axis permutations that bring local axis ``k`` to ``z``: new local axis ``j`` is old axis ``_TO_Z[k][j]``.
_TO_Z = {0: (1, 2, 0), 1: (2, 0, 1)}


def thin_axis_as_z(xi):
    """The slab ``xi`` (11 parameters) with its local axes re-labelled so that its thin axis is ``z``:
    ``(11,)`` float, or None where ``xi`` is no slab or its thin axis is ``z`` already.

    The half-axes and the frame's columns are permuted cyclically (a proper rotation: the same box in
    space) and ``e1`` and ``e2`` swapped, so that the exponent of the face (``e1`` of ``xi``) stays the
    face's (now ``e2``), and ``e1`` shapes the whole section across the thin axis (module docstring).
    The surface is the same where ``e1 == e2``; otherwise it is another one, with the same box, half-axes
    and exponents, used as a start (3H's plain run, :func:`sqfit.fitting.plain_run.square_section_fit`).
    The exponents are not clipped; the centre is unchanged. A ``ValueError`` names ``xi`` where it is not
    11 finite numbers."""
    x = check_shape(xi, (C.N_PARAMS,), "xi").copy()
    section = thin_section(x)
    if section is None or section[0] == 2:
        return None
    perm = list(_TO_Z[section[0]])
    R = euler_to_matrix(x[C.ROTATION])[:, perm]
    x[C.SIZE] = x[C.SIZE][perm]
    x[C.SHAPE] = x[C.SHAPE][::-1]
    x[C.ROTATION] = matrix_to_euler(R)
    return x
