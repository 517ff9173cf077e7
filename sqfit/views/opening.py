"""An object's bulk in one view: the mask with its thin parts opened away.

A table's legs, a monitor's stand, a lamp's pole, a chair's legs are thin in every view; the part
a single superquadric can describe (the top, the screen, the shade, the seat and back) is not. A
morphological *opening* of the mask (erode, then dilate, by a disk) removes every part narrower
than the disk and leaves the rest as it was, up to the disk's rounding of convex corners.
:func:`opened` does it exactly on the mask's outline polygon (shapely: a negative, then a positive
buffer), with a disk whose radius is :data:`OPEN_FRACTION` of the mask's equivalent radius
(``sqrt(area / pi)``), so the same fraction of the object's size is opened at any distance. Of what
is left it keeps the largest part, as :meth:`Observation.from_mask` keeps a mask's largest
component, and rebuilds the observation from that outline (:meth:`Observation.from_outline`).
:func:`split_share` measures the second part it leaves (a lamp's base apart from its shade) and
:func:`main_part` gives the mask near the largest part, the corners the disk rounded kept (stage 3W,
:mod:`sqfit.fitting.weighted_overlap`, "Parts apart").

Stage 3V (:mod:`sqfit.fitting.least_volume`) fits these outlines for a candidate superquadric.
Fractions 0.15 and 0.3 were tried in a one-off run (the default chain on the opened masks alone, 10
household objects per kind, seed 0): at 0.3 the monitors' fits fell back from 0.50 to 0.30 median
3D IoU and the books' from 0.85 to 0.71. With stage 3V built at 0.15, 0.1 and 0.22 were tried too
(monitors, lamps, tables, chairs, 20 each, seeds 0 and 1): 0.1 lowered monitors by up to 0.055 and
raised tables by 0.03; 0.22 moved the medians by -0.006 to +0.017, single fits both ways. 0.15
stays (docs/real-objects.md, "Least volume").
"""

from __future__ import annotations

import numpy as np

from ..geometry import outline as ol
from .observation import Observation
from .visibility import BACKGROUND, INTERIOR

__all__ = ["OPEN_FRACTION", "MIN_REMOVED", "opened", "split_share", "main_part"]

#: Radius of the opening disk, as a fraction of the mask's equivalent radius ``sqrt(area_px / pi)``.
OPEN_FRACTION = 0.15
#: A view whose opening removes less than this share of the mask's area has no thin part (a box's
#: four corners rounded by the disk lose 0.6 %): :func:`opened` returns None for it.
MIN_REMOVED = 0.01
#: Segments of the disk's quarter circle (shapely's ``quad_segs``).
QUAD_SEGMENTS = 8


def opened(observation, fraction=OPEN_FRACTION, rng=0):
    """The observation of the largest part of the mask that a disk of radius ``fraction`` times
    the mask's equivalent radius fits into (module docstring), or None.

    Parameters
    ----------
    observation : Observation
    fraction : float
        > 0.
    rng : None, int or numpy.random.Generator
        For the new area samples (as many as ``observation`` has, drawn as it drew them: area,
        outline or both, read from its sample labels).

    Returns
    -------
    Observation or None
        None when the view is partial (an occluded or cut outline: what lies beyond it is
        unknown, so are its thin parts), when the opening removes less than :data:`MIN_REMOVED` of
        the area (nothing thin: only corners rounded) or when nothing is left of the mask.
    """
    found = _largest(observation, fraction)
    return None if found is None else _from_part(observation, found[1], rng)


def _from_part(observation, part, rng):
    """The observation of one part of the mask (a shapely Polygon), sampled as ``observation`` was."""
    interior = observation.sample_labels == INTERIOR
    sampling = "uniform" if interior.all() else "contour" if not interior.any() else "mixed"
    return Observation.from_outline(observation.camera, [np.asarray(part.exterior.coords)[:-1]],
                                    n_samples=len(observation.samples), sampling=sampling, rng=rng)


def split_share(observation, fraction=OPEN_FRACTION):
    """The area of the second largest part the opening of :func:`opened` leaves, as a share of the mask's area:
    0 where it leaves one part or none, or where the view is partial (an occluded or cut outline, as there).

    A lamp's pole opened away leaves its shade and its base apart (the base up to 0.48 of the mask's area on the
    lamps of ``scenes/household.toml``, seed 0); a toy's limbs or a table's legs opened away leave one part. A mask
    of a convex shape never falls apart (stage 3W, :mod:`sqfit.fitting.weighted_overlap`, "Parts apart").
    """
    opening = _opening(observation, fraction)
    if opening is None:
        return 0.0
    region, rest, _ = opening
    areas = sorted((p.area for p in ol.shapely_parts(rest)), reverse=True)
    return float(areas[1] / region.area) if len(areas) > 1 and region.area > 0 else 0.0


def main_part(observation, fraction=OPEN_FRACTION, rng=0):
    """The observation of the mask within the disk's radius of the largest part the opening of :func:`opened`
    leaves: that part with the corners the opening rounded, without the other parts (a lamp's base) and the thin
    ones beyond the radius. None where :func:`opened` returns None (arguments as there)."""
    found = _largest(observation, fraction)
    if found is None:
        return None
    region, part, radius = found
    near = region.intersection(part.buffer(radius, quad_segs=QUAD_SEGMENTS))
    return _from_part(observation, ol.largest_part(near), rng)


def _opening(observation, fraction):
    """``(region, rest, radius)``: the mask's outline as a shapely region, what a disk of ``radius`` (``fraction``
    times the mask's equivalent radius) leaves of it (erode, then dilate), and that radius; None where the view is
    partial (an occluded or cut outline). Remembered on the observation (:meth:`Observation.derived`)."""
    import shapely

    if not fraction > 0:
        raise ValueError(f"fraction must be > 0, got {fraction}")
    if np.any(observation.contour_labels != BACKGROUND):
        return None

    def compute():
        region = shapely.Polygon(observation.contour).buffer(0)
        radius = fraction * np.sqrt(observation.area_px / np.pi)
        return region, region.buffer(-radius, quad_segs=QUAD_SEGMENTS).buffer(radius, quad_segs=QUAD_SEGMENTS), radius

    # the pixels' own: 3V, 3U and 3W (its parts' test and main parts, its slab step) open the same masks
    return observation.derived(("opening", float(fraction)), compute)


def _largest(observation, fraction):
    """``(region, part, radius)`` as :func:`_opening`'s with ``part`` the largest part the opening leaves; None
    where :func:`opened` returns None."""
    opening = _opening(observation, fraction)
    if opening is None:
        return None
    region, rest, radius = opening
    part = ol.largest_part(rest)
    if part.is_empty or part.area < 1.0 or part.area > region.area * (1.0 - MIN_REMOVED):
        return None
    return region, part, radius
