"""``sqsim generate``: write simulated trials to disk in the dataset format of ``sqfit.io``.

Each trial is written into ``DIR/trials/.tmp-NNNNNN-<pid>/`` and renamed to ``DIR/trials/NNNNNN``
(``os.replace``, atomic on one file system), so an interrupted or killed run never leaves a
half-written trial; stale ``.tmp-*`` directories are removed on the next start, and finished
trials are skipped, so re-running resumes. Files are byte-deterministic: a trial's bytes depend
only on the scene, the seed and its index (no timestamps; JSON with sorted keys and Python's
shortest round-trip float repr; PNGs through Pillow with a fixed compression level).
``annotations.json`` (COCO instances, RLE masks from pycocotools, or polygons with
``--coco-polygons``, a ``track_id`` per object) is rebuilt from all finished trials at the end
of every run, and so is the COLMAP model ``sparse/0`` with ``--colmap`` (:mod:`sqsim.export`).
"""

from __future__ import annotations

import json
import os
import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from sqfit.io import FORMAT, FORMAT_VERSION, load_trial, trial_dirs, write_mask_png

from . import __version__
from ._files import atomic_write_text
from .scene import OBJECT_KINDS, load_scene, parse_scene
from .sequence_dataset import finish_sequence_dataset, write_sequence_trial
from .trajectory import is_sequence

__all__ = ["generate", "write_trial", "build_annotations", "trial_name", "add_arguments", "run"]

#: COCO category ids, one per object kind (stable: appended only).
CATEGORIES = [{"id": k + 1, "name": kind, "supercategory": "object"} for k, kind in enumerate(OBJECT_KINDS)]


def trial_name(index):
    return f"{int(index):06d}"


def _dumps(obj):
    return json.dumps(obj, sort_keys=True, indent=1, allow_nan=False) + "\n"


def write_trial(scene, index, root, renderer=None):
    """Simulate one trial and write it atomically to ``root/trials/NNNNNN``.

    Parameters
    ----------
    scene : sqsim.scene.Scene or dict
        A dict is parsed (the picklable form used by worker processes).
    index : int
    root : str or os.PathLike
        Dataset directory.
    renderer : sqsim.render.Renderer, optional

    Returns
    -------
    resampled : int or None
        Re-draws of the trial; ``None`` if it already existed (nothing written).
    """
    from .trial import simulate_trial

    if isinstance(scene, dict):
        scene = parse_scene(scene, source="<dataset>")
    if is_sequence(scene):
        return write_sequence_trial(scene, index, root, renderer)
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
        (tmp / "cameras.json").write_text(_dumps({"views": views}), encoding="utf-8")
        gt = {"trial": int(index), "seed": scene.experiment.seed, "resampled": sim.resampled,
              "objects": [o.to_dict() for o in sim.objects]}
        (tmp / "gt.json").write_text(_dumps(gt), encoding="utf-8")
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


def _ignore_sigint():
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


_PARSED = {}


def _worker(scene_dict, index, root):
    # Runs in a worker process: the renderer and its OpenGL context are created here. The parsed
    # scene is kept, so its cameras are built once per process, not once per trial.
    key = json.dumps(scene_dict, sort_keys=True)
    scene = _PARSED.get(key)
    if scene is None:
        scene = parse_scene(scene_dict, source="<dataset>")
        _PARSED.clear()
        _PARSED[key] = scene
    return index, write_trial(scene, index, root)


def _comparable(scene_dict):
    """Scene identity for resuming: everything except the number of trials."""
    d = json.loads(json.dumps(scene_dict))
    d.get("experiment", {}).pop("trials", None)
    return d


def _prepare(root, scene):
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
    atomic_write_text(meta_path, _dumps(meta))


