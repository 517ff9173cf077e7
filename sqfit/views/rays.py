"""Rays through image points: what the 3G silhouette residuals (:mod:`sqfit.fitting.raycost`) are computed on.

A view's point ``s`` gives the ray ``x(d) = c + d b`` from the camera centre ``c`` along the world
bearing ``b`` (unit camera depth, as eq. 10). Each ray has a *mode* -- :data:`CONTOUR` (a point on
the mask outline: the ray should graze the object), :data:`INSIDE` (inside the mask: the ray must
meet it) or :data:`OUTSIDE` (in a band outside the mask: the ray must miss it) -- a weight, its
view, and whether it is two-sided: a ray through an outline point labelled ``instance`` or
``border`` (:mod:`sqfit.views.visibility`) is one-sided, since the object may continue unseen there.
:func:`contour_rays` builds them from observations; :mod:`sqfit.fitting.raycost` defines the residuals.

Outline offset: a segmenter's outline may lie ``delta`` px outside (``delta > 0``, over-segmentation)
or inside (``delta < 0``) the object's silhouette, along the outline's outward normal. The silhouette
point behind an observed outline point ``s`` is then ``s - delta n``, and its ray's direction is
``directions + delta offsets`` (exact: the direction is affine in the image point). ``offsets`` is
``-R_c [n_u / fx, n_v / fy, 0]`` for rays through outline points (and the band points beside them),
0 for rays through interior samples; ``n`` is the outline's normal averaged over
:data:`NORMAL_ARC_PX` of arc on each side, which smooths the pixel staircase of the outline.
``radii`` is ``n . (s - centroid)``, the outline point's distance from the mask centroid along the
normal (px, at least :data:`MIN_RADIUS_PX`; infinite for interior samples): the length that the
3G residual, a log of a scale about the object's centre, measures pixel errors against.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .._checks import check_shape
from ..geometry.camera import world_bearings
from ..geometry.outline import outward_normals  # re-exported: the normals of 3G's band rays
from ..kernels.backend import compiled
from .observation import Observation, arc_lengths
from .visibility import BACKGROUND, point_labels

__all__ = ["RaySet", "CONTOUR", "INSIDE", "OUTSIDE", "NORMAL_ARC_PX", "MIN_RADIUS_PX", "contour_rays",
           "outward_normals", "arc_normals"]

#: Ray modes (see the module docstring).
CONTOUR, INSIDE, OUTSIDE = 0, 1, 2
#: Half-length (px of arc) of the chord whose normal is an outline point's normal (:func:`arc_normals`):
#: the marching-squares outline of a mask turns by 45 degrees every pixel or so, and 3 px each side
#: average that staircase (on a circle the chord's normal is radial for any length; thin parts of
#: a few px are where a longer chord would bend the normals).
NORMAL_ARC_PX = 3.0
#: Floor of ``RaySet.radii`` (px): outline points whose normal passes the centroid (concave
#: stretches, slivers) get this.
MIN_RADIUS_PX = 1.0
_TINY = 1e-300


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
    offsets : (n, 3) float
        Change of ``directions`` per pixel of outline offset (module docstring), world frame;
        default (None when constructing): all 0.
    radii : (n,) float
        Distance of each ray's image point from its mask's centroid along the outline normal, px,
        > 0 (module docstring); default (None when constructing): all infinite.
    """

    origins: np.ndarray
    directions: np.ndarray
    modes: np.ndarray
    weights: np.ndarray
    view: np.ndarray
    two_sided: np.ndarray | None = None
    offsets: np.ndarray | None = None
    radii: np.ndarray | None = None

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
        offsets = np.zeros((n, 3)) if self.offsets is None else check_shape(self.offsets, (n, 3), "offsets")
        object.__setattr__(self, "offsets", offsets)
        radii = np.full(n, np.inf) if self.radii is None else check_shape(self.radii, (n,), "radii", finite=False)
        if np.any(~(radii > 0)):
            raise ValueError("radii must be > 0")
        object.__setattr__(self, "radii", radii)
        self._index_hinges()

    def _index_hinges(self):
        # Rays with a hinge residual (see the module docstring), as indices: computed once, not
        # per evaluation. One-sided CONTOUR rays act as INSIDE rays; one-sided OUTSIDE rays are dropped.
        hinge_in, hinge_out = _hinges(self.modes, self.two_sided)
        object.__setattr__(self, "_hinge_in", hinge_in)
        object.__setattr__(self, "_hinge_out", hinge_out)

    @classmethod
    def _made(cls, origins, directions, modes, weights, view, two_sided, offsets, radii, hinges=None):
        """A RaySet of arrays that :func:`contour_rays` made from checked observations (float64 and
        int64 arrays of the right shapes, finite, weights >= 0, radii > 0), without checking them
        again: the graph makes one per view of every frame (the checks were a third of its cost).
        ``hinges``: the rays' hinge indices (:meth:`_index_hinges`) if already known."""
        rays = object.__new__(cls)
        rays.__dict__.update(origins=origins, directions=directions, modes=modes, weights=weights, view=view,
                             two_sided=two_sided, offsets=offsets, radii=radii)
        if hinges is None:
            rays._index_hinges()
        else:
            rays.__dict__.update(_hinge_in=hinges[0], _hinge_out=hinges[1])
        return rays

    def __len__(self):
        return len(self.origins)


