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

__all__ = ["OPEN_FRACTION", "MIN_REMOVED", "opened"]

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
    import shapely

    if not fraction > 0:
        raise ValueError(f"fraction must be > 0, got {fraction}")
    if np.any(observation.contour_labels != BACKGROUND):
        return None
    region = shapely.Polygon(observation.contour).buffer(0)
    radius = fraction * np.sqrt(observation.area_px / np.pi)
    part = ol.largest_part(region.buffer(-radius, quad_segs=QUAD_SEGMENTS).buffer(radius, quad_segs=QUAD_SEGMENTS))
    if part.is_empty or part.area < 1.0 or part.area > region.area * (1.0 - MIN_REMOVED):
        return None
    interior = observation.sample_labels == INTERIOR
    sampling = "uniform" if interior.all() else "contour" if not interior.any() else "mixed"
    return Observation.from_outline(observation.camera, [np.asarray(part.exterior.coords)[:-1]],
                                    n_samples=len(observation.samples), sampling=sampling, rng=rng)
