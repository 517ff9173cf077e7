"""``sqsim generate`` for sequence scenes: one sequence per trial directory, plus TUM trajectories.

Same guarantees as ``sqsim.data.dataset`` (whose ``generate`` calls in here for a sequence scene): a
sequence is written into ``trials/.tmp-NNNNNN-<pid>/`` and renamed to ``trials/NNNNNN`` (atomic),
finished sequences are skipped on a re-run, and every byte depends only on the scene, the seed and
the index. Layout of a sequence directory: ``sqfit.views.sequence`` (module docstring).

At the end of every run, ``annotations.json`` (COCO) is rebuilt: one image per frame (with
``frame``, ``timestamp``, ``T_world_camera`` = the odometry pose and ``T_world_camera_true``),
one annotation per *observed* (frame, object) pair, with ``track_id`` = the object's id (the same
object in every frame); a dataset of exactly one sequence also gets ``DIR/true.tum`` and
``DIR/odometry.tum``, byte copies of the sequence's own.
"""

from __future__ import annotations

import json
from pathlib import Path

from sqfit.formats.tum import write_tum
from sqfit.views.dataset import trial_dirs, write_mask_png

__all__ = ["write_sequence_trial", "finish_sequence_dataset", "sequence_annotations", "TRAJECTORY_FILES"]

#: The trajectories of a sequence, TUM format (camera -> world).
TRAJECTORY_FILES = ("true.tum", "odometry.tum")


def write_sequence_trial(scene, index, root, renderer=None):
    """Simulate sequence ``index`` and write it atomically to ``root/trials/NNNNNN``.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
        A sequence scene.
    index : int
    root : str or os.PathLike
    renderer : sqsim.imaging.render.Renderer, optional

    Returns
    -------
    resampled : int or None
        Re-draws of the sequence; ``None`` if it already existed (nothing written).
    """
    from .dataset import dumps, staged_trial_dir, trial_name
    from ..imaging.sequence import simulate_sequence

    if (Path(root) / "trials" / trial_name(index)).exists():
        return None
    seq = simulate_sequence(scene, scene.experiment.seed, index, renderer)
    with staged_trial_dir(root, index) as tmp:
        views = []
        for k in range(seq.n_frames):
            name = f"masks/view_{k:02d}.png"
            write_mask_png(tmp / name, seq.images[k])
            views.append({"intrinsics": seq.intrinsics.to_dict(), "T_world_camera": seq.odometry_poses[k].tolist(),
                          "T_world_camera_true": seq.true_poses[k].tolist(), "mask": name, "frame": k,
                          "timestamp": float(seq.timestamps[k])})
        (tmp / "cameras.json").write_text(dumps({"sequence": {"frames": seq.n_frames}, "views": views}),
                                          encoding="utf-8")
        gt = {"trial": int(index), "seed": scene.experiment.seed, "resampled": seq.resampled,
              "objects": [o.to_dict() for o in seq.scene_objects],
              "observed": [[int(i) for i in seq.object_ids[row]] for row in seq.observed]}
        (tmp / "gt.json").write_text(dumps(gt), encoding="utf-8")
        write_tum(tmp / "true.tum", seq.timestamps, seq.true_poses)
        write_tum(tmp / "odometry.tum", seq.timestamps, seq.odometry_poses)
    return seq.resampled


def sequence_annotations(root):
    """COCO instances of every finished sequence (see the module docstring).

    Returns
    -------
    coco : dict
    """
    from .dataset import build_annotations

    root = Path(root)
    coco = build_annotations(root)
    frames = {}
    for path in trial_dirs(root):
        views = json.loads((path / "cameras.json").read_text(encoding="utf-8"))["views"]
        observed = json.loads((path / "gt.json").read_text(encoding="utf-8"))["observed"]
        for k, view in enumerate(views):
            frames[(path.name, k)] = (view["frame"], view["timestamp"], set(observed[k]))
    keep = {}
    for image in coco["images"]:
        frame, timestamp, ids = frames[(image["trial"], image["view"])]
        image.update(frame=frame, timestamp=timestamp)
        keep[image["id"]] = ids
    annotations = [a for a in coco["annotations"] if a["instance_id"] in keep[a["image_id"]]]
    for k, a in enumerate(annotations, start=1):
        a.update(id=k, track_id=int(a["instance_id"]))
    coco["annotations"] = annotations
    coco["info"]["description"] = "sqkit simulated image sequences"
    return coco


def finish_sequence_dataset(root):
    """Write ``annotations.json`` and, for a single sequence, ``DIR/true.tum`` / ``DIR/odometry.tum``."""
    from .files import atomic_write_text

    root = Path(root)
    atomic_write_text(root / "annotations.json", json.dumps(sequence_annotations(root), sort_keys=True) + "\n")
    sequences = trial_dirs(root)
    for name in TRAJECTORY_FILES:
        if len(sequences) == 1:
            atomic_write_text(root / name, (sequences[0] / name).read_text(encoding="utf-8"))
        elif (root / name).exists():
            (root / name).unlink()
