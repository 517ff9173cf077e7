"""``sqsim generate``: render a scene's trials (or sequences) into a dataset directory.

The trials are written by :mod:`sqsim.data.dataset` (sequences by :mod:`sqsim.data.sequence_dataset`),
each atomically, so a killed run resumes; this module runs them in this process, in a spawn-context
process pool or on a Dask cluster (:mod:`sqsim.runs.parallel`), then rebuilds ``annotations.json``
(COCO), optionally the COLMAP model ``sparse/0`` (``--colmap``, :mod:`sqsim.data.export`) and a
rerun recording (``--rerun``); ``--coco-polygons`` writes the COCO masks as polygons. The bytes
written do not depend on where or in which order a trial ran.
"""

from __future__ import annotations

import json
from pathlib import Path

from sqfit.views.dataset import load_trial, trial_dirs

from ..data.dataset import build_annotations, prepare_dataset, trial_name, write_trial
from ..data.files import atomic_write_text
from ..data.sequence_dataset import finish_sequence_dataset, write_sequence_trial
from ..world.scene import add_set_option, load_scene, parse_scene, scene_overrides
from ..world.trajectory import is_sequence

__all__ = ["generate", "add_arguments", "run"]


def _write(scene, index, root):
    """Write trial ``index``: a sequence for a sequence scene, else a multi-view trial."""
    if is_sequence(scene):
        return write_sequence_trial(scene, index, root)
    return write_trial(scene, index, root)


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
    return index, _write(scene, index, root)


def generate(scene, output, trials=None, seed=None, workers=1, progress=True, scheduler=None, rerun=None,
             rerun_trials=None, colmap=False, coco_polygons=None):
    """Write (or complete) a dataset.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
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
        Also write the cameras as a COLMAP text model ``DIR/sparse/0`` (:mod:`sqsim.data.export`).
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
    prepare_dataset(root, scene)
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
        from ..data.export import write_colmap_model

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
                results.append(_write(scene, i, root))
                bar.update()
            return results
        from .parallel import map_unordered

        # Bounded submissions (sqsim.runs.parallel): on Ctrl-C or an error the queued trials are
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


# --- command line -----------------------------------------------------------------------------------

def add_arguments(parser):
    parser.add_argument("scene", help="scene TOML file (keys: README, \"Scene files\"; example: scenes/paper.toml)")
    parser.add_argument("-o", "--output", required=True, help="dataset directory (created; re-running resumes)")
    add_set_option(parser)
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
    scene = load_scene(args.scene, scene_overrides(args.set))
    summary = generate(scene, args.output, trials=args.trials, seed=args.seed, workers=args.workers,
                       progress=not args.no_progress, scheduler=args.scheduler, rerun=args.rerun,
                       rerun_trials=args.rerun_trials, colmap=args.colmap, coco_polygons=args.coco_polygons)
    print(f"{args.output}: {summary['written']} trial(s) written, {summary['skipped']} already there, "
          f"{summary['resampled']} unobservable draw(s) re-sampled")
    return 0
