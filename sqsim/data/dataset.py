"""Write simulated trials to disk in the dataset format of ``sqfit.views.dataset``.

Each trial is written into ``DIR/trials/.tmp-NNNNNN-<pid>/`` and renamed to ``DIR/trials/NNNNNN``
(``os.replace``, atomic on one file system), so an interrupted or killed run never leaves a
half-written trial; stale ``.tmp-*`` directories are removed on the next start, and finished
trials are skipped, so re-running resumes. Files are byte-deterministic: a trial's bytes depend
only on the scene, the seed and its index (no timestamps; JSON with sorted keys and Python's
shortest round-trip float repr; PNGs through Pillow with a fixed compression level).
``annotations.json`` (COCO instances, RLE masks from pycocotools or polygons, a ``track_id`` per object,
:func:`build_annotations`) is rebuilt from all finished trials at the end of every run of
``sqsim generate`` (:mod:`sqsim.runs.generate`, which runs the trials over processes or Dask).
"""

from __future__ import annotations

import json
import os
import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from sqfit.views.dataset import FORMAT, FORMAT_VERSION, load_trial, trial_dirs, write_mask_png

from .. import __version__
from ..world.scene import OBJECT_KINDS, parse_scene
from .files import atomic_write_text

__all__ = ["write_trial", "staged_trial_dir", "prepare_dataset", "build_annotations", "trial_name", "dumps",
           "CATEGORIES"]

#: COCO category ids, one per object kind (stable: appended only).
CATEGORIES = [{"id": k + 1, "name": kind, "supercategory": "object"} for k, kind in enumerate(OBJECT_KINDS)]


def trial_name(index):
    """Directory name of trial ``index``: six digits."""
    return f"{int(index):06d}"


def dumps(obj):
    """JSON of a dataset file: sorted keys, no NaN, one trailing newline (byte-deterministic)."""
    return json.dumps(obj, sort_keys=True, indent=1, allow_nan=False) + "\n"


def write_trial(scene, index, root, renderer=None):
    """Simulate one trial of a trial scene and write it atomically to ``root/trials/NNNNNN``.

    A sequence scene's trial is a sequence: :func:`sqsim.data.sequence_dataset.write_sequence_trial`.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene or dict
        A dict is parsed (the picklable form used by worker processes).
    index : int
    root : str or os.PathLike
        Dataset directory.
    renderer : sqsim.imaging.render.Renderer, optional

    Returns
    -------
    resampled : int or None
        Re-draws of the trial; ``None`` if it already existed (nothing written).
    """
    from ..imaging.trial import simulate_trial

    if isinstance(scene, dict):
        scene = parse_scene(scene, source="<dataset>")
    if (Path(root) / "trials" / trial_name(index)).exists():
        return None
    sim = simulate_trial(scene, index, renderer)
    with staged_trial_dir(root, index) as tmp:
        views = []
        for k, (cam, true, image) in enumerate(zip(sim.cameras, sim.true_cameras, sim.images)):
            name = f"masks/view_{k:02d}.png"
            write_mask_png(tmp / name, image)
            views.append({"intrinsics": cam.intrinsics.to_dict(), "T_world_camera": cam.pose.tolist(),
                          "T_world_camera_true": true.pose.tolist(), "mask": name})
        (tmp / "cameras.json").write_text(dumps({"views": views}), encoding="utf-8")
        gt = {"trial": int(index), "seed": scene.experiment.seed, "resampled": sim.resampled,
              "objects": [o.to_dict() for o in sim.objects]}
        (tmp / "gt.json").write_text(dumps(gt), encoding="utf-8")
    return sim.resampled


@contextmanager
def staged_trial_dir(root, index):
    """Write trial ``index`` into a temporary directory that becomes ``trials/NNNNNN`` at once.

    Yields the temporary directory (with ``masks/`` made); on success it is renamed into place,
    on any exception (Ctrl-C included) removed, so a dataset never holds a half-written trial.
    """
    trials = Path(root) / "trials"
    tmp = trials / f".tmp-{trial_name(index)}-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "masks").mkdir(parents=True)
    try:
        yield tmp
        os.replace(tmp, trials / trial_name(index))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _comparable(scene_dict):
    """Scene identity for resuming: everything except the number of trials."""
    d = json.loads(json.dumps(scene_dict))
    d.get("experiment", {}).pop("trials", None)
    return d


