"""Fit objects of a user's scene: COCO instance masks + camera poses -> ``fits.jsonl``.

Joining the two files:

- Poses come from a pose source in :data:`POSE_FORMATS` (a COLMAP model directory, a JSON
  pose file), each a reader ``path -> {image name: sqfit.Camera}`` that does its own pose
  convention conversion once.
- A COCO image is matched to a pose by its ``file_name``: first the exact name (COLMAP stores
  names relative to its image folder, e.g. ``frames/0001.png``), else the base name
  (``0001.png``) when exactly one pose has it. A COCO image with no match, or whose
  ``width`` x ``height`` differs from its camera's, cannot be used: each object seen there
  records that view as dropped, with the reason. No match at all is an error.
- Objects are the tracks of :mod:`sqfit.formats.coco` (``track_id``); an object's views are the
  images where its track has an annotation (several annotations of one track in one image are
  merged). Each view is observed from an instance image holding the object (id 1) over every
  other annotation of that image (id 2), through :func:`sqfit.io.observe_views`, so a view with
  an empty mask is dropped with a warning exactly as in a native dataset.

Records are those of ``sqfit fit`` on a native dataset (:mod:`sqfit.fitcli`) with ``trial``
null, ``object_id`` and ``track_id`` the track id and ``images`` the file names of the views
used. Samples are seeded per track from ``SeedSequence([seed, crc32(str(track_id))])``, which is
the native seeding when the track id is ``"<trial>/<object id>"`` (what ``sqsim generate``
writes), so an exported dataset fits to the same parameters as the native one.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from .. import constants as C
from .coco import read_coco
from .colmap import read_colmap
from .posejson import read_pose_json

__all__ = ["POSE_FORMATS", "detect_pose_format", "read_poses", "ImportedScene", "match_cameras", "load_import",
           "observe_track", "fit_import"]

#: Pose sources: name -> reader ``path -> {image name: sqfit.Camera (T_world_camera)}``.
#: A new source (e.g. TUM trajectories) is one reader here and one rule in detect_pose_format.
POSE_FORMATS = {"colmap": read_colmap, "json": read_pose_json}


def detect_pose_format(path):
    """``"colmap"`` for a directory, ``"json"`` for a ``.json`` file; ValueError otherwise."""
    path = Path(path)
    if path.is_dir():
        return "colmap"
    if path.suffix.lower() == ".json":
        return "json"
    raise ValueError(f"cannot tell the pose format of {path} (a COLMAP model directory or a .json file); "
                     f"name it with --pose-format ({', '.join(POSE_FORMATS)})")


def read_poses(path, pose_format="auto"):
    """``{image name: sqfit.Camera}`` from a pose source (``pose_format`` in POSE_FORMATS or "auto")."""
    if pose_format == "auto":
        if not Path(path).exists():
            raise OSError(f"pose source not found: {path}")
        pose_format = detect_pose_format(path)
    if pose_format not in POSE_FORMATS:
        raise ValueError(f"pose format must be one of {['auto', *POSE_FORMATS]}, got {pose_format!r}")
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
        ``COCO image id -> reason`` for the others (no pose, size mismatch).
    """

    coco: object
    cameras: dict
    unusable: dict
    _union: dict = field(default_factory=dict, repr=False)  # image id -> RLE of all its annotations

    def union_mask(self, image_id):
        """``(h, w) bool``: pixels of any annotation of an image (each image decoded once, kept as RLE)."""
        from .coco import decode_segmentation, encode_mask

        image = self.coco.images[image_id]
        if image_id not in self._union:
            union = np.zeros((image.height, image.width), dtype=bool)
            for by_image in self.coco.tracks.values():
                for ann in by_image.get(image_id, []):
                    try:
                        union |= self.coco.mask(ann)
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
    by_base = {}
    for name in poses:
        by_base.setdefault(PurePosixPath(name.replace("\\", "/")).name, []).append(name)
    cameras, unusable = {}, {}
    for image_id, image in images.items():
        name = image.file_name
        candidates = [name] if name in poses else by_base.get(PurePosixPath(name.replace("\\", "/")).name, [])
        if len(candidates) != 1:
            how = "no pose with this file name or base name" if not candidates else \
                f"base name matches {len(candidates)} poses ({', '.join(sorted(candidates)[:3])}); use full names"
            unusable[image_id] = f"image {name!r} is not in {source}: {how}"
            continue
        cam = poses[candidates[0]]
        if (cam.intrinsics.width, cam.intrinsics.height) != (image.width, image.height):
            unusable[image_id] = (f"image {name!r} is {image.width}x{image.height} in COCO but its camera in "
                                  f"{source} is {cam.intrinsics.width}x{cam.intrinsics.height}")
            continue
        cameras[image_id] = cam
    return cameras, unusable