def arc_normals(contour, arc_lengths, half_arc=NORMAL_ARC_PX):
    """Unit outward normals of a counter-clockwise image polygon at given arc lengths.

    The normal of the chord between the points ``half_arc`` before and after (as
    :func:`outward_normals`: ``(dv, -du)`` for a chord ``(du, dv)``), so pixel steps shorter than
    ``half_arc`` are averaged out.

    Parameters
    ----------
    contour : (m, 2) float
        Closed polygon, not repeated at the end, positive shoelace area in ``(u, v)``.
    arc_lengths : (n,) float
        Arc lengths from vertex 0, px (any real: taken modulo the perimeter).
    half_arc : float
        Half-length of the chord, px, > 0.

    Returns
    -------
    normals : (n, 2) float
    """
    contour = check_shape(contour, (None, 2), "contour")
    if len(contour) < 3:
        raise ValueError(f"contour must have at least 3 vertices, got {len(contour)}")
    if not (np.isfinite(half_arc) and half_arc > 0):
        raise ValueError(f"half_arc must be a finite number > 0, got {half_arc}")
    at, _, perimeter = _arc_sampler(contour)
    half = min(float(half_arc), 0.25 * perimeter)
    s = np.asarray(arc_lengths, dtype=np.float64)
    return _chord_normals(at(s + half)[0] - at(s - half)[0])


def _chord_normals(chord):
    """Unit outward normals ``(n, 2)`` of chords ``(n, 2)`` of a counter-clockwise polygon."""
    normal = np.empty_like(chord)
    normal[:, 0], normal[:, 1] = chord[:, 1], -chord[:, 0]
    # np.linalg.norm's sums, without its overhead (the graph makes the rays of every new view)
    length = np.sqrt(normal[:, 0] * normal[:, 0] + normal[:, 1] * normal[:, 1])
    return normal / np.maximum(length, _TINY)[:, None]


def _arc_sampler(polygon, arc=None):
    """``(at, integral, perimeter)`` of a closed polygon ``(m, 2)``, arc lengths from vertex 0 taken
    modulo the perimeter: ``at(s)`` gives the points ``(n, 2)`` at arc lengths ``s`` and the edge of
    each (edge ``k`` runs from vertex ``k`` to ``k + 1``); ``integral(s, points, edges)`` the integral
    of the point along the polygon from arc length 0 to ``s`` (``(n, 2)``; ``points, edges = at(s)``),
    exact on the straight edges. ``arc``: :func:`sqfit.views.observation.arc_lengths` of the polygon
    if already known (``Observation.contour_arc``). ``at`` touches only the edges it samples (a
    view's rays need a few dozen of its outline's hundreds of edges)."""
    seg, cum = arc_lengths(polygon) if arc is None else arc
    m = len(seg)
    last = m - 1

    def at(s):
        s = np.mod(s, cum[-1])
        idx = np.minimum(np.searchsorted(cum, s, side="right") - 1, last)
        start, length = polygon[idx], seg[idx]
        edge = polygon[(idx + 1) % m] - start
        return start + ((s - cum[idx]) * (1.0 / np.where(length > 0, length, 1.0)))[:, None] * edge, idx

    def integral(s, points, idx):
        closed = np.concatenate([polygon, polygon[:1]])
        area = np.concatenate([[[0.0, 0.0]], np.cumsum(seg[:, None] * 0.5 * (closed[:-1] + closed[1:]), axis=0)])
        turns = np.floor(s / cum[-1])
        rest = s - turns * cum[-1]
        return turns[:, None] * area[-1] + area[idx] + (rest - cum[idx])[:, None] * 0.5 * (closed[idx] + points)

    return at, integral, cum[-1]


