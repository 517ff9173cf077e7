"""Fit objects of a user's scene: COCO instance masks + camera poses -> ``fits.jsonl``.

Joining the two files:

- Poses come from a pose source in :data:`POSE_FORMATS` (a COLMAP model directory, a JSON
  pose file), each a reader ``path -> {image name: sqfit.Camera}`` that does its own pose
  convention conversion once; or from a timestamped trajectory in :data:`TRAJECTORY_FORMATS` (a
  TUM file), which has no intrinsics and no image names: the user gives the intrinsics, each
  image gets a timestamp and the nearest pose in time (:mod:`sqfit.formats.trajectory`).
- A COCO image is matched to a named pose by its ``file_name``: first the exact name (COLMAP stores
  names relative to its image folder, e.g. ``frames/0001.png``), else the base name
  (``0001.png``) when exactly one pose has it. A COCO image with no match, or whose
  ``width`` x ``height`` differs from its camera's, cannot be used (likewise an image without a
  timestamp or without a trajectory pose near enough in time): each object seen there records
  that view as dropped, with the reason. No match at all is an error.
- Objects are the tracks of :mod:`sqfit.formats.coco` (``track_id``); an object's views are the
  images where its track has an annotation (several annotations of one track in one image are
  merged). A view whose annotations are all RLE is observed from an instance image holding the
  object (id 1) over every other annotation of that image (id 2), as
  :func:`sqfit.views.dataset.observe_views` does, so a view with an empty mask is dropped with a
  warning exactly as in a native dataset.
- Polygons (the polygon route): a view whose annotations are all polygons is observed from the
  polygons themselves (:meth:`sqfit.Observation.from_outline`) in the file's polygon reading
  (:data:`sqfit.formats.coco_polygons.POLYGON_READINGS`: ``auto`` detects ``pixel-centres`` or
  ``outline`` from the vertices), the image's other annotations as what may hide it; its samples
  come from the same generator, in view order, as a mask view's. With the reading ``raster`` (or
  a view that mixes RLE and polygons) polygons are rasterised and the view is a mask view:
  ``raster`` by pycocotools (sqfit's reading before the polygon route), else by pixel centre
  inside the polygons' region, which keeps the pixels a pycocotools rasterisation of a
  pixel-centre polygon loses.

``sqfit fit --coco`` (:func:`sqfit.cli.fit.fit_import`) fits every track of such a scene.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import constants as C
from ..formats._names import NameIndex
from ..formats.coco import read_coco
from ..formats.coco_polygons import POLYGON_READINGS, polygon_reading
from ..formats.colmap import read_colmap
from ..formats.posejson import read_pose_json
from ..formats.tum import read_tum
from ..geometry.outline import OUTLINE_CONVENTIONS, region_pixels, shapely_parts, visible_region
from .observation import Observation

__all__ = ["POSE_FORMATS", "TRAJECTORY_FORMATS", "detect_pose_format", "resolve_pose_format", "read_poses",
           "ImportedScene", "match_cameras", "load_import", "observe_track", "track_rng"]

#: Pose sources with image names: name -> reader ``path -> {image name: sqfit.Camera (T_world_camera)}``.
#: A new source is one reader here and one rule in detect_pose_format.
POSE_FORMATS = {"colmap": read_colmap, "json": read_pose_json}

#: Timestamped trajectories: name -> reader ``path -> (timestamps (m,), T_world_camera (m, 4, 4))``,
#: joined to images by time with user intrinsics (:func:`sqfit.formats.trajectory.match_trajectory`).
TRAJECTORY_FORMATS = {"tum": read_tum}

#: Suffixes of TUM trajectory files (``groundtruth.txt`` in TUM RGB-D; evo writes ``.tum`` or ``.txt``).
TUM_SUFFIXES = (".tum", ".txt")


def detect_pose_format(path):
    """``"colmap"`` for a directory, ``"json"`` for ``.json``, ``"tum"`` for ``.tum``/``.txt``; else ValueError."""
    path = Path(path)
    if path.is_dir():
        return "colmap"
    if path.suffix.lower() == ".json":
        return "json"
    if path.suffix.lower() in TUM_SUFFIXES:
        return "tum"
    raise ValueError(f"cannot tell the pose format of {path} (a COLMAP model directory, a .json file or a TUM "
                     f"trajectory {'/'.join(TUM_SUFFIXES)}); name it with --pose-format "
                     f"({', '.join([*POSE_FORMATS, *TRAJECTORY_FORMATS])})")


def resolve_pose_format(path, pose_format="auto"):
    """The format of a pose source: ``pose_format`` checked, or detected from ``path`` if "auto"."""
    if pose_format == "auto":
        if not Path(path).exists():
            raise OSError(f"pose source not found: {path}")
        return detect_pose_format(path)
    if pose_format not in POSE_FORMATS and pose_format not in TRAJECTORY_FORMATS:
        raise ValueError(f"pose format must be one of {['auto', *POSE_FORMATS, *TRAJECTORY_FORMATS]}, "
                         f"got {pose_format!r}")
    return pose_format


def read_poses(path, pose_format="auto"):
    """``{image name: sqfit.Camera}`` from a pose source with names (``pose_format`` in POSE_FORMATS or "auto")."""
    pose_format = resolve_pose_format(path, pose_format)
    if pose_format in TRAJECTORY_FORMATS:
        raise ValueError(f"{path} is a {pose_format.upper()} trajectory: it has no image names; join it to images "
                         "by time with load_import(..., intrinsics=...) or sqfit.formats.trajectory.match_trajectory")
    return POSE_FORMATS[pose_format](path)


@dataclass(frozen=True)
class ImportedScene:
    """A COCO file joined with poses.

    Attributes
    ----------
    coco : sqfit.formats.coco.CocoInstances
    cameras : dict
        ``COCO image id -> sqfit.Camera`` of the images that can be used.
    unusable : dict
        ``COCO image id -> reason`` for the others (no pose, no timestamp or no pose near it in time,
        size mismatch).
    polygons : {"pixel-centres", "outline", "raster"} or None
        How polygon segmentations are read (:func:`sqfit.formats.coco_polygons.polygon_reading`);
        None when the file has none.
    polygon_note : str
        How the polygons are read and why, for the user ("" without polygons).
    """

    coco: object
    cameras: dict
    unusable: dict
    polygons: str | None = None
    polygon_note: str = ""
    _union: dict = field(default_factory=dict, repr=False)  # image id -> RLE of all its annotations
    _regions: dict = field(default_factory=dict, repr=False)  # id(annotation) -> its region in the image

    def outlines(self, annotation):
        """The polygons of an annotation as outlines (``(k, 2)`` vertex arrays), or None for RLE or
        with the reading ``raster``: ``outline`` polygons as they are, ``pixel-centres`` ones grown to
        the outline (:func:`sqfit.geometry.outline.grow_pixel_centres`, clipped to the image).

        Raises ValueError for malformed polygons, or (``pixel-centres``) when their region does not
        reach into the image (:func:`sqfit.geometry.outline.visible_region`)."""
        rings = self.coco.polygons(annotation) if self.polygons in OUTLINE_CONVENTIONS else None
        if not rings or self.polygons == "outline":
            return rings
        return [np.asarray(p.exterior.coords)[:-1] for p in shapely_parts(self._region(annotation, rings))]

    def annotation_mask(self, annotation):
        """``(h, w) bool`` mask of one annotation: RLE decoded; polygons rasterised in this scene's
        reading (``raster``: by pycocotools; else the pixels whose centres the polygons' region holds)."""
        rings = self.coco.polygons(annotation) if self.polygons in OUTLINE_CONVENTIONS else None
        if rings is None:
            return self.coco.mask(annotation)
        image = self.coco.images[annotation["image_id"]]
        if not rings:
            return np.zeros((image.height, image.width), dtype=bool)
        return region_pixels(self._region(annotation, rings), (image.height, image.width))

    def _region(self, annotation, rings):
        """The region of an annotation's polygons in its image, computed once (growing is the cost)."""
        key = id(annotation)  # the annotation dicts live in self.coco as long as the scene
        if key not in self._regions:
            image = self.coco.images[annotation["image_id"]]
            try:
                self._regions[key] = visible_region(rings, self.polygons, image.width, image.height)
            except ValueError as exc:
                self._regions[key] = str(exc)  # raised again at each use
        if isinstance(self._regions[key], str):
            raise ValueError(self._regions[key])
        return self._regions[key]

    def union_mask(self, image_id):
        """``(h, w) bool``: pixels of any annotation of an image (each image decoded once, kept as RLE)."""
        from ..formats.coco import decode_segmentation, encode_mask

        image = self.coco.images[image_id]
        if image_id not in self._union:
            union = np.zeros((image.height, image.width), dtype=bool)
            for by_image in self.coco.tracks.values():
                for ann in by_image.get(image_id, []):
                    try:
                        union |= self.annotation_mask(ann)
                    except ValueError:
                        pass  # reported by its own track; other objects keep this view
            self._union[image_id] = encode_mask(union)[0]
        return decode_segmentation(self._union[image_id], image.height, image.width)

    @property
    def track_ids(self):
        return list(self.coco.tracks)


def match_cameras(images, poses, source="the pose source"):
    """Camera of each COCO image, matched by file name (module docstring).

    Parameters
    ----------
    images : dict
        ``image id -> CocoImage``.
    poses : dict
        ``image name -> sqfit.Camera``.
    source : str
        Name of the pose source, for messages.

    Returns
    -------
    cameras : dict
        ``image id -> Camera``.
    unusable : dict
        ``image id -> reason``.
    """
    index = NameIndex(poses)
    cameras, unusable = {}, {}
    for image_id, image in images.items():
        name = image.file_name
        found, how = index.find(name)
        if found is None:
            unusable[image_id] = f"image {name!r} is not in {source}: {how}"
            continue
        cam = poses[found]
        if (cam.intrinsics.width, cam.intrinsics.height) != (image.width, image.height):
            unusable[image_id] = (f"image {name!r} is {image.width}x{image.height} in COCO but its camera in "
                                  f"{source} is {cam.intrinsics.width}x{cam.intrinsics.height}")
            continue
        cameras[image_id] = cam
    return cameras, unusable


def load_import(coco_path, poses_path, pose_format="auto", intrinsics=None, image_times=None, max_time_diff=None,
                intrinsics_convention=None, polygon_convention="auto"):
    """Read a COCO instance file and a pose source and join them.

    Parameters
    ----------
    coco_path : str or os.PathLike
    poses_path : str or os.PathLike
        COLMAP model directory, JSON pose file or TUM trajectory.
    pose_format : {"auto", "colmap", "json", "tum"}
    intrinsics : sqfit.Intrinsics, dict, str or os.PathLike, optional
        TUM only (required there): the camera of every image,
        :func:`sqfit.formats.trajectory.read_intrinsics` (``"fx fy cx cy width height"`` or a file).
    image_times : dict, str or os.PathLike, optional
        TUM only: ``file name -> seconds`` or an ``rgb.txt``-style list; default: the file name
        stem as seconds (:func:`sqfit.formats.trajectory.image_timestamps`).
    max_time_diff : float, optional
        TUM only: seconds between an image and its pose at most (default
        :data:`sqfit.formats.trajectory.DEFAULT_MAX_TIME_DIFF`).
    intrinsics_convention : {"opencv", "sqfit"}, optional
        TUM only: principal point convention of ``intrinsics`` (default "opencv": top-left pixel
        centre at (0, 0), as OpenCV, ROS and the TUM RGB-D parameters).
    polygon_convention : {"auto", "pixel-centres", "outline", "raster"}
        How polygon segmentations are read (module docstring,
        :mod:`sqfit.formats.coco_polygons`); RLE segmentations are masks either way.

    Returns
    -------
    scene : ImportedScene

    Raises
    ------
    OSError, ValueError
        Unreadable files (messages from the readers), a TUM trajectory without intrinsics, TUM
        options with another pose format, fewer than two COCO images with a pose, or an unknown
        polygon convention.
    """
    if polygon_convention not in POLYGON_READINGS:
        raise ValueError(f"polygon convention must be one of {list(POLYGON_READINGS)}, got {polygon_convention!r}")
    coco = read_coco(coco_path)
    pose_format = resolve_pose_format(poses_path, pose_format)
    tum_options = {"intrinsics": intrinsics, "image_times": image_times, "max_time_diff": max_time_diff,
                   "intrinsics_convention": intrinsics_convention}
    if pose_format in TRAJECTORY_FORMATS:
        from ..formats.trajectory import DEFAULT_MAX_TIME_DIFF, match_trajectory, read_intrinsics

        if intrinsics is None:
            raise ValueError(f"{poses_path} is a {pose_format.upper()} trajectory, which has no camera intrinsics: "
                             "give them (--intrinsics 'fx fy cx cy width height', or a file holding them)")
        camera = read_intrinsics(intrinsics, intrinsics_convention or "opencv")
        times, trajectory = TRAJECTORY_FORMATS[pose_format](poses_path)
        cameras, unusable = match_trajectory(coco.images, (times, trajectory), camera, image_times,
                                             DEFAULT_MAX_TIME_DIFF if max_time_diff is None else max_time_diff,
                                             str(poses_path))
        how = "matched by timestamp"
        hint = f"the trajectory spans t = {times[0]:.6f} .. {times[-1]:.6f} s"
    else:
        given = [name for name, value in tum_options.items() if value is not None]
        if given:
            raise ValueError(f"{', '.join(given)} only apply to a TUM trajectory; {poses_path} is a {pose_format} "
                             "pose source, which carries its own intrinsics and image names")
        poses = POSE_FORMATS[pose_format](poses_path)
        if not poses:
            raise ValueError(f"{poses_path} holds no image with a pose")
        cameras, unusable = match_cameras(coco.images, poses, str(poses_path))
        how = "matched by file name, then base name"
        hint = f"pose image names look like {sorted(poses)[:2]}"
    if coco.images and not cameras:
        raise ValueError(f"no image of {coco_path} can be used with the poses of {poses_path} ({how}): "
                         f"{next(iter(unusable.values()))}; {hint}")
    if coco.images and len(cameras) < C.MIN_VIEWS:
        raise ValueError(f"only {len(cameras)} image of {coco_path} can be used with the poses of {poses_path}; "
                         f"fitting needs >= {C.MIN_VIEWS} views of each object")
    reading, note = polygon_reading(_all_polygons(coco), polygon_convention)
    return ImportedScene(coco, cameras, unusable, reading, note)


def _all_polygons(coco):
    """Every well-formed polygon of the file's tracked annotations (malformed ones are reported per view)."""
    for by_image in coco.tracks.values():
        for anns in by_image.values():
            for ann in anns:
                try:
                    yield from coco.polygons(ann) or ()
                except ValueError:
                    pass


def observe_track(scene, track, n_samples=C.DEFAULT_SAMPLES, sampling="uniform", rng=None, cleanup=True):
    """Observations of one track in every image where it is annotated.

    Parameters
    ----------
    scene : ImportedScene
    track : int or str
        A key of ``scene.coco.tracks``.
    n_samples, sampling, rng, cleanup
        As :func:`sqfit.views.dataset.observe_views` (one generator, used view after view).

    Returns
    -------
    views : sqfit.views.dataset.ViewObservations
        Views indexed in the track's image order, named by COCO file name; views of unusable
        images, undecodable segmentations, empty masks and polygons that cannot be observed (no
        area in the image) are dropped with the reason.
    """
    from .dataset import ViewObservations

    coco = scene.coco
    image_ids = list(coco.tracks[track])
    names = [coco.images[i].file_name for i in image_ids]
    rng = np.random.default_rng(rng)
    observations, used, dropped = [], [], []
    for k, image_id in enumerate(image_ids):
        if image_id in scene.unusable:
            dropped.append((k, scene.unusable[image_id]))
            continue
        try:
            got = _observe_view(scene, image_id, track, n_samples, sampling, rng, cleanup)
        except ValueError as exc:
            dropped.append((k, str(exc)))
            continue
        if got is None:
            dropped.append((k, "the object's mask is empty in this view"))
            continue
        observations.append(got)
        used.append(k)
    return ViewObservations(observations, used, dropped, names)


def _observe_view(scene, image_id, track, n_samples, sampling, rng, cleanup):
    """The observation of ``track`` in one image (module docstring), or None if its mask is empty."""
    from .dataset import observations_from_images

    camera = scene.cameras[image_id]
    annotations = scene.coco.tracks[track][image_id]
    rings = _view_polygons(scene, annotations)
    if rings is None:
        got = observations_from_images([camera], _instance_image(scene, image_id, track)[None], 1, n_samples,
                                       sampling, rng, cleanup)
        return got[0] if got else None
    if not rings:
        return None
    own = np.zeros_like(scene.union_mask(image_id))
    for ann in annotations:
        own |= scene.annotation_mask(ann)
    return Observation.from_outline(camera, rings, "outline", n_samples, sampling, rng, cleanup,
                                    occluder=scene.union_mask(image_id) & ~own)


def _view_polygons(scene, annotations):
    """The outlines of a view's annotations when the polygon route takes it (all are polygons), else None."""
    if scene.polygons not in OUTLINE_CONVENTIONS:
        return None
    if not all(isinstance(ann.get("segmentation"), list) for ann in annotations):
        return None
    return [ring for ann in annotations for ring in scene.outlines(ann)]


def _instance_image(scene, image_id, track):
    """``(h, w) uint16``: 1 where ``track`` is, 2 where only other annotations of the image are, else 0."""
    out = scene.union_mask(image_id).astype(np.uint16) * 2
    for ann in scene.coco.tracks[track][image_id]:
        out[scene.annotation_mask(ann)] = 1
    return out


def track_rng(seed, track):
    """The sample generator of one track: ``SeedSequence([seed, crc32(str(track))])``.

    For a track id ``"<trial>/<object id>"`` (what ``sqsim generate`` writes) this is the seeding
    of ``sqfit fit`` on the native dataset, so both routes draw the same samples.
    """
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(str(track).encode())]))
