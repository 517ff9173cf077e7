"""Segmenter-like mask models: the outline errors of masks made by networks and labelling tools.

Real instance masks (Mask R-CNN, SAM, YOLO, annotation tools) are never pixel-exact: their
outline sits a fraction of a pixel to a few pixels off, biased in or out per object, wobbles
smoothly, loses thin parts and has holes. Each model acts on one binary mask ``(h, w) bool``:

- :func:`bias_boundary` by ``delta`` px: the outline moved along its normal by ``delta``
  (> 0 grows the mask, < 0 shrinks it); sub-pixel amounts work (the mask's area follows the
  offset outline's, not integer dilation). :func:`draw_bias` draws ``delta`` per object and view from ``N(mean, std)``.
- :func:`smooth_boundary_error` of ``amplitude`` px RMS and ``wavelength`` px: the outline
  displaced along its normal by a smooth random field made of :data:`SMOOTH_WAVES` plane waves
  of that wavelength (random directions and phases), the low-frequency, blobby outline error of
  promptable segmenters.
- :func:`remove_thin_parts` below ``width`` px: morphological opening with a disc of diameter
  ``width``; parts narrower than ``width`` vanish, convex corners round off with radius
  ``width / 2``.
- :func:`punch_holes` at ``rate`` holes per :data:`HOLE_AREA_UNIT_PX` px of mask area (Poisson)
  of radius ``radius`` px, each inside the mask with a rim of at least :data:`HOLE_RIM_PX`.

The outline of a binary mask is its marching-squares contour at level 0.5
(``skimage.measure.find_contours``: through the midpoints between inside and outside pixel
centres; the image border counts as background), low-passed along each contour
(:func:`smooth_outline`), so that a digitised curve stands for the curve, not for its staircase.
Models move that outline (a buffer in shapely, or a displacement of the signed distance
:func:`signed_distance`) and read the result back at the pixel centres; a zero amount leaves the
mask unchanged. An object cut by the image border goes on beyond it (the border is not part of
its outline: no model moves it); holes keep away from the border.

:func:`apply_mask_models` applies them in the order thin-part loss, smooth error, bias, holes
(:func:`sqsim.imaging.noise.corrupt_image` calls it per instance before the classic corruptions).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from sqfit._checks import check_number

from .mask_ops import as_mask, mask_box

__all__ = ["outline_contours", "smooth_outline", "signed_distance", "bias_boundary", "draw_bias",
           "smooth_boundary_error", "remove_thin_parts", "punch_holes", "apply_mask_models", "mask_models_active",
           "OUTLINE_SPACING_PX", "OUTLINE_SMOOTHING_VERTICES", "SMOOTH_WAVES", "HALF_PIXEL", "HOLE_AREA_UNIT_PX",
           "HOLE_RIM_PX"]

#: Spacing of the points sampled along the outline for distances (px): error <= spacing**2 / 8 / d.
OUTLINE_SPACING_PX = 0.1
#: Gaussian sigma (in vertices, ~0.7 px each) of the low-pass along the outline (:func:`smooth_outline`).
OUTLINE_SMOOTHING_VERTICES = 2.0
#: Plane waves summed into the smooth boundary-error field.
SMOOTH_WAVES = 16
#: Half a pixel (px): pixel centres farther than this beyond a moved outline always change.
HALF_PIXEL = 0.5
#: Mask area (px) per unit of hole rate: ``rate`` holes per 1000 px of mask.
HOLE_AREA_UNIT_PX = 1000.0
#: Least distance (px) between a hole's edge and the mask's outline.
HOLE_RIM_PX = 1.0


# --- checks and the outline ------------------------------------------------------------------------

def outline_contours(mask):
    """The mask's outline: closed marching-squares contours at level 0.5.

    Parameters
    ----------
    mask : (h, w) bool

    Returns
    -------
    contours : list of (n, 2) float
        ``(row, col)`` vertices, pixel ``(i, j)``'s centre at ``(i, j)``; each contour closed
        (last vertex == first). Outer outlines and hole outlines alike; the image border counts
        as background, so every contour closes.
    """
    from skimage import measure

    mask = as_mask(mask)
    return [c - 1.0 for c in measure.find_contours(np.pad(mask, 1).astype(np.uint8), 0.5)]


def smooth_outline(mask):
    """The mask's outline low-passed along each contour: the curve a staircase stands for.

    Each marching-squares contour (:func:`outline_contours`) is filtered along its vertices by a
    Gaussian of :data:`OUTLINE_SMOOTHING_VERTICES` (wrapping around). Straight and 45° edges stay
    put; a digitised disc's outline becomes a circle whose length is within 1 % of the true
    perimeter (the staircase's is ~5 % longer).

    Parameters
    ----------
    mask : (h, w) bool

    Returns
    -------
    region : shapely.Geometry
        The area inside the smoothed contours (even-odd: hole outlines cut holes), coordinates
        ``(row, col)`` as in :func:`outline_contours`.
    """
    import shapely

    region = shapely.Polygon()
    for c in outline_contours(mask):
        ring = ndimage.gaussian_filter1d(c[:-1], OUTLINE_SMOOTHING_VERTICES, axis=0, mode="wrap")
        if len(ring) >= 3:
            region = shapely.symmetric_difference(region, shapely.Polygon(ring).buffer(0))
    return region


def _depth(region, points):
    """Signed distance (px) of ``points`` (k, 2) to the boundary of ``region``: > 0 inside, (k,)."""
    import shapely
    from scipy.spatial import cKDTree

    if region.is_empty or not len(points):
        return np.full(len(points), -np.inf)
    edge = shapely.get_coordinates(shapely.segmentize(region.boundary, OUTLINE_SPACING_PX))
    dist = cKDTree(edge).query(points)[0]
    return np.where(shapely.contains_xy(region, points[:, 0], points[:, 1]), dist, -dist)


def _band(mask, width):
    """Pixels within about ``width`` px of the outline (pixel-grid distance): (h, w) bool."""
    padded = np.pad(mask, 1)  # the image border is background, as for the outline
    inside = ndimage.distance_transform_edt(padded)[1:-1, 1:-1]
    outside = ndimage.distance_transform_edt(~padded)[1:-1, 1:-1]
    return np.where(mask, inside, outside) <= width + 1.5


def signed_distance(mask, band=np.inf):
    """Signed distance of every pixel centre to the mask's smoothed outline, px.

    Parameters
    ----------
    mask : (h, w) bool
    band : float
        Only pixels within about ``band`` px of the outline get a distance; the others get
        ``+inf`` (in the mask) or ``-inf`` (outside).

    Returns
    -------
    sd : (h, w) float
        Distance to the boundary of :func:`smooth_outline`, with the mask's sign: > 0 (or 0) for
        pixels of the mask, < 0 (or 0) for the others, even where the smoothed outline passes on
        the other side of a pixel centre (so a zero displacement changes nothing).
    """
    mask = as_mask(mask)
    sd = np.where(mask, np.inf, -np.inf)
    if not mask.any():
        return sd
    near = _band(mask, band)
    dist = np.abs(_depth(smooth_outline(mask), np.argwhere(near).astype(np.float64)))
    sd[near] = np.where(mask[near], dist, -dist)
    return sd


def _on_crop(mask, margin, model):
    """Run ``model`` ((H, W) bool -> (H, W) bool) on the mask's box grown by ``margin`` px.

    Beyond the image border the box is extended by repeating its edge pixels (``margin`` px), so
    an object cut by the border goes on past it: no model moves an outline along the border.
    """
    box = mask_box(mask, margin)
    out = mask.copy()
    out[box] = model(np.pad(mask[box], margin, mode="edge"))[margin:-margin, margin:-margin]
    return out


def _moved(mask, level):
    """Pixels inside the zero set of ``level`` (h, w) float; a pixel on it keeps its state."""
    return np.where(mask, level >= 0, level > 0)


# --- the models ------------------------------------------------------------------------------------

def bias_boundary(mask, delta):
    """Move the outline along its normal by ``delta`` px: over- (> 0) or under-segmentation (< 0).

    A binary mask knows its outline only to within a pixel, and moving a staircase by a fraction
    of a pixel changes no pixel centre. So the moved outline is the smoothed outline
    (:func:`smooth_outline`) offset by ``delta`` (shapely ``buffer``), the mask gains (loses) as
    many pixels as the area between the two (rounded), and the pixels it gains (keeps) are the
    ones deepest inside the moved outline (along a straight edge moved by a fraction of a pixel
    they fall in runs, as the depths differ by the outline's sampling, ~1e-3 px);
    a pixel whose centre lies more than half a pixel beyond the moved outline always changes (so
    parts thinner than ``-2 delta`` vanish whole).

    Parameters
    ----------
    mask : (h, w) bool
    delta : float
        Signed offset, pixels; sub-pixel values work (a disc of radius ``r`` becomes one of area
        ``pi (r + delta)**2``).

    Returns
    -------
    biased : (h, w) bool
        A superset (``delta > 0``) or subset (``delta < 0``) of ``mask``.
    """
    mask = as_mask(mask)
    delta = check_number(delta, "boundary bias")
    if delta == 0 or not mask.any():
        return mask.copy()
    return _on_crop(mask, int(np.ceil(abs(delta))) + 2, lambda sub: _offset(sub, delta))


def _offset(sub, delta):
    region = smooth_outline(sub)
    moved = region.buffer(delta, quad_segs=32)
    pool = (~sub if delta > 0 else sub) & _band(sub, abs(delta))
    rows, cols = np.nonzero(pool)
    depth = _depth(moved, np.column_stack([rows, cols]).astype(np.float64))
    beyond = np.sum(depth > HALF_PIXEL) if delta > 0 else np.sum(depth < -HALF_PIXEL)
    n = int(min(max(round(abs(moved.area - region.area)), beyond), len(rows)))
    # Gain the outside pixels deepest in the moved outline; lose the inside ones least deep in it.
    order = np.argsort(-depth if delta > 0 else depth, kind="stable")[:n]
    out = sub.copy()
    out[rows[order], cols[order]] = delta > 0
    return out


def draw_bias(mean, std, rng=None):
    """One boundary bias (px) from ``N(mean, std)``; ``mean`` itself (no draw) when ``std`` is 0.

    Parameters
    ----------
    mean : float
        Pixels, signed.
    std : float
        Pixels, >= 0.
    rng : None, int or numpy.random.Generator

    Returns
    -------
    delta : float
    """
    mean = check_number(mean, "boundary bias mean")
    std = check_number(std, "boundary bias std", lo=0)
    if std == 0:
        return mean
    return float(np.random.default_rng(rng).normal(mean, std))


def _wave_field(shape, wavelength, rng):
    """Unit-RMS sum of plane waves of one wavelength (px), random directions and phases: (h, w) float."""
    theta = rng.uniform(0.0, 2.0 * np.pi, SMOOTH_WAVES)
    phase = rng.uniform(0.0, 2.0 * np.pi, SMOOTH_WAVES)
    k = 2.0 * np.pi / wavelength
    rows, cols = np.indices(shape, dtype=np.float64)
    field = np.zeros(shape)
    for t, p in zip(theta, phase):
        field += np.cos(k * (np.cos(t) * cols + np.sin(t) * rows) + p)
    return field * np.sqrt(2.0 / SMOOTH_WAVES)


def smooth_boundary_error(mask, amplitude, wavelength, rng=None):
    """Displace the outline along its normal by a smooth random field: blobby, rounded outlines.

    Parameters
    ----------
    mask : (h, w) bool
    amplitude : float
        RMS of the normal displacement, pixels, >= 0.
    wavelength : float
        Wavelength of the displacement field, pixels, > 0 (along an outline it varies no faster
        than this).
    rng : None, int or numpy.random.Generator

    Returns
    -------
    displaced : (h, w) bool
    """
    mask = as_mask(mask)
    amplitude = check_number(amplitude, "smooth boundary error", lo=0)
    wavelength = check_number(wavelength, "smooth boundary error wavelength", lo=0, lo_open=True)
    rng = np.random.default_rng(rng)
    if amplitude == 0 or not mask.any():
        return mask.copy()
    reach = amplitude * np.sqrt(2.0 * SMOOTH_WAVES)  # bound of |field|

    def displace(sub):
        field = amplitude * _wave_field(sub.shape, wavelength, rng)
        return _moved(sub, signed_distance(sub, band=float(np.abs(field).max())) + field)

    return _on_crop(mask, int(np.ceil(reach)) + 2, displace)


def remove_thin_parts(mask, width):
    """Morphological opening with a disc of diameter ``width`` px: parts thinner than it vanish.

    The opening is exact on the smoothed outline (:func:`smooth_outline`, shapely ``buffer`` by
    ``-width / 2`` then ``+width / 2``) and read back at the pixel centres of the mask, so
    straight edges stay put, convex corners round off with radius ``width / 2``, and the result
    is a subset of ``mask``.

    Parameters
    ----------
    mask : (h, w) bool
    width : float
        Pixels, >= 0; 0 leaves the mask unchanged.

    Returns
    -------
    opened : (h, w) bool
    """
    import shapely

    mask = as_mask(mask)
    width = check_number(width, "thin-part width", lo=0)
    if width == 0 or not mask.any():
        return mask.copy()
    radius = 0.5 * width

    def open_(sub):
        opened = smooth_outline(sub).buffer(-radius, quad_segs=32).buffer(radius, quad_segs=32)
        rows, cols = np.nonzero(sub & _band(sub, radius))  # deeper pixels are centres of discs that fit
        out = sub.copy()
        out[rows, cols] = shapely.contains_xy(opened, rows.astype(np.float64), cols.astype(np.float64))
        return out

    return _on_crop(mask, int(np.ceil(radius)) + 2, open_)


def punch_holes(mask, rate, radius, rng=None):
    """Punch small interior holes: Poisson(``rate * area / HOLE_AREA_UNIT_PX``) discs.

    Parameters
    ----------
    mask : (h, w) bool
    rate : float
        Expected holes per :data:`HOLE_AREA_UNIT_PX` px of mask area, >= 0.
    radius : float
        Hole radius, pixels, > 0. Centres are drawn uniformly where the mask is at least
        ``radius + HOLE_RIM_PX`` deep (no hole if there is no such place); overlapping holes merge.
    rng : None, int or numpy.random.Generator

    Returns
    -------
    holed : (h, w) bool
    """
    mask = as_mask(mask)
    rate = check_number(rate, "hole rate", lo=0)
    radius = check_number(radius, "hole radius", lo=0, lo_open=True)
    rng = np.random.default_rng(rng)
    if rate == 0 or not mask.any():
        return mask.copy()
    n = rng.poisson(rate * mask.sum() / HOLE_AREA_UNIT_PX)
    depth = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1] - 0.5
    # A centre lies anywhere in its pixel: up to half a diagonal from the pixel centre.
    candidates = np.argwhere(depth >= radius + HOLE_RIM_PX + np.sqrt(0.5))
    out = mask.copy()
    if n == 0 or len(candidates) == 0:
        return out
    centres = candidates[rng.integers(0, len(candidates), n)] + rng.uniform(-0.5, 0.5, (n, 2))
    reach = int(np.ceil(radius))
    offsets = np.argwhere(np.ones((2 * reach + 3, 2 * reach + 3), dtype=bool)) - (reach + 1)
    for centre in centres:
        pixels = np.round(centre).astype(int) + offsets
        inside = np.linalg.norm(pixels - centre, axis=1) <= radius
        out[pixels[inside, 0], pixels[inside, 1]] = False
    return out


# --- scenes -----------------------------------------------------------------------------------------

def mask_models_active(noise):
    """True when a scene's ``[noise]`` (``sqsim.world.scene.NoiseConfig``) turns on a model of this module."""
    return bool(noise.boundary_bias_px or noise.boundary_bias_std_px or noise.smooth_error_px
                or noise.thin_part_width_px or noise.hole_rate)


def apply_mask_models(mask, noise, rng=None):
    """The models of a scene's ``[noise]`` on one instance mask, in the module's order.

    Parameters
    ----------
    mask : (h, w) bool
    noise : sqsim.world.scene.NoiseConfig
        ``thin_part_width_px``, ``smooth_error_px`` / ``smooth_error_wavelength_px``,
        ``boundary_bias_px`` / ``boundary_bias_std_px``, ``hole_rate`` / ``hole_radius_px``.
    rng : None, int or numpy.random.Generator
        Drawn from only by the models that are on, so scenes without them are unchanged.

    Returns
    -------
    out : (h, w) bool
    """
    rng = np.random.default_rng(rng)
    out = remove_thin_parts(mask, noise.thin_part_width_px)
    out = smooth_boundary_error(out, noise.smooth_error_px, noise.smooth_error_wavelength_px, rng)
    if noise.boundary_bias_px or noise.boundary_bias_std_px:
        out = bias_boundary(out, draw_bias(noise.boundary_bias_px, noise.boundary_bias_std_px, rng))
    return punch_holes(out, noise.hole_rate, noise.hole_radius_px, rng)