def load_import(coco_path, poses_path, pose_format="auto"):
    """Read a COCO instance file and a pose source and join them.

    Parameters
    ----------
    coco_path : str or os.PathLike
    poses_path : str or os.PathLike
        COLMAP model directory or JSON pose file.
    pose_format : {"auto", "colmap", "json"}

    Returns
    -------
    scene : ImportedScene

    Raises
    ------
    OSError, ValueError
        Unreadable files (messages from the readers), or fewer than two COCO images with a pose.
    """
    coco = read_coco(coco_path)
    poses = read_poses(poses_path, pose_format)
    cameras, unusable = match_cameras(coco.images, poses, str(poses_path))
    if not poses:
        raise ValueError(f"{poses_path} holds no image with a pose")
    if coco.images and not cameras:
        raise ValueError(f"no image of {coco_path} can be used with the poses of {poses_path} (matched by file "
                         f"name, then base name): {next(iter(unusable.values()))}; pose image names look like "
                         f"{sorted(poses)[:2]}")
    if coco.images and len(cameras) < C.MIN_VIEWS:
        raise ValueError(f"only {len(cameras)} image of {coco_path} can be used with the poses of {poses_path}; "
                         f"fitting needs >= {C.MIN_VIEWS} views of each object")
    return ImportedScene(coco, cameras, unusable)


def observe_track(scene, track, n_samples=C.DEFAULT_SAMPLES, sampling="uniform", rng=None, cleanup=True):
    """Observations of one track in every image where it is annotated.

    Parameters
    ----------
    scene : ImportedScene
    track : int or str
        A key of ``scene.coco.tracks``.
    n_samples, sampling, rng, cleanup
        As :func:`sqfit.io.observe_views`.

    Returns
    -------
    views : sqfit.io.ViewObservations
        Views indexed in the track's image order, named by COCO file name; views of unusable
        images, undecodable segmentations and empty masks are dropped with the reason.
    """
    from ..io import ViewObservations, observe_views

    coco = scene.coco
    image_ids = list(coco.tracks[track])
    names = [coco.images[i].file_name for i in image_ids]
    usable, cams, images, dropped = [], [], [], []
    for k, image_id in enumerate(image_ids):
        if image_id in scene.unusable:
            dropped.append((k, scene.unusable[image_id]))
            continue
        try:
            images.append(_instance_image(scene, image_id, track))
        except ValueError as exc:
            dropped.append((k, str(exc)))
            continue
        usable.append(k)
        cams.append(scene.cameras[image_id])
    got = observe_views(cams, images, 1, n_samples, sampling, rng, cleanup)
    dropped += [(usable[k], reason) for k, reason in got.dropped]
    return ViewObservations(got.observations, [usable[k] for k in got.views], sorted(dropped), names)


def _instance_image(scene, image_id, track):
    """``(h, w) uint16``: 1 where ``track`` is, 2 where only other annotations of the image are, else 0."""
    out = scene.union_mask(image_id).astype(np.uint16) * 2
    for ann in scene.coco.tracks[track][image_id]:
        out[scene.coco.mask(ann)] = 1
    return out


def _track_rng(seed, track):
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(str(track).encode())]))


def fit_import(coco_path, poses_path, output, chain, samples=C.DEFAULT_SAMPLES, sampling="uniform", polygon="hull",
               seed=0, progress=True, cleanup=True, pose_format="auto"):
    """Fit every track of a COCO file with cameras from a pose source; write ``fits.jsonl``.

    Parameters
    ----------
    coco_path, poses_path, pose_format
        As :func:`load_import`.
    output : str or os.PathLike
        JSON-lines file (one record per track; module docstring).
    chain, samples, sampling, polygon, seed, progress, cleanup
        As ``sqfit fit`` (:func:`sqfit.fitcli.fit_dataset`).

    Returns
    -------
    n_records, n_not_ok : int
    """
    from tqdm import tqdm

    from ..pipeline import FitOptions, fit, parse_chain

    parse_chain(chain)
    options = FitOptions(polygon=polygon)
    scene = load_import(coco_path, poses_path, pose_format)
    out_path = Path(output)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    n_records = n_errors = 0
    with open(out_path, "w", encoding="utf-8") as out:
        for track in tqdm(scene.track_ids, desc="sqfit fit", unit="object", disable=not progress):
            record = {"trial": None, "object_id": track, "track_id": track}
            try:
                views = observe_track(scene, track, samples, sampling, _track_rng(seed, track), cleanup)
                record.update(views.record(fit(views.observations, chain, options=options)))
                if record["status"] == "too_few_views":
                    record["message"] = (f"track {track!r} has {len(views.views)} usable view(s) "
                                         f"{record['images']}; fitting needs >= {C.MIN_VIEWS}")
            except (OSError, ValueError, TypeError) as exc:
                record.update({"chain": chain, "status": "error", "message": str(exc)})
            n_errors += record["status"] != "ok"
            out.write(json.dumps(record) + "\n")
            n_records += 1
    return n_records, n_errors