def prepare_dataset(root, scene):
    """Create or check ``root/dataset.json`` for ``scene`` before trials are added.

    A directory holding another format, another scene or seed, or trials without ``dataset.json``
    is refused (ValueError); an existing dataset's trial count grows to the larger of the two, and
    stale ``.tmp-*`` directories of killed runs are removed.
    """
    root.mkdir(parents=True, exist_ok=True)
    (root / "trials").mkdir(exist_ok=True)
    meta_path = root / "dataset.json"
    meta = {"format": FORMAT, "version": FORMAT_VERSION, "scene": scene.to_dict(),
            "seed": scene.experiment.seed, "trials": scene.experiment.trials, "sqkit_version": __version__}
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{meta_path} is not valid JSON ({exc}); remove it or use another output") from None
        if old.get("format") != FORMAT or old.get("version") != FORMAT_VERSION:
            raise ValueError(f"{root} holds a dataset of another format/version "
                             f"({old.get('format')!r} v{old.get('version')}); use another output directory")
        if old.get("seed") != meta["seed"] or _comparable(old.get("scene", {})) != _comparable(meta["scene"]):
            raise ValueError(f"{root} holds a dataset made from a different scene or seed; "
                             "use another output directory or delete it")
        meta["trials"] = max(int(old.get("trials", 0)), meta["trials"])
        meta["scene"]["experiment"]["trials"] = meta["trials"]
    elif any(p for p in (root / "trials").iterdir() if not p.name.startswith(".")):
        raise ValueError(f"{root}/trials holds trials but no dataset.json; use another output directory")
    for stale in (root / "trials").glob(".tmp-*"):
        shutil.rmtree(stale, ignore_errors=True)
    atomic_write_text(meta_path, dumps(meta))


def build_annotations(root, polygons=None):
    """COCO instances of every finished trial of a dataset.

    ``images`` carry ``file_name`` (relative to the dataset), ``width``, ``height``, ``trial``,
    ``view``, ``intrinsics``, ``T_world_camera`` (the fitter's pose) and ``T_world_camera_true``;
    ``annotations`` carry an RLE ``segmentation`` (pycocotools, counts as ASCII) or, with
    ``polygons``, a list of polygons traced in that convention (``"opencv"`` or ``"skimage"``,
    :mod:`sqfit.formats.coco_polygons`; ``area`` and ``bbox`` then of the polygons as
    pycocotools rasterises them; ``info["mask_encoding"]`` names the choice), ``area``,
    ``bbox`` ``[x, y, w, h]``, ``category_id`` (the object kind), ``instance_id`` (the pixel
    value in the PNG) and ``track_id`` ``"NNNNNN/ID"`` (trial and instance id: unique across the
    dataset's trials, :func:`sqsim.data.export.track_id`), which groups views into objects for
    ``sqfit fit --coco``.

    Returns
    -------
    coco : dict
    """
    from sqfit.formats.coco import encode_mask
    from sqfit.formats.coco_polygons import encode_polygons

    from .export import track_id, view_file_name

    def encode(mask):
        return encode_mask(mask) if polygons is None else encode_polygons(mask, polygons)

    root = Path(root)
    images, annotations = [], []
    for path in trial_dirs(root):
        trial = load_trial(path)
        kinds = {int(o["id"]): o.get("kind", "superquadric") for o in trial.objects}
        for v, (cam, image) in enumerate(zip(trial.cameras, trial.images)):
            image_id = len(images) + 1
            true = trial.true_cameras[v] if trial.true_cameras else cam
            images.append({"id": image_id, "file_name": view_file_name(path.name, v),
                           "width": int(image.shape[1]), "height": int(image.shape[0]),
                           "trial": path.name, "view": v, "intrinsics": cam.intrinsics.to_dict(),
                           "T_world_camera": cam.pose.tolist(), "T_world_camera_true": true.pose.tolist()})
            for oid in [int(i) for i in np.unique(image) if i != 0]:
                segmentation, area, bbox = encode(image == oid)
                annotations.append({
                    "id": len(annotations) + 1, "image_id": image_id, "instance_id": oid, "iscrowd": 0,
                    "track_id": track_id(path.name, oid),
                    "category_id": OBJECT_KINDS.index(kinds.get(oid, "superquadric")) + 1,
                    "segmentation": segmentation, "area": area, "bbox": bbox})
    encoding = "rle" if polygons is None else f"polygons-{polygons}"
    return {"info": {"description": "sqkit simulated instance masks", "version": str(FORMAT_VERSION),
                     "mask_encoding": encoding},
            "images": images, "annotations": annotations, "categories": CATEGORIES}
