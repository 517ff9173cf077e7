"""Image sequences: frames with timestamps, true and odometry poses, instance images, objects.

A :class:`Sequence` is what a SLAM back end (the factor graph) consumes: ``n`` frames, ordered by
time, each with a pose from odometry (``odometry_poses``, what a robot knows), the true pose when
known (``true_poses``), and an instance-id image (``images[k]``, ``(h, w) uint16``, 0 =
background, ``j`` = object ``j``; the full image, so occluders and image borders can be told
apart later). ``observed[k, i]`` says whether object ``object_ids[i]`` counts as observed in frame
``k`` (its visible pixels reach the scene's ``min_area_px``; cut by the border or partly hidden
still counts). Poses are ``T_world_camera`` (camera -> world, ``sqfit.geometry.camera``).

On disk (written by ``sqsim generate`` for a sequence scene; read by :func:`load_sequence`), one
sequence is a trial directory of the ``sqfit.views.dataset`` layout plus two TUM files::

    trials/NNNNNN/cameras.json    {"sequence": {"frames": n}, "views": [{"intrinsics": ..., "T_world_camera":
                                   odometry pose, "T_world_camera_true": true pose, "mask":
                                   "masks/view_VV.png", "frame": k, "timestamp": t}, ...]}
    trials/NNNNNN/masks/view_VV.png   uint16 instance ids per frame
    trials/NNNNNN/gt.json         {"objects": [...], "observed": [[ids observed in frame 0], ...], ...}
    trials/NNNNNN/true.tum        true trajectory, TUM (sqfit.formats.tum)
    trials/NNNNNN/odometry.tum    odometry trajectory, TUM

A dataset of a single sequence also has ``DIR/true.tum`` and ``DIR/odometry.tum`` (copies).
"""

from __future__ import annotations

import collections.abc
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera, Intrinsics
from ..formats.tum import read_tum
from ..geometry.superquadric import Superquadric
from ..formats.jsonfile import read_json
from .dataset import read_mask_png

__all__ = ["Sequence", "LazyImages", "load_sequence"]


class LazyImages(collections.abc.Sequence):
    """Instance-id images read from PNG files on access: ``images[k] -> (h, w) uint16``.

    Parameters
    ----------
    paths : list of pathlib.Path
    shape : (2,) int
        ``(height, width)`` every image must have.
    """

    def __init__(self, paths, shape):
        self._paths = list(paths)
        self._shape = tuple(shape)

    def __len__(self):
        return len(self._paths)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        image = read_mask_png(self._paths[k])
        if image.shape != self._shape:
            raise ValueError(f"{self._paths[k]}: mask has shape {image.shape}, intrinsics say "
                             f"(height, width) = {self._shape}")
        return image


@dataclass(frozen=True, eq=False)
class Sequence:
    """One image sequence (module docstring); arrays are read-only.

    Attributes
    ----------
    timestamps : (n,) float
        Seconds, strictly increasing.
    intrinsics : Intrinsics
        Shared by every frame.
    true_poses : (n, 4, 4) float or None
        ``T_world_camera`` the images were made from (None for data without ground truth).
    odometry_poses : (n, 4, 4) float
        ``T_world_camera`` from odometry (drifting; ``odometry_poses[0] == true_poses[0]`` in
        simulated sequences).
    images : sequence of (h, w) uint16
        Instance ids per frame: an ``(n, h, w)`` array in memory, a :class:`LazyImages` when
        loaded from disk.
    objects : dict of int -> Superquadric or None
        Ground truth by instance id (None for the mesh kinds; empty without ground truth).
    object_ids : (m,) int
        Sorted ids of the objects.
    observed : (n, m) bool
        ``observed[k, i]``: object ``object_ids[i]`` is observed in frame ``k``.
    object_kinds : dict of int -> str
        Kind of each object (``"superquadric"``, ``"box"``, ...).
    name : str
    """

    timestamps: np.ndarray
    intrinsics: Intrinsics
    true_poses: np.ndarray | None
    odometry_poses: np.ndarray
    images: object
    objects: dict
    object_ids: np.ndarray
    observed: np.ndarray
    object_kinds: dict
    name: str = "sequence"

    def __post_init__(self):
        n = len(self.timestamps)
        shapes = {"timestamps": (n,), "odometry_poses": (n, 4, 4), "observed": (n, len(self.object_ids))}
        if self.true_poses is not None:
            shapes["true_poses"] = (n, 4, 4)
        for field, shape in shapes.items():
            value = np.array(getattr(self, field), dtype=bool if field == "observed" else np.float64)
            if value.shape != shape:
                raise ValueError(f"Sequence.{field} must have shape {shape}, got {value.shape}")
            value.flags.writeable = False
            object.__setattr__(self, field, value)
        if len(self.images) != n:
            raise ValueError(f"Sequence.images must hold {n} frames, got {len(self.images)}")
        ids = np.array(self.object_ids, dtype=np.int64)
        ids.flags.writeable = False
        object.__setattr__(self, "object_ids", ids)

    @property
    def n_frames(self):
        """``int``: number of frames."""
        return len(self.timestamps)

    def cameras(self, which="odometry"):
        """``list of Camera`` of every frame, at the ``"odometry"`` or ``"true"`` poses."""
        if which not in ("odometry", "true"):
            raise ValueError(f"which must be 'odometry' or 'true', got {which!r}")
        poses = self.odometry_poses if which == "odometry" else self.true_poses
        if poses is None:
            raise ValueError(f"sequence {self.name!r} has no true poses")
        return [Camera(self.intrinsics, T) for T in poses]

    def frames_observing(self, object_id):
        """``(k,) int``: frames in which an object is observed."""
        hit = np.flatnonzero(self.object_ids == int(object_id))
        if not hit.size:
            raise ValueError(f"sequence {self.name!r} has no object {object_id} (ids: {self.object_ids.tolist()})")
        return np.flatnonzero(self.observed[:, hit[0]])