def contour_rays(observations, n_contour=64, band_px=0.0, n_inside=0, smooth_px=0.0):
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
    smooth_px : float
        > 0: each contour point is the mean point of the outline over ``smooth_px`` px of arc on
        each side, which averages the pixel staircase of a mask's outline; >= 0.

    Returns
    -------
    rays : RaySet
        Each view's rays weighted ``1 / sqrt(rays in that view)``, so every view counts equally;
        ``two_sided`` False where the outline point is labelled ``instance`` or ``border``
        (``Observation.contour_labels``); ``offsets`` from the outline's normals (module docstring).
    """
    if int(n_contour) != n_contour or n_contour < 3:
        raise ValueError(f"n_contour must be an integer >= 3, got {n_contour}")
    if not (np.isfinite(band_px) and band_px >= 0):
        raise ValueError(f"band_px must be a finite number >= 0, got {band_px}")
    if int(n_inside) != n_inside or n_inside < 0:
        raise ValueError(f"n_inside must be an integer >= 0, got {n_inside}")
    if not (np.isfinite(smooth_px) and smooth_px >= 0):
        raise ValueError(f"smooth_px must be a finite number >= 0, got {smooth_px}")
    parts = []
    args = (int(n_contour), float(band_px), int(n_inside), float(smooth_px))
    key = ("contour_rays",) + args
    for i, o in enumerate(observations):
        if not isinstance(o, Observation):
            raise TypeError(f"observations[{i}] must be a sqfit.Observation, got {type(o).__name__}")
        # the image side depends on the pixels alone: once per mask, whatever the camera's pose
        points, modes, two_sided, normals, radii, weights, *hinges = o.derived(key, lambda: _view_rays(o, *args))
        cam = o.camera
        rotation = cam.rotation
        directions = world_bearings(cam, points)
        k = cam.intrinsics
        offsets = (normals * [-1.0 / k.fx, -1.0 / k.fy]) @ rotation[:, :2].T
        parts.append((cam.center, directions, modes, weights, i, two_sided, offsets, radii, hinges))
    if not parts:
        raise ValueError("observations must not be empty")
    # the points come from checked observations: finite, with radii >= MIN_RADIUS_PX
    if len(parts) == 1:  # one view (the factor graph's rays): its hinge indices as they were cached
        center, directions, modes, weights, _, two_sided, offsets, radii, hinges = parts[0]
        origins = np.empty_like(directions)
        origins[:] = center
        return RaySet._made(origins, directions, modes, weights, np.zeros(len(directions), dtype=np.int64), two_sided,
                            offsets, radii, hinges)
    columns = list(zip(*parts))
    sizes = [len(d) for d in columns[1]]
    origins = np.repeat(np.array(columns[0], dtype=np.float64), sizes, axis=0)
    view = np.repeat(np.arange(len(parts), dtype=np.int64), sizes)
    directions, modes, weights, two_sided, offsets, radii = (np.concatenate(columns[j]) for j in (1, 2, 3, 5, 6, 7))
    return RaySet._made(origins, directions, modes, weights, view, two_sided, offsets, radii)


@cache
def _contour_phase():
    """Phase of the contour points: fixed (the first draw of seed 0), so the rays are a
    deterministic function of the mask; drawn once, not per view."""
    return float(np.random.default_rng(0).random())


def _hinges(modes, two_sided):
    """The indices of the rays with an inside hinge and with an outside hinge (:meth:`RaySet._index_hinges`)."""
    return (np.flatnonzero((modes == INSIDE) | ((modes == CONTOUR) & ~two_sided)), np.flatnonzero(modes == OUTSIDE))


def _view_rays(observation, n_contour, band_px, n_inside, smooth_px):
    """What one view's rays take from its pixels alone (:func:`_view_points`, then the radii, the
    weights and the two arrays of hinge indices), for :meth:`sqfit.views.observation.Observation.derived`."""
    points, modes, two_sided, normals = _view_points(observation, n_contour, band_px, n_inside, smooth_px)
    radii = np.maximum(np.einsum("ij,ij->i", points - observation.centroid, normals), MIN_RADIUS_PX)
    if n_inside:  # interior samples: no outline, no offset
        radii[len(points) - min(int(n_inside), len(observation.samples)):] = np.inf
    weights = np.full(len(points), 1.0 / np.sqrt(len(points)))
    return (points, modes, two_sided, normals, radii, weights) + _hinges(modes, two_sided)


def _view_points(observation, n_contour, band_px, n_inside, smooth_px):
    """Image points, modes, two-sidedness and outline normals (0 for interior samples) of one view."""
    contour = observation.contour
    seg, cum = observation.contour_arc
    half = min(NORMAL_ARC_PX, 0.25 * cum[-1])
    kernels = compiled("outlines")
    if kernels is not None:  # the same points, bit for bit, in one compiled loop
        on, sided, normal_at = kernels.outline_samples(
            np.ascontiguousarray(contour, dtype=np.float64), seg, cum,
            np.ascontiguousarray(observation.contour_labels, dtype=np.int8), BACKGROUND, int(n_contour),
            _contour_phase(), float(half), float(smooth_px))
    else:
        on, sided, normal_at = _outline_samples(observation, n_contour, half, smooth_px)
    if band_px > 0:
        # Normals at the sample points: those of the nearest contour vertices.
        normals = outward_normals(observation.contour)
        nearest = np.argmin(((on[:, None, :] - observation.contour[None]) ** 2).sum(-1), axis=1)
        nrm = normals[nearest]
        points = [on - band_px * nrm, on + band_px * nrm]
        modes = [np.full(n_contour, INSIDE), np.full(n_contour, OUTSIDE)]
        two_sided = [sided, sided]
        normals = [normal_at, normal_at]
    else:
        points, modes, two_sided, normals = [on], [np.full(n_contour, CONTOUR)], [sided], [normal_at]
    if n_inside:
        inner = observation.samples[:n_inside]
        points.append(inner)
        modes.append(np.full(len(inner), INSIDE))
        two_sided.append(np.ones(len(inner), dtype=bool))
        normals.append(np.zeros((len(inner), 2)))
    return tuple(c[0] if len(c) == 1 else np.concatenate(c) for c in (points, modes, two_sided, normals))


def _outline_samples(observation, n_contour, half, smooth_px):
    """The outline points ``(n, 2)``, their two-sidedness ``(n,)`` and the outline's normals there
    ``(n, 2)``, in numpy (:func:`sqfit.kernels.outline_kernels.outline_samples` computes the same)."""
    contour = observation.contour
    at, integral, perimeter = _arc_sampler(contour, observation.contour_arc)
    arc = (_contour_phase() + np.arange(n_contour)) / n_contour * perimeter
    # sampled at once: the points (as sqfit.views.observation.polyline_points), the ends of their
    # normals' chords, and the ends of the arcs they are averaged over
    shifts = np.array([0.0, -half, half, -smooth_px, smooth_px] if smooth_px > 0 else [0.0, -half, half])
    where = (arc[None, :] + shifts[:, None]).ravel()
    points, edges = at(where)
    if smooth_px > 0:  # the mean point of the outline over the arc
        ends = integral(where[3 * n_contour:], points[3 * n_contour:], edges[3 * n_contour:])
        on = (ends[n_contour:] - ends[:n_contour]) / (2.0 * smooth_px)
    else:
        on = points[:n_contour]
    points = points.reshape(len(shifts), n_contour, 2)
    sided = point_labels(observation.contour_labels, edges[:n_contour]) == BACKGROUND
    return on, sided, _chord_normals(points[2] - points[1])
