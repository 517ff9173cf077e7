"""``sqfit fit DATASET -o fits.jsonl --chain C``: fit every object of a dataset.

``sqfit fit --coco annotations.json --poses sparse/0 -o fits.jsonl`` fits a user's COCO masks
with COLMAP or JSON poses instead, or with a TUM trajectory (``--poses traj.tum --intrinsics
"fx fy cx cy width height"``, images matched by timestamp; :mod:`sqfit.views.imported`,
:mod:`sqfit.formats.trajectory`; same records). Polygon segmentations are read as outlines, not
rasterised (``--polygon-convention``, :mod:`sqfit.formats.coco_polygons`); RLE ones as masks.

The dataset is read with :mod:`sqfit.views.dataset` (written by ``sqsim generate``, or a user's own
``cameras.json`` + ``masks/view_VV.png``). Objects are the ``gt.json`` records (``"id"``) when
present, else every non-zero instance id found in the masks. One JSON line per (trial, object):
``trial``, ``object_id``, then :meth:`sqfit.FitResult.to_dict` (chain, status, final ``params``,
per-stage ``params`` / seconds / status / R-IOU-M, warnings), ``views`` (the view indices used)
and ``dropped_views`` (``{"view", "reason"}`` for each view where the object's mask is empty or
unusable, also listed in ``warnings``; warnings name views by their index in the trial). An
object that cannot be read or fitted gets a record with ``status`` ``"error"`` and the message;
the command goes on.
Samples are seeded per (trial, object) from ``--seed`` with ``numpy.random.SeedSequence``, so a
record does not depend on which other trials are in the dataset.
"""

from __future__ import annotations

import json
from pathlib import Path


from .. import constants as C