def _sequence_dir(directory):
    path = Path(directory)
    if not path.is_dir():
        raise OSError(f"sequence directory not found: {path}")
    if (path / "cameras.json").is_file():
        return path
    trials = path / "trials"
    found = sorted(p for p in trials.iterdir() if p.is_dir() and not p.name.startswith(".")) if trials.is_dir() else []
    if not found:
        raise ValueError(f"{path} is not a sequence: no cameras.json and no trials/NNNNNN directory")
    if len(found) > 1:
        raise ValueError(f"{path} holds {len(found)} sequences under trials/; pass one of them "
                         f"(e.g. {found[0]})")
    return found[0]


def load_sequence(directory):
    """Load a sequence written by ``sqsim generate`` (layout: module docstring).

    Parameters
    ----------
    directory : str or os.PathLike
        A sequence's trial directory, or a dataset directory holding exactly one sequence.

    Returns
    -------
    sequence : Sequence
        Images are read lazily (:class:`LazyImages`).

    Raises
    ------
    OSError
        Missing directory or file.
    ValueError
        Not a sequence, malformed files, or files that disagree (frame counts, timestamps).
    """
    path = _sequence_dir(directory)
    meta = read_json(path / "cameras.json")
    views = meta.get("views") if isinstance(meta, dict) else None
    if not isinstance(meta, dict) or "sequence" not in meta or not isinstance(views, list) or not views:
        raise ValueError(f"{path / 'cameras.json'} is not a sequence (no 'sequence' record or no views); "
                         "multi-view trials are read with sqfit.views.dataset.load_trial")
    try:
        intrinsics = Intrinsics(**views[0]["intrinsics"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path / 'cameras.json'} view 0: bad intrinsics: {exc}") from None
    times, odometry = read_tum(path / "odometry.tum")
    true_times, true_poses = read_tum(path / "true.tum") if (path / "true.tum").exists() else (times, None)
    stamps = np.array([v.get("timestamp", np.nan) for v in views], dtype=np.float64)
    for name, t in (("odometry.tum", times), ("true.tum", true_times)):
        if len(t) != len(views) or not np.array_equal(t, stamps):
            raise ValueError(f"{path / name} has {len(t)} poses whose timestamps do not match the "
                             f"{len(views)} frames of cameras.json")
    images = LazyImages([path / v.get("mask", f"masks/view_{k:02d}.png") for k, v in enumerate(views)],
                        (intrinsics.height, intrinsics.width))
    gt = read_json(path / "gt.json") if (path / "gt.json").exists() else {}
    records = {int(o["id"]): o for o in gt.get("objects", [])}
    objects = {i: Superquadric.from_vector(o["params"]) if "params" in o else None for i, o in records.items()}
    ids = sorted(records)
    if "observed" in gt:
        if len(gt["observed"]) != len(views):
            raise ValueError(f"{path / 'gt.json'}: 'observed' has {len(gt['observed'])} frames, expected {len(views)}")
        observed = np.array([[i in set(frame) for i in ids] for frame in gt["observed"]], dtype=bool)
    else:  # a user's sequence: every non-empty mask is an observation
        present = [set(np.unique(images[k]).tolist()) for k in range(len(images))]
        ids = ids or sorted(set().union(*present) - {0})
        observed = np.array([[i in frame for i in ids] for frame in present], dtype=bool).reshape(len(views), len(ids))
    return Sequence(timestamps=times, intrinsics=intrinsics, true_poses=true_poses, odometry_poses=odometry,
                    images=images, objects=objects, object_ids=np.array(ids, dtype=np.int64), observed=observed,
                    object_kinds={i: o.get("kind", "superquadric") for i, o in records.items()},
                    name=f"{path.parent.parent.name}/{path.name}" if path.parent.name == "trials" else path.name)
