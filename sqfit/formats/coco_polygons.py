"""COCO polygons of a mask, written the way the common tools write them.

A COCO ``segmentation`` may be a list of polygons, each a flat ``[x0, y0, x1, y1, ...]`` list in
image coordinates (pixel ``(i, j)`` covers ``[j, j + 1) x [i, i + 1)``, :mod:`sqfit.formats.coco`).
Tools trace a binary mask in one of two conventions (:data:`POLYGON_CONVENTIONS`):

- ``"opencv"``, as detectron2 writes them (``GenericMask.mask_to_polygons``):
  ``cv2.findContours(mask, RETR_CCOMP, CHAIN_APPROX_NONE)`` returns the centres of the boundary
  pixels (integer ``(x, y)``); detectron2 adds 0.5 to make them image coordinates and drops
  contours of fewer than 3 points. Such a polygon runs through the centres of the outermost
  pixels, half a pixel inside the outline, so pycocotools rasterises it back without part of
  that rim: about half of the boundary pixels (on an axis-aligned box, its top row and left
  column), and objects of 1-2 pixels vanish.
- ``"skimage"``: ``skimage.measure.find_contours(mask, 0.5)`` on the mask padded by one pixel,
  the marching-squares outline through the midpoints between inside and outside pixel centres
  (its ``(row, col)`` swapped to ``(x, y)`` and shifted by +0.5 to image coordinates): the
  mask's own outline, which pycocotools rasterises back to the mask.

Both write every contour the tool returns, one polygon per outer outline (several for several
components) and one per hole outline; pycocotools merges a segmentation's polygons as a union,
so holes come back filled (COCO polygons cannot express holes).

Reading them back (``sqfit fit --coco --polygon-convention``, :data:`POLYGON_READINGS`): as
``"pixel-centres"`` (the OpenCV convention: grown half a pixel step to the outline) or
``"outline"`` (the skimage convention, and a labelling tool's polygon drawn along the object's
edge: taken as it is), both without rasterising (:mod:`sqfit.geometry.outline`,
:meth:`sqfit.Observation.from_outline`); as ``"raster"``, rasterised by pycocotools and traced
as a mask (sqfit's reading before the polygon route); ``"auto"`` detects the convention from the
vertices of the whole file (:func:`detect_polygon_convention`): pixel-centres when every vertex
has half-integer ``x`` and ``y`` (``x - 0.5`` and ``y - 0.5`` whole numbers, within
:data:`CENTRE_TOLERANCE`), which is what ``cv2.findContours`` + 0.5 writes; else outline
(skimage's vertices have one whole and one half-integer coordinate, hand-drawn ones anything).
"""

from __future__ import annotations

import numpy as np

__all__ = ["POLYGON_CONVENTIONS", "POLYGON_READINGS", "READING_OF", "CENTRE_TOLERANCE", "mask_to_polygons",
           "encode_polygons", "detect_polygon_convention", "polygon_reading"]

#: Ways of tracing a mask into COCO polygons (module docstring).
POLYGON_CONVENTIONS = ("opencv", "skimage")
#: Ways of reading COCO polygons (module docstring); the first is the default.
POLYGON_READINGS = ("auto", "pixel-centres", "outline", "raster")
#: The reading that is faithful to each tracing convention.
READING_OF = {"opencv": "pixel-centres", "skimage": "outline"}
#: Largest distance (px) of a coordinate from a half-integer that still counts as a pixel centre
#: (JSON keeps detectron2's ``x + 0.5`` exactly; this leaves room for float32 and rounding).
CENTRE_TOLERANCE = 1e-4

#: Offset (px) from a pixel's integer index to its centre in image coordinates.
PIXEL_CENTRE = 0.5


def _check(mask, convention):
    if convention not in POLYGON_CONVENTIONS:
        raise ValueError(f"polygon convention must be one of {list(POLYGON_CONVENTIONS)}, got {convention!r}")
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must have shape (h, w), got {mask.shape}")
    return mask != 0