def add_arguments(parser):
    from ..formats.coco_polygons import POLYGON_READINGS
    from ..views.imported import POSE_FORMATS, TRAJECTORY_FORMATS
    from ..formats.trajectory import DEFAULT_MAX_TIME_DIFF, INTRINSICS_CONVENTIONS
    from ..views.observation import POLYGON_KINDS, SAMPLING_METHODS
    from ..fitting.pipeline import DEFAULT_CHAIN

    parser.add_argument("dataset", nargs="?",
                        help="dataset directory (DIR/trials/NNNNNN/...) or one trial directory; or use --coco")
    parser.add_argument("--coco", metavar="FILE", help="COCO instance file (RLE or polygon masks, 'track_id' per "
                        "annotation groups views into objects); needs --poses (README: 'Your own data')")
    parser.add_argument("--poses", metavar="PATH", help="camera poses of the --coco images: a COLMAP model "
                        "directory (sparse/0, binary or text), a JSON pose file, or a TUM trajectory "
                        "('t tx ty tz qx qy qz qw' per line, camera -> world; needs --intrinsics)")
    parser.add_argument("--pose-format", default="auto", choices=["auto", *POSE_FORMATS, *TRAJECTORY_FORMATS],
                        help="format of --poses (auto: a directory is COLMAP, *.json is JSON, *.tum / *.txt is TUM)")
    parser.add_argument("--polygon-convention", default=POLYGON_READINGS[0], choices=POLYGON_READINGS,
                        help="what the vertices of --coco polygon segmentations are. pixel-centres: centres of the "
                        "mask's boundary pixels (cv2.findContours + 0.5, as detectron2 writes them), half a pixel "
                        "step inside the outline: grown by it; outline: on the object's outline "
                        "(skimage.measure.find_contours at 0.5, a labelling tool's edge clicks): taken as they are; "
                        "both used as outlines, not rasterised. raster: rasterised by pycocotools and traced as a "
                        "mask (sqfit's reading before; loses about half the boundary pixels of a pixel-centre polygon). "
                        "auto (default): pixel-centres when every polygon vertex of the file has half-integer x "
                        "and y (x - 0.5 and y - 0.5 whole numbers), else outline. RLE masks are masks either way")
    tum = parser.add_argument_group(
        "TUM trajectory poses", "A TUM file has no intrinsics and no image names: give the intrinsics, and each "
        "COCO image gets the pose nearest in time (as TUM's associate.py). An image's time is its file name stem "
        "in seconds (rgb/1305031102.175304.png), or comes from --image-times. An image with no timestamp or no "
        "pose within --max-time-diff is dropped from its objects' views, with the reason in the record.")
    tum.add_argument("--intrinsics", metavar="'FX FY CX CY W H'|FILE",
                     help="pinhole camera of every image: the six numbers 'fx fy cx cy width height', or a file "
                     "holding them (text, or JSON with these keys); no distortion (undistort first)")
    tum.add_argument("--intrinsics-convention", choices=list(INTRINSICS_CONVENTIONS), default=None,
                     help="where --intrinsics' cx cy put the top-left pixel's centre: opencv (default; (0, 0) as "
                     "OpenCV, ROS CameraInfo and the TUM RGB-D parameters; 0.5 px is added) or sqfit ((0.5, 0.5) "
                     "as COLMAP and sqfit's cameras.json)")
    tum.add_argument("--image-times", metavar="FILE", help="timestamps of the images: lines 'timestamp filename' "
                     "as TUM RGB-D's rgb.txt (names matched as COCO file_name: exact, else base name)")
    tum.add_argument("--max-time-diff", type=float, default=None, metavar="SECONDS",
                     help=f"largest time between an image and its pose (default {DEFAULT_MAX_TIME_DIFF})")
    parser.add_argument("-o", "--output", required=True, help="JSON-lines file to write")
    parser.add_argument("--chain", default=DEFAULT_CHAIN,
                        help="stages joined by '-', e.g. 1-2-3D-3A; or 'default', 'whole' (one superquadric for "
                             "the whole object: the default without its two parts, faster on furniture), 'hull' (the "
                             "visual-hull baseline), 'tolerant' (whole with 3R also re-fitted from the visual hull's "
                             "fit, slower where it acts, and 3T without the part gate). The default ends with 3U: 3V "
                             "(where no superquadric grazes the outline, G2 on the mask contours, also from a fit of "
                             "the masks with thin parts opened away, each kept only where what it leaves out is a part "
                             "seen in several views, legs, stands; of the fits that match the contours alike, the one "
                             "of least volume), then where the masks show two slabs at an angle (chairs, laptops, "
                             "monitors) one of two superquadrics fitted together to them (about 1.5 s per object where "
                             "it fits the two); elsewhere 3W: where the silhouettes still do not match the masks and "
                             "the masks agree under the cameras, the fit of the highest overlap with a silhouette "
                             "pixel outside the mask weighted twice (arms, leaves, poles let go), from the fit and "
                             "from cylinder-like starts")
    parser.add_argument("--samples", type=int, default=C.DEFAULT_SAMPLES, help="samples N per observation")
    parser.add_argument("--sampling", default="uniform", choices=SAMPLING_METHODS)
    parser.add_argument("--polygon", default="hull", choices=POLYGON_KINDS,
                        help="observation polygon of the R-IOU costs")
    parser.add_argument("--no-cleanup", dest="cleanup", action="store_false",
                        help="use masks as given (default: keep each mask's largest component and fill its holes)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the mask sampling")
    from ..recording import add_arguments as add_rerun_arguments

    add_rerun_arguments(parser, "cameras, masks, ground truth, every stage of every fit "
                                "(native datasets; not with --coco)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def fit_record(record, observe, chain, options, after=None):
    """Complete one ``fits.jsonl`` record: observe the object, fit it, or say why not.

    Parameters
    ----------
    record : dict
        The record's identifying keys (``trial``, ``object_id``, ...); updated in place.
    observe : callable
        ``() -> sqfit.views.dataset.ViewObservations`` of the object.
    chain : str
    options : sqfit.fitting.pipeline.FitOptions
    after : callable, optional
        ``(record, views, result) -> None``, run after the fit (a recording, a message).

    Returns
    -------
    record : dict
        With the fit (:meth:`sqfit.views.dataset.ViewObservations.record`), or ``status`` ``"error"`` and the
        message of an OSError / ValueError / TypeError raised on the way.
    """
    from ..fitting.pipeline import fit

    try:
        views = observe()
        result = fit(views.observations, chain, options=options)
        record.update(views.record(result))
        if after is not None:
            after(record, views, result)
    except (OSError, ValueError, TypeError) as exc:
        record.update({"chain": chain, "status": "error", "message": str(exc)})
    return record


def fit_dataset(dataset, output, chain, samples=C.DEFAULT_SAMPLES, sampling="uniform", polygon="hull",
                seed=0, progress=True, cleanup=True, rerun=None, rerun_trials=None):
    """Fit every object of every trial; returns ``(records written, errors)``.

    ``rerun``: path of an ``.rrd`` file to record the trials and the stages of every fit into
    (:class:`sqfit.recording.Recorder`; needs rerun-sdk), at most ``rerun_trials`` trials.
    """
    from contextlib import nullcontext

    from tqdm import tqdm

    from ..fitting.pipeline import FitOptions, parse_chain
    from ..views.dataset import load_trial, object_rng, observe_views, trial_dirs

    parse_chain(chain)  # fail fast on a bad chain
    options = FitOptions(polygon=polygon)
    paths = trial_dirs(dataset)
    n_records = n_errors = 0
    out_path = Path(output)
    if out_path.parent and not out_path.parent.exists():
        out_path.parent.mkdir(parents=True)
    recorder = None
    if rerun is not None:
        from ..recording import Recorder

        recorder = Recorder(rerun, max_trials=rerun_trials)
    with open(out_path, "w", encoding="utf-8") as out, (recorder or nullcontext()):
        for path in tqdm(paths, desc="sqfit fit", unit="trial", disable=not progress):
            try:
                trial = load_trial(path)
                ids = trial.object_ids
            except (OSError, ValueError) as exc:
                out.write(json.dumps({"trial": path.name, "object_id": None, "status": "error",
                                      "message": str(exc)}) + "\n")
                n_records += 1
                n_errors += 1
                continue
            if recorder is not None:
                recorder.log_loaded_trial(trial)
            for oid in ids:
                def observe(oid=oid):
                    return observe_views(trial.cameras, trial.images, oid, samples, sampling,
                                            object_rng(seed, trial.name, oid), cleanup)

                def log(record, views, result, oid=oid):
                    recorder.log_fit(trial.name, oid, chain, result.stages, trial.cameras)

                record = fit_record({"trial": trial.name, "object_id": oid}, observe, chain, options,
                                    None if recorder is None else log)
                n_errors += record["status"] != "ok"
                out.write(json.dumps(record) + "\n")
                n_records += 1
    return n_records, n_errors


def _too_few_views_message(record, views, result):
    if record["status"] == "too_few_views":
        record["message"] = (f"track {record['track_id']!r} has {len(views.views)} usable view(s) "
                             f"{record['images']}; fitting needs >= {C.MIN_VIEWS}")


def fit_import(coco_path, poses_path, output, chain, samples=C.DEFAULT_SAMPLES, sampling="uniform", polygon="hull",
               seed=0, progress=True, cleanup=True, pose_format="auto", intrinsics=None, image_times=None,
               max_time_diff=None, intrinsics_convention=None, polygon_convention="auto", notify=None):
    """Fit every track of a COCO file with cameras from a pose source; write ``fits.jsonl``.

    Parameters
    ----------
    coco_path, poses_path, pose_format, intrinsics, image_times, max_time_diff, intrinsics_convention
        As :func:`sqfit.views.imported.load_import` (the four after ``pose_format`` for a TUM
        trajectory only).
    polygon_convention : {"auto", "pixel-centres", "outline", "raster"}
        How polygon segmentations are read (:func:`sqfit.views.imported.load_import`).
    notify : callable, optional
        ``str -> None``, told once how the file's polygons are read (when it has any).
    output : str or os.PathLike
        JSON-lines file (one record per track; module docstring).
    chain, samples, sampling, polygon, seed, progress, cleanup
        As ``sqfit fit`` (:func:`fit_dataset`).

    Returns
    -------
    n_records, n_not_ok : int

    Notes
    -----
    Records are those of :func:`fit_dataset` with ``trial`` null, ``object_id`` and ``track_id`` the
    track id and ``images`` the file names of the views used. Samples are seeded per track from
    ``SeedSequence([seed, crc32(str(track_id))])``, which is the native seeding when the track id is
    ``"<trial>/<object id>"`` (what ``sqsim generate`` writes), so an exported dataset fits to the
    same parameters as the native one.
    """
    from tqdm import tqdm

    from ..fitting.pipeline import FitOptions, parse_chain
    from ..views.imported import load_import, observe_track, track_rng

    parse_chain(chain)
    options = FitOptions(polygon=polygon)
    scene = load_import(coco_path, poses_path, pose_format, intrinsics, image_times, max_time_diff,
                        intrinsics_convention, polygon_convention)
    if notify is not None and scene.polygon_note:
        notify(scene.polygon_note)
    out_path = Path(output)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    n_records = n_errors = 0
    with open(out_path, "w", encoding="utf-8") as out:
        for track in tqdm(scene.track_ids, desc="sqfit fit", unit="object", disable=not progress):
            record = fit_record({"trial": None, "object_id": track, "track_id": track},
                                lambda: observe_track(scene, track, samples, sampling, track_rng(seed, track),
                                                      cleanup),
                                chain, options, _too_few_views_message)
            n_errors += record["status"] != "ok"
            out.write(json.dumps(record) + "\n")
            n_records += 1
    return n_records, n_errors


def run(args):
    if args.coco is not None or args.poses is not None:
        if args.dataset is not None or args.coco is None or args.poses is None:
            raise ValueError("give either a DATASET directory or --coco FILE with --poses PATH")
        if args.rerun is not None:
            raise ValueError("--rerun records native datasets only (sqsim generate format); "
                             "it is not available with --coco yet")
        n, errors = fit_import(args.coco, args.poses, args.output, args.chain, args.samples, args.sampling,
                               args.polygon, args.seed, progress=not args.no_progress, cleanup=args.cleanup,
                               pose_format=args.pose_format, intrinsics=args.intrinsics,
                               image_times=args.image_times, max_time_diff=args.max_time_diff,
                               intrinsics_convention=args.intrinsics_convention,
                               polygon_convention=args.polygon_convention, notify=print)
        print(_summary_line(n, errors, args.output))
        return 0
    if args.dataset is None:
        raise ValueError("give a DATASET directory, or --coco FILE with --poses PATH")
    if args.polygon_convention != "auto":
        raise ValueError("--polygon-convention reads the polygons of a --coco file; a DATASET holds masks")
    n, errors = fit_dataset(args.dataset, args.output, args.chain, args.samples, args.sampling, args.polygon,
                            args.seed, progress=not args.no_progress, cleanup=args.cleanup, rerun=args.rerun,
                            rerun_trials=args.rerun_trials)
    print(_summary_line(n, errors, args.output))
    return 0


def _summary_line(n, errors, output):
    poor = 0
    with open(output) as f:
        for line in f:
            poor += any(w.startswith("poor fit") for w in json.loads(line).get("warnings") or ())
    note = f"; {poor} flagged as poor fits (R-IOU-M < {C.POOR_FIT_R_IOU_M}: see their warnings)" if poor else ""
    return f"wrote {n} fit record(s) to {output}; {errors} not ok{note}"
