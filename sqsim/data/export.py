"""Export a generated dataset's cameras as a COLMAP model, for the COCO + COLMAP import path.

``sqsim generate --colmap`` writes ``DIR/sparse/0/`` (text files, through pycolmap's
``Reconstruction`` in :func:`sqfit.formats.write_colmap`): one image per (trial, view) named like
its COCO ``file_name`` in ``DIR/annotations.json`` (``trials/NNNNNN/masks/view_VV.png``), posed
with the pose the fitter uses (``T_world_camera``, noisy if the scene adds pose noise), one
PINHOLE camera per distinct intrinsics, no 3D points. Every trial is its own scene, so the
model overlays all trials in one world frame; objects stay apart because their COCO track ids
(``"NNNNNN/ID"``, :func:`track_id`) are unique across trials. Then

    sqfit fit --coco DIR/annotations.json --poses DIR/sparse/0 -o fits.jsonl

fits every object, to the same parameters as ``sqfit fit DIR`` (same seeds, same masks).
Like ``annotations.json``, the model is rebuilt from all finished trials at the end of every
run, into a temporary directory renamed into place.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from sqfit.views.dataset import load_trial, trial_dirs

__all__ = ["COLMAP_DIR", "track_id", "view_file_name", "write_colmap_model"]

#: Where ``sqsim generate --colmap`` writes the model, relative to the dataset.
COLMAP_DIR = Path("sparse") / "0"


def track_id(trial_name, object_id):
    """COCO ``track_id`` of an object of a trial: ``"NNNNNN/ID"``, unique across a dataset's trials."""
    return f"{trial_name}/{int(object_id)}"


def view_file_name(trial_name, view):
    """Image name of a view in ``annotations.json`` and in the COLMAP model (relative to the dataset)."""
    return f"trials/{trial_name}/masks/view_{int(view):02d}.png"


def write_colmap_model(root):
    """Write ``root/sparse/0`` from every finished trial of a dataset.

    Parameters
    ----------
    root : str or os.PathLike
        Dataset directory.

    Returns
    -------
    path : pathlib.Path
        The model directory.
    """
    from sqfit.formats import write_colmap

    root = Path(root)
    cameras = {}
    for path in trial_dirs(root):
        for v, cam in enumerate(load_trial(path).cameras):
            cameras[view_file_name(path.name, v)] = cam
    final = root / COLMAP_DIR
    tmp = final.with_name(f".tmp-{final.name}-{os.getpid()}")
    old = final.with_name(f".old-{final.name}-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        write_colmap(tmp, cameras)
        if final.exists():
            os.replace(final, old)
        os.replace(tmp, final)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
    return final
