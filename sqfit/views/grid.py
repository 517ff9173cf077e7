"""Deterministic samples: a regular grid inside an observation's outline instead of random points.

``Observation.from_mask`` draws its ``n`` samples at random (seeded), so everything computed from
them changes with the sampling seed. Where a chain must give one answer whatever the seed (the
default chain's rescue, :mod:`sqfit.fitting.axis_screen`), it uses :func:`with_grid_samples`: the
same observation with its samples replaced by :func:`grid_samples` of its contour, or, where only
the hull of the samples is read (R-IOU-M against ``polygon="hull"``), :func:`with_outline_samples`:
the contour's vertices as samples, whose hull is the hull of the whole outline.

The grid: square cells of side ``h = sqrt(area / n)`` (``area`` of the contour polygon), one
point per cell centre, the cell lattice anchored at the polygon's centroid (a point lies at
``centroid + h (i, j)``, ``i, j`` integers); the points inside the polygon are kept. That is
about ``n`` points spread evenly over the region, the stratified counterpart of uniform random
samples. When fewer than ``n / 2`` fall inside (a thin region narrower than ``h``), ``h`` is halved
until at least that many do (up to :data:`MAX_REFINEMENTS` times); a region that still holds
fewer than 3 grid points gets its contour vertices instead.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..geometry.polygon import polygon_moments
from .observation import Observation

__all__ = ["grid_samples", "with_grid_samples", "with_outline_samples", "MAX_REFINEMENTS"]

#: Halvings of the grid step at most, for thin regions (a 2**-6 step gives 4096 times the points).
MAX_REFINEMENTS = 6


def grid_samples(polygon, n):
    """About ``n`` points on a regular grid inside a polygon (module docstring).

    Parameters
    ----------
    polygon : (k, 2) float
        Simple polygon, image coordinates ``(u, v)``, k >= 3, non-zero area.
    n : int
        Target number of points, >= 3.

    Returns
    -------
    points : (m, 2) float
        Grid points inside the polygon, in row-major grid order (``v`` then ``u``); ``m`` is about
        ``n``, at least ``n / 2`` unless the region is too thin (then its vertices, ``m = k``).
    """
    if int(n) != n or n < 3:
        raise ValueError(f"n must be an integer >= 3, got {n}")
    area, centroid, _ = polygon_moments(polygon)
    polygon = np.asarray(polygon, dtype=np.float64)
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    step = np.sqrt(area / n)
    for _ in range(MAX_REFINEMENTS + 1):
        i = np.arange(np.floor((lo[0] - centroid[0]) / step), np.ceil((hi[0] - centroid[0]) / step) + 1)
        j = np.arange(np.floor((lo[1] - centroid[1]) / step), np.ceil((hi[1] - centroid[1]) / step) + 1)
        inside = _inside_grid(polygon, centroid[0] + step * i, centroid[1] + step * j)
        if 2 * len(inside) >= n:
            return inside
        step /= 2.0
    return inside if len(inside) >= 3 else polygon.copy()


def _inside_grid(polygon, us, vs):
    """``(m, 2) float``: the points of the grid ``us x vs`` (ascending) inside a polygon (even-odd
    rule), row by row: a point is inside when an odd number of the row's edge crossings lie to its left."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    # Half-open in v, so a row through a vertex counts it once.
    rows, edges = np.nonzero((a[:, 1] <= vs[:, None]) != (b[:, 1] <= vs[:, None]))
    ea, eb = a[edges], b[edges]
    u = ea[:, 0] + (vs[rows] - ea[:, 1]) / (eb[:, 1] - ea[:, 1]) * (eb[:, 0] - ea[:, 0])
    left = np.zeros((len(vs), len(us)), dtype=np.int64)
    np.add.at(left, rows, np.searchsorted(us, u, side="right")[:, None] <= np.arange(len(us)))
    r, c = np.nonzero(left % 2 == 1)
    return np.stack([us[c], vs[r]], axis=1)


def with_grid_samples(observation, n=None):
    """The observation with :func:`grid_samples` of its contour as samples (all ``interior``).

    Parameters
    ----------
    observation : Observation
    n : int, optional
        Target number of samples; default the observation's own number of samples.

    Returns
    -------
    observation : Observation
        Camera, contour, labels, centroid, area and hidden pixels unchanged.
    """
    if not isinstance(observation, Observation):
        raise TypeError(f"observation must be a sqfit.Observation, got {type(observation).__name__}")
    n = max(len(observation.samples), 3) if n is None else n
    samples = grid_samples(observation.contour, n)
    samples.flags.writeable = False
    return replace(observation, samples=samples, sample_labels=None)


def with_outline_samples(observation):
    """The observation with its contour vertices as samples (all ``interior``).

    Its ``polygon("hull")`` is then the convex hull of the outline, which does not depend on the
    sampling seed. Meant for scores that read only the hull (R-IOU-M); the samples are not spread
    over the region, so a cost over the samples (G5) should use :func:`with_grid_samples`.

    Parameters
    ----------
    observation : Observation

    Returns
    -------
    observation : Observation
    """
    if not isinstance(observation, Observation):
        raise TypeError(f"observation must be a sqfit.Observation, got {type(observation).__name__}")
    return replace(observation, samples=observation.contour, sample_labels=None)