def generate(scene, output, trials=None, seed=None, workers=1, progress=True, scheduler=None, rerun=None,
             rerun_trials=None, colmap=False, coco_polygons=None):
    """Write (or complete) a dataset.

    Parameters
    ----------
    scene : sqsim.scene.Scene
    output : str or os.PathLike
        Dataset directory (created).
    trials, seed : int, optional
        Override ``experiment.trials`` / ``experiment.seed``.
    workers : int
        Processes (``1``: in this process; otherwise a spawn-context process pool).
    progress : bool
        Show a tqdm progress bar on stderr.
    scheduler : str, optional
        Dask scheduler address ``tcp://HOST:PORT`` (overrides ``workers``); the workers must see
        ``output`` on a shared file system. The bytes written do not depend on where a trial ran.
    rerun : str or os.PathLike, optional
        Also write a rerun recording (``.rrd``) of the dataset's trials: cameras, masks, ground
        truth (:class:`sqfit.recording.Recorder`).
    rerun_trials : int, optional
        Record only the first ``rerun_trials`` trials (default: all).
    colmap : bool
        Also write the cameras as a COLMAP text model ``DIR/sparse/0`` (:mod:`sqsim.export`).
    coco_polygons : str, optional
        Write the masks in ``annotations.json`` as polygons traced the way ``"opencv"``
        (detectron2) or ``"skimage"`` does (:mod:`sqfit.formats.coco_polygons`); default RLE.

    Returns
    -------
    summary : dict
        ``{"written": int, "skipped": int, "resampled": int (of the trials written now)}``.
    """
    overrides = {}
    if trials is not None:
        overrides["experiment.trials"] = trials
    if seed is not None:
        overrides["experiment.seed"] = seed
    if overrides:
        scene = scene.with_overrides(overrides)
    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers}")
    if colmap and is_sequence(scene):
        raise ValueError("--colmap exports trial datasets; a sequence scene (trajectory.kind = "
                         f"{scene.trajectory.kind!r}) writes its poses as TUM trajectories (true.tum, odometry.tum)")
    if coco_polygons is not None:
        from sqfit.formats.coco_polygons import POLYGON_CONVENTIONS

        if coco_polygons not in POLYGON_CONVENTIONS:
            raise ValueError(f"--coco-polygons must be one of {list(POLYGON_CONVENTIONS)}, got {coco_polygons!r}")
        if is_sequence(scene):
            raise ValueError("--coco-polygons writes trial datasets; a sequence scene (trajectory.kind = "
                             f"{scene.trajectory.kind!r}) writes its COCO masks as RLE")
    if rerun is not None and is_sequence(scene):
        raise ValueError("--rerun records trial datasets; recording a sequence scene (trajectory.kind = "
                         f"{scene.trajectory.kind!r}) is not supported yet")
    if rerun is not None:
        from sqfit.recording import check_recording_path

        check_recording_path(rerun, rerun_trials)
    root = Path(output)
    _prepare(root, scene)
    present = {p.name for p in (root / "trials").iterdir()}  # one listing, not a stat per trial
    todo = [i for i in range(scene.experiment.trials) if trial_name(i) not in present]
    skipped = scene.experiment.trials - len(todo)
    results = _run(scene, todo, root, int(workers), scheduler, progress)
    if is_sequence(scene):
        finish_sequence_dataset(root)
    else:
        atomic_write_text(root / "annotations.json",
                          json.dumps(build_annotations(root, coco_polygons), sort_keys=True) + "\n")
    if colmap:
        from .export import write_colmap_model

        write_colmap_model(root)
    if rerun is not None:
        from sqfit.recording import Recorder

        with Recorder(rerun, max_trials=rerun_trials) as recorder:
            for path in trial_dirs(root):
                if not recorder.admits(path.name):
                    recorder.skipped.add(path.name)  # counted, not read
                    continue
                recorder.log_loaded_trial(load_trial(path))
    return {"written": sum(r is not None for r in results), "skipped": skipped,
            "resampled": int(sum(r or 0 for r in results))}


def _run(scene, todo, root, workers, scheduler, progress):
    from tqdm import tqdm

    bar = tqdm(total=len(todo), unit="trial", disable=not progress or not todo, desc="generate")
    results = []
    try:
        if scheduler is None and (workers == 1 or len(todo) <= 1):
            for i in todo:
                results.append(write_trial(scene, i, root))
                bar.update()
            return results
        from .parallel import map_unordered

        # Bounded submissions (sqsim.parallel): on Ctrl-C or an error the queued trials are
        # dropped and each worker finishes (and renames) the trial it is writing; local workers
        # ignore SIGINT so none dies half-way through a trial.
        scene_dict = scene.to_dict()
        args = ((scene_dict, i, str(root.resolve())) for i in todo)
        for _, resampled in map_unordered(_worker, args, workers=workers, scheduler=scheduler,
                                          initializer=_ignore_sigint, wait_on_exit=True):
            results.append(resampled)
            bar.update()
        return results
    finally:
        bar.close()


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
    dataset's trials, :func:`sqsim.export.track_id`), which groups views into objects for
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


# --- command line -----------------------------------------------------------------------------------

def add_arguments(parser):
    parser.add_argument("scene", help="scene TOML file (keys: README, \"Scene files\"; example: scenes/paper.toml)")
    parser.add_argument("-o", "--output", required=True, help="dataset directory (created; re-running resumes)")
    parser.add_argument("--trials", type=int, default=None, help="number of trials (default: experiment.trials)")
    parser.add_argument("--seed", type=int, default=None, help="seed (default: experiment.seed)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--scheduler", default=None,
                        help="Dask scheduler address tcp://HOST:PORT (overrides --workers; the output "
                             "directory must be on a file system the workers share)")
    from sqfit.recording import add_arguments as add_rerun_arguments

    add_rerun_arguments(parser, "the dataset's cameras, masks and ground truth")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--colmap", action="store_true",
                        help="also write the cameras as a COLMAP text model DIR/sparse/0 (for sqfit fit --coco)")
    parser.add_argument("--coco-polygons", choices=["opencv", "skimage"], default=None,
                        help="write the masks in annotations.json as polygons, traced as detectron2 does "
                             "(opencv: contours through the boundary pixels' centres, +0.5) or as "
                             "skimage.measure.find_contours at 0.5 (the exact outline); default RLE")


def run(args):
    scene = load_scene(args.scene)
    summary = generate(scene, args.output, trials=args.trials, seed=args.seed, workers=args.workers,
                       progress=not args.no_progress, scheduler=args.scheduler, rerun=args.rerun,
                       rerun_trials=args.rerun_trials, colmap=args.colmap, coco_polygons=args.coco_polygons)
    print(f"{args.output}: {summary['written']} trial(s) written, {summary['skipped']} already there, "
          f"{summary['resampled']} unobservable draw(s) re-sampled")
    return 0