def mask_to_polygons(mask, convention):
    """Trace a mask into COCO polygons.

    Parameters
    ----------
    mask : (h, w) bool
    convention : str
        ``"opencv"`` or ``"skimage"`` (module docstring).

    Returns
    -------
    polygons : list of list of float
        Flat ``[x0, y0, x1, y1, ...]`` lists (>= 3 vertices each, not repeating the first),
        image coordinates; empty for an empty mask.
    """
    mask = _check(mask, convention)
    if convention == "opencv":
        import cv2

        contours = cv2.findContours(np.ascontiguousarray(mask, dtype=np.uint8), cv2.RETR_CCOMP,
                                    cv2.CHAIN_APPROX_NONE)[-2]
        rings = [c.reshape(-1, 2).astype(np.float64) + PIXEL_CENTRE for c in contours]
    else:
        from skimage import measure

        contours = measure.find_contours(np.pad(mask, 1).astype(np.uint8), 0.5)
        # (row, col) of the padded image -> (x, y) of the image: -1 for the pad, +0.5 for the grid.
        rings = [c[:-1, ::-1] - 1.0 + PIXEL_CENTRE for c in contours]
    return [ring.ravel().tolist() for ring in rings if len(ring) >= 3]


def encode_polygons(mask, convention):
    """A COCO polygon segmentation of a mask, with its area and box as pycocotools decodes it.

    Parameters
    ----------
    mask : (h, w) bool
    convention : str
        ``"opencv"`` or ``"skimage"``.

    Returns
    -------
    segmentation : list of list of float
        :func:`mask_to_polygons`.
    area : float
        Pixels of the polygons' union, rasterised by pycocotools.
    bbox : list of float
        ``[x, y, width, height]`` of that rasterisation, pixels.
    """
    from pycocotools import mask as mask_utils

    mask = _check(mask, convention)
    polygons = mask_to_polygons(mask, convention)
    if not polygons:
        return [], 0.0, [0.0, 0.0, 0.0, 0.0]
    rle = mask_utils.merge(mask_utils.frPyObjects(polygons, *mask.shape))
    return polygons, float(mask_utils.area(rle)), [float(x) for x in mask_utils.toBbox(rle)]


def detect_polygon_convention(rings):
    """The convention of polygon vertices, from their coordinates (module docstring).

    Parameters
    ----------
    rings : iterable of (k, 2) float
        Polygons, image coordinates.

    Returns
    -------
    convention : {"pixel-centres", "outline"} or None
        None when there is no vertex.
    reason : str
        Why, for a message.
    """
    vertices = np.concatenate([np.asarray(r, dtype=np.float64).reshape(-1, 2) for r in rings] or [np.zeros((0, 2))])
    if not len(vertices):
        return None, "no polygon"
    off = np.abs(vertices - PIXEL_CENTRE - np.round(vertices - PIXEL_CENTRE)).max(axis=1) > CENTRE_TOLERANCE
    if not off.any():
        return "pixel-centres", (f"all {len(vertices)} polygon vertices lie on pixel centres (x - 0.5 and y - 0.5 "
                                 "whole numbers), as cv2.findContours + 0.5 writes them (detectron2)")
    return "outline", f"{int(off.sum())} of {len(vertices)} polygon vertices lie off pixel centres"


def polygon_reading(rings, reading="auto"):
    """How to read a file's polygons: ``reading`` checked, or detected from ``rings`` if "auto".

    Parameters
    ----------
    rings : iterable of (k, 2) float
        Every polygon of the file.
    reading : {"auto", "pixel-centres", "outline", "raster"}

    Returns
    -------
    reading : {"pixel-centres", "outline", "raster"} or None
        None when the file holds no polygon.
    note : str
        A sentence saying how the polygons are read and why ("" without polygons).
    """
    if reading not in POLYGON_READINGS:
        raise ValueError(f"polygon convention must be one of {list(POLYGON_READINGS)}, got {reading!r}")
    rings = list(rings)
    if not rings:
        return None, ""
    if reading != "auto":
        return reading, f"{len(rings)} COCO polygon(s) {_HOW[reading]} (--polygon-convention {reading})"
    found, reason = detect_polygon_convention(rings)
    return found, f"{len(rings)} COCO polygon(s) {_HOW[found]} (auto: {reason})"


_HOW = {"pixel-centres": "read as outlines through boundary pixels' centres, grown half a pixel step",
        "outline": "read as outlines, taken as they are", "raster": "rasterised by pycocotools"}
