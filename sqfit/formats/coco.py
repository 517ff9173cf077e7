"""COCO instance files: read images and track-grouped instance masks, write masks as RLE.

Masks are decoded and encoded with pycocotools (imported here only). Conventions:

- An annotation's ``segmentation`` is compressed RLE (``counts`` a string), uncompressed RLE
  (``counts`` a list of run lengths, column-major) or polygons (a list of flat ``[x0, y0, x1,
  y1, ...]`` lists). pycocotools rasterises a polygon with pixel ``(i, j)`` covering
  ``[j, j + 1) x [i, i + 1)``, the same pixel grid as :mod:`sqfit.geometry.camera` (pinned by
  ``tests/test_formats.py``), so polygon coordinates are image coordinates of the fitter.
- Objects across views are grouped by the ``track_id`` field of each annotation
  (:data:`TRACK_KEY`; an int or a string, unique per object in the file). Associating instances
  into tracks is the user's job (a tracker, or ids from the data set); annotations with
  ``iscrowd = 1`` are skipped, any other annotation without a track id is an error.
"""

from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .jsonfile import read_json

__all__ = ["TRACK_KEY", "CocoImage", "CocoInstances", "read_coco", "decode_segmentation", "polygon_rings",
           "encode_mask"]

#: Annotation field that groups instances of one object across images.
TRACK_KEY = "track_id"


@dataclass(frozen=True)
class CocoImage:
    """One ``images`` record.

    Attributes
    ----------
    id : int
    file_name : str
    width, height : int
        Pixels.
    """

    id: int
    file_name: str
    width: int
    height: int


@dataclass(frozen=True)
class CocoInstances:
    """What an instance file says, grouped for fitting.

    Attributes
    ----------
    path : str
        The file read (for messages).
    images : dict
        ``image id -> CocoImage``, in file order.
    tracks : dict
        ``track id -> {image id -> [annotation, ...]}``; tracks in sorted order, images in file order.
    """

    path: str
    images: dict
    tracks: dict

    def describe(self, annotation):
        """``"FILE: annotation ID (IMAGE FILE NAME)"``: where an annotation is, for messages."""
        return f"{self.path}: annotation {annotation.get('id')} ({self.images[annotation['image_id']].file_name})"

    def mask(self, annotation):
        """``(height, width) bool`` mask of one annotation of this file (polygons rasterised by pycocotools)."""
        image = self.images[annotation["image_id"]]
        return decode_segmentation(annotation.get("segmentation"), image.height, image.width,
                                   self.describe(annotation))

    def polygons(self, annotation):
        """The polygons of an annotation as ``(k, 2)`` vertex arrays (:func:`polygon_rings`), or None
        when its segmentation is not a polygon list (RLE)."""
        segmentation = annotation.get("segmentation")
        return polygon_rings(segmentation, self.describe(annotation)) if isinstance(segmentation, list) else None


def read_coco(path):
    """Read a COCO instance file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    instances : CocoInstances

    Raises
    ------
    OSError
        The file does not exist.
    ValueError
        Not JSON, no ``images`` / ``annotations`` lists, an image without ``id`` / ``file_name`` /
        ``width`` / ``height``, duplicate image ids or file names, an annotation naming an unknown
        image, or an annotation without a ``track_id`` (the message names the file, the
        annotation and the field).

    Warns
    -----
    UserWarning
        Annotation ids that occur more than once (named): the file is read as it is, but
        messages that name an annotation by its id become ambiguous.
    """
    path = Path(path)
    data = read_json(path, "COCO file")
    if not isinstance(data, dict) or not isinstance(data.get("images"), list) \
            or not isinstance(data.get("annotations"), list):
        raise ValueError(f"{path}: a COCO instance file needs lists 'images' and 'annotations'")
    images = _read_images(data["images"], path)
    _warn_duplicate_ids(data["annotations"], path)
    tracks = {}
    for k, ann in enumerate(data["annotations"]):
        where = f"{path}: annotation {ann.get('id', f'#{k}') if isinstance(ann, dict) else f'#{k}'}"
        if not isinstance(ann, dict):
            raise ValueError(f"{where} must be an object")
        if ann.get("iscrowd", 0):
            continue
        if ann.get("image_id") not in images:
            raise ValueError(f"{where}: image_id {ann.get('image_id')!r} is not in 'images'")
        track = ann.get(TRACK_KEY)
        if isinstance(track, bool) or not isinstance(track, (int, str)):
            raise ValueError(f"{where} ({images[ann['image_id']].file_name}) has no '{TRACK_KEY}' (int or string): "
                             f"instances are grouped into objects across images by '{TRACK_KEY}'")
        tracks.setdefault(track, {}).setdefault(ann["image_id"], []).append(ann)
    order = list(images)
    tracks = {t: dict(sorted(tracks[t].items(), key=lambda kv: order.index(kv[0])))
              for t in sorted(tracks, key=lambda t: (isinstance(t, str), t))}
    return CocoInstances(str(path), images, tracks)


def _warn_duplicate_ids(annotations, path, shown=10):
    counts = Counter(a["id"] for a in annotations if isinstance(a, dict) and isinstance(a.get("id"), (int, str)))
    duplicates = sorted((i for i, n in counts.items() if n > 1), key=lambda i: (isinstance(i, str), i))
    if duplicates:
        more = f" and {len(duplicates) - shown} more" if len(duplicates) > shown else ""
        warnings.warn(f"{path}: {len(duplicates)} annotation id(s) occur more than once: "
                      f"{', '.join(map(repr, duplicates[:shown]))}{more} (messages naming an annotation by "
                      "its id are ambiguous; ids should be unique)", UserWarning, stacklevel=3)


