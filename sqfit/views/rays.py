"""Rays through image points: what the 3G silhouette residuals (:mod:`sqfit.fitting.raycost`) are computed on.

A view's point ``s`` gives the ray ``x(d) = c + d b`` from the camera centre ``c`` along the world
bearing ``b`` (unit camera depth, as eq. 10). Each ray has a *mode* -- :data:`CONTOUR` (a point on
the mask outline: the ray should graze the object), :data:`INSIDE` (inside the mask: the ray must
meet it) or :data:`OUTSIDE` (in a band outside the mask: the ray must miss it) -- a weight, its
view, and whether it is two-sided: a ray through an outline point labelled ``instance`` or
``border`` (:mod:`sqfit.views.visibility`) is one-sided, since the object may continue unseen there.
:func:`contour_rays` builds them from observations; :mod:`sqfit.fitting.raycost` defines the residuals.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .._checks import check_shape
from ..geometry.camera import bearings
from ..geometry.outline import outward_normals  # re-exported: the normals of 3G's band rays
from .observation import Observation, polyline_points
from .visibility import BACKGROUND, point_labels

__all__ = ["RaySet", "CONTOUR", "INSIDE", "OUTSIDE", "contour_rays", "outward_normals"]

#: Ray modes (see the module docstring).
CONTOUR, INSIDE, OUTSIDE = 0, 1, 2


@dataclass(frozen=True)
class RaySet:
    """Rays through image points, with what each residual asks of them.

    Attributes
    ----------
    origins : (n, 3) float
        Camera centre of each ray, world frame, metres.
    directions : (n, 3) float
        World direction per unit camera depth (``R_c @ [(u - cx) / fx, (v - cy) / fy, 1]``).
    modes : (n,) int
        :data:`CONTOUR`, :data:`INSIDE` or :data:`OUTSIDE`.
    weights : (n,) float
        Residual weights, >= 0.
    view : (n,) int
        View index of each ray.
    two_sided : (n,) bool
        False for rays through occluded or truncated outline points (see the module docstring);
        default (None when constructing): all True.
    """

    origins: np.ndarray
    directions: np.ndarray
    modes: np.ndarray
    weights: np.ndarray
    view: np.ndarray
    two_sided: np.ndarray | None = None

    def __post_init__(self):
        origins = check_shape(self.origins, (None, 3), "origins")
        n = len(origins)
        object.__setattr__(self, "origins", origins)
        object.__setattr__(self, "directions", check_shape(self.directions, (n, 3), "directions"))
        modes = check_shape(self.modes, (n,), "modes", dtype=np.int64)
        if not np.all((modes >= CONTOUR) & (modes <= OUTSIDE)):  # the three modes are 0, 1, 2
            raise ValueError("modes must be CONTOUR (0), INSIDE (1) or OUTSIDE (2)")
        object.__setattr__(self, "modes", modes)
        weights = check_shape(self.weights, (n,), "weights")
        if np.any(weights < 0):
            raise ValueError("weights must be >= 0")
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "view", check_shape(self.view, (n,), "view", dtype=np.int64))
        two_sided = np.ones(n, dtype=bool) if self.two_sided is None else np.asarray(self.two_sided)
        if two_sided.shape != (n,) or two_sided.dtype != bool:
            raise ValueError(f"two_sided must be a boolean array of shape ({n},), got {two_sided.dtype} "
                             f"{two_sided.shape}")
        object.__setattr__(self, "two_sided", two_sided)
        # Rays with a hinge residual (see the module docstring), as indices: computed once, not
        # per evaluation. One-sided CONTOUR rays act as INSIDE rays; one-sided OUTSIDE rays are dropped.
        object.__setattr__(self, "_hinge_in", np.flatnonzero((modes == INSIDE) | ((modes == CONTOUR) & ~two_sided)))
        object.__setattr__(self, "_hinge_out", np.flatnonzero(modes == OUTSIDE))

    def __len__(self):
        return len(self.origins)


def contour_rays(observations, n_contour=64, band_px=0.0, n_inside=0):
    """Rays of the 3G residuals for a list of observations.

    Parameters
    ----------
    observations : list of Observation
    n_contour : int
        Points per view, evenly spaced by arc length along ``Observation.contour`` (fixed phase,
        deterministic), >= 3.
    band_px : float
        0: the contour points give :data:`CONTOUR` rays. > 0: each contour point gives an
        :data:`INSIDE` ray ``band_px`` pixels inward and an :data:`OUTSIDE` ray ``band_px`` pixels
        outward (along the outward normal).
    n_inside : int
        Extra :data:`INSIDE` rays per view through the observation's samples (the first
        ``n_inside``; all of them if fewer), >= 0.

    Returns
    -------
    rays : RaySet
        Each view's rays weighted ``1 / sqrt(rays in that view)``, so every view counts equally;
        ``two_sided`` False where the outline point is labelled ``instance`` or ``border``
        (``Observation.contour_labels``).
    """
    if int(n_contour) != n_contour or n_contour < 3:
        raise ValueError(f"n_contour must be an integer >= 3, got {n_contour}")
    if not (np.isfinite(band_px) and band_px >= 0):
        raise ValueError(f"band_px must be a finite number >= 0, got {band_px}")
    if int(n_inside) != n_inside or n_inside < 0:
        raise ValueError(f"n_inside must be an integer >= 0, got {n_inside}")
    parts = []
    for i, o in enumerate(observations):
        if not isinstance(o, Observation):
            raise TypeError(f"observations[{i}] must be a sqfit.Observation, got {type(o).__name__}")
        points, modes, two_sided = _view_points(o, int(n_contour), float(band_px), int(n_inside))
        cam = o.camera
        directions = bearings(cam, points) @ cam.rotation.T
        weights = np.full(len(points), 1.0 / np.sqrt(len(points)))
        parts.append((np.broadcast_to(cam.center, directions.shape), directions, modes, weights,
                      np.full(len(points), i), two_sided))
    if not parts:
        raise ValueError("observations must not be empty")
    return RaySet(*(np.concatenate(col) for col in zip(*parts)))


@cache
def _contour_phase():
    """Phase of the contour points: fixed (the first draw of seed 0), so the rays are a
    deterministic function of the mask; drawn once, not per view."""
    return float(np.random.default_rng(0).random())


def _view_points(observation, n_contour, band_px, n_inside):
    on, edges = polyline_points(observation.contour, n_contour, _contour_phase(), return_index=True,
                                arc=observation.contour_arc)
    sided = point_labels(observation.contour_labels, edges) == BACKGROUND
    if band_px > 0:
        # Normals at the sample points: those of the nearest contour vertices.
        normals = outward_normals(observation.contour)
        nearest = np.argmin(((on[:, None, :] - observation.contour[None]) ** 2).sum(-1), axis=1)
        nrm = normals[nearest]
        points = [on - band_px * nrm, on + band_px * nrm]
        modes = [np.full(n_contour, INSIDE), np.full(n_contour, OUTSIDE)]
        two_sided = [sided, sided]
    else:
        points, modes, two_sided = [on], [np.full(n_contour, CONTOUR)], [sided]
    if n_inside:
        inner = observation.samples[:n_inside]
        points.append(inner)
        modes.append(np.full(len(inner), INSIDE))
        two_sided.append(np.ones(len(inner), dtype=bool))
    return np.concatenate(points), np.concatenate(modes), np.concatenate(two_sided)