def _read_images(records, path):
    images, names = {}, set()
    for k, rec in enumerate(records):
        where = f"{path}: images[{k}]"
        try:
            image = CocoImage(rec["id"], str(rec["file_name"]), rec["width"], rec["height"])
        except (KeyError, TypeError):
            raise ValueError(f"{where} needs 'id', 'file_name', 'width' and 'height'") from None
        for key in ("width", "height"):
            value = getattr(image, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{where} ({image.file_name}): {key} must be a positive integer, got {value!r}")
        if image.id in images:
            raise ValueError(f"{where}: duplicate image id {image.id!r}")
        if image.file_name in names:
            raise ValueError(f"{where}: duplicate file_name {image.file_name!r}")
        images[image.id] = image
        names.add(image.file_name)
    return images


def decode_segmentation(segmentation, height, width, where="segmentation"):
    """Rasterise an annotation's segmentation.

    Parameters
    ----------
    segmentation : dict or list
        Compressed / uncompressed RLE, or polygons (module docstring).
    height, width : int
        Image size the segmentation must have.
    where : str
        Prefix of error messages.

    Returns
    -------
    mask : (height, width) bool
    """
    from pycocotools import mask as mask_utils

    if isinstance(segmentation, dict):
        size = segmentation.get("size")
        if not isinstance(size, (list, tuple)) or [int(s) for s in size] != [height, width]:
            raise ValueError(f"{where}: RLE size {size} does not match the image (height, width) = "
                             f"({height}, {width})")
        counts = segmentation.get("counts")
        if isinstance(counts, list):
            if not all(isinstance(c, int) and not isinstance(c, bool) for c in counts):
                raise ValueError(f"{where}: uncompressed RLE counts must be integers")
            if sum(counts) != height * width:
                raise ValueError(f"{where}: uncompressed RLE counts sum to {sum(counts)}, not height * width = "
                                 f"{height * width}")
            if any(int(c) < 0 for c in counts):
                raise ValueError(f"{where}: uncompressed RLE counts must be >= 0")
            rle = mask_utils.frPyObjects(segmentation, height, width)
        elif isinstance(counts, (str, bytes)):
            rle = {"size": [height, width], "counts": counts.encode("ascii") if isinstance(counts, str) else counts}
        else:
            raise ValueError(f"{where}: RLE 'counts' must be a string or a list of run lengths")
    elif isinstance(segmentation, list):
        polygons = [ring.ravel().tolist() for ring in polygon_rings(segmentation, where)]
        if not polygons:
            return np.zeros((height, width), dtype=bool)
        rle = mask_utils.merge(mask_utils.frPyObjects(polygons, height, width))
    else:
        raise ValueError(f"{where}: segmentation must be RLE (a dict) or polygons (a list), "
                         f"got {type(segmentation).__name__}")
    try:
        mask = mask_utils.decode(rle)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: cannot decode RLE: {exc}") from None
    # pycocotools fills pixels a malformed string does not cover from uninitialised memory: a
    # valid compressed RLE decodes to 0/1 and re-encodes to itself.
    if isinstance(rle, dict) and (mask.max(initial=0) > 1
                                  or mask_utils.encode(np.asfortranarray(mask))["counts"] != rle["counts"]):
        raise ValueError(f"{where}: malformed compressed RLE (its runs do not cover height * width = "
                         f"{height * width} pixels)")
    return mask.astype(bool)


def polygon_rings(segmentation, where="segmentation"):
    """The polygons of a polygon segmentation as vertex arrays.

    Parameters
    ----------
    segmentation : list of list of float
        Flat ``[x0, y0, x1, y1, ...]`` lists, image coordinates (module docstring).
    where : str
        Prefix of error messages.

    Returns
    -------
    rings : list of (k, 2) float
        One per polygon, k >= 3; empty for an empty list.

    Raises
    ------
    ValueError
        Not a list of lists of >= 3 finite (x, y) pairs.
    """
    polygons = [p for p in segmentation if isinstance(p, list)] if isinstance(segmentation, list) else None
    if polygons is None or len(polygons) != len(segmentation) or any(len(p) < 6 or len(p) % 2 for p in polygons) \
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)
                       for p in polygons for x in p):
        raise ValueError(f"{where}: polygons must be lists of >= 3 finite (x, y) pairs "
                         "[x0, y0, x1, y1, ...]")
    return [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in polygons]


def encode_mask(mask):
    """Compressed RLE of a mask, JSON-ready (``counts`` as an ASCII string).

    Parameters
    ----------
    mask : (h, w) bool

    Returns
    -------
    segmentation : dict
        ``{"size": [h, w], "counts": str}``.
    area : float
        Pixels.
    bbox : list of float
        ``[x, y, width, height]``, pixels.
    """
    from pycocotools import mask as mask_utils

    rle = mask_utils.encode(np.asfortranarray(mask, dtype=np.uint8))
    return ({"size": [int(s) for s in rle["size"]], "counts": rle["counts"].decode("ascii")},
            float(mask_utils.area(rle)), [float(x) for x in mask_utils.toBbox(rle)])
