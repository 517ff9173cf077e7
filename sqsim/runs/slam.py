"""``sqsim slam``: run simulated sequences through the factor graph and its baselines, and score them.

For each sequence ``index`` of a sequence scene (``sqsim.imaging.sequence.simulate_sequence(scene, seed,
index)``, the same sequence ``sqsim generate`` writes as trial ``index``), the observations are made
from the noisy instance images at the odometry poses (``sqfit.graph.observations_from_instances``;
data association comes from the instance ids) and every method of ``sqfit.graph.METHODS`` runs on
them: ``odometry``, ``fixed`` (per-object fits on the odometry poses), ``quadric`` (QuadricSLAM,
boxes), ``graph`` (batch LM) and ``graph-isam2`` (iSAM2, frame by frame).

Metrics (``evo``'s Python API, :func:`trajectory_errors`):

- ATE: RMS of the camera-centre errors against the true trajectory, **without alignment** (the
  headline figure): every method starts at the known first pose (the graph's prior on frame 0 is
  the first odometry pose, which is the true one in simulation), so the trajectories already share
  the ground truth's frame, and an alignment would hide part of the drift the methods are there to
  remove. ``ate_se3_m`` gives the same after an SE(3) Umeyama alignment, for comparison with
  papers that align;
- RPE: RMS of the frame-to-frame (delta 1 frame) translation error (m) and rotation angle (deg);
- per-object 3D IoU against the ground truth (``sqfit.metrics.iou_3d``; ``iou_3d_mesh`` for mesh
  objects); an object a method did not return (skipped, failed) scores 0 and is listed in
  ``missing``;
- wall and CPU seconds per method, and for iSAM2 the median per-frame update.

Output directory::

    slam.json                   scene, seed, methods, graph options (a re-run must match; it resumes),
                                installs (library versions: sqsim.data.provenance)
    sequences/NNNNNN/true.tum   true trajectory (TUM, sqfit.formats.tum), odometry.tum, METHOD.tum
    sequences/NNNNNN/objects.json   {"true": {id: {...}}, "methods": {METHOD: {id: [11 params]}}}
    sequences/NNNNNN/record.json    metrics, times, warnings, skipped objects (written last: marks
                                    the sequence finished; a re-run skips it)
    sequences/NNNNNN/topdown.png    top-down figure: trajectories, true and fitted objects
    summary.json, table.md      every finished sequence, rebuilt at the end of every run (summary.json
                                with slam.json's installs)

Sequences are mapped over processes or a Dask cluster as in ``sqsim experiment``
(``sqsim.runs.parallel.map_unordered``): the workers return plain data and only this process writes.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from ..data.files import atomic_write_text, check_or_write_run_config
from ..reports.slam import footprint_hull

__all__ = ["add_arguments", "run", "run_slam", "slam_sequence", "evaluate_sequence", "trajectory_errors",
           "parse_methods", "scene_graph_options", "FORMAT"]

FORMAT = "sqkit-slam"
FORMAT_VERSION = 1
#: Child of ``trial_seed(seed, index)`` seeding the observations' contour samples (0, 1, 4: sqsim.imaging.sequence).
OBSERVATION_STREAM = 5


# --------------------------------------------------------------------------- command line

def add_arguments(parser):
    parser.description = """\
Simulate sequences of a sequence scene (trajectory.kind "orbit" or "waypoints") and run each
through the factor graph (superquadrics from masks: batch LM "graph", iSAM2 "graph-isam2") and its
baselines ("odometry" alone, "fixed": per-object fits on the odometry poses, "quadric": QuadricSLAM
quadrics from boxes). Data association comes from the instance ids.

Writes, per sequence, DIR/sequences/NNNNNN/: true.tum, odometry.tum and METHOD.tum (TUM, camera ->
world), objects.json (true and fitted superquadrics), record.json (ATE/RPE with evo, no alignment:
every method starts at the known first pose; SE(3)-aligned ATE too; per-object 3D IoU; CPU and wall
times; skipped objects and warnings) and topdown.png; over all sequences DIR/summary.json and
DIR/table.md. Re-running into the same directory resumes: finished sequences are not recomputed.

example: sqsim slam scenes/sequence.toml -o /tmp/slam --sequences 5 --workers 2"""
    from ..world.scene import add_set_option

    parser.add_argument("scene", help="sequence scene TOML file, e.g. scenes/sequence.toml")
    add_set_option(parser)
    parser.add_argument("-o", "--output", required=True, help="output directory (created; resumed if it exists)")
    parser.add_argument("--sequences", type=int, default=None,
                        help="number of sequences, indices 0..N-1 (default: the scene's experiment.trials)")
    parser.add_argument("--seed", type=int, default=None, help="seed (default: the scene's experiment.seed)")
    parser.add_argument("--methods", default=None,
                        help="comma-separated subset of odometry,fixed,quadric,graph,graph-isam2 (default: all)")
    parser.add_argument("--options", default=None,
                        help="sqfit.graph.GraphOptions fields as JSON, e.g. '{\"batch_start\": \"windows\"}'; they override "
                        "what --scene-odometry-noise and --floor give")
    parser.add_argument("--scene-odometry-noise", action="store_true",
                        help="give the graph the scene's odometry noise as its odometry sigmas "
                        "(noise.odometry_translation_m and odometry_rotation_deg; default: the graph's own, 5 mm and "
                        "0.5 deg per step): better trajectories on superquadric scenes, worse maps on household "
                        "objects (docs/slam-history.md, \"Issue 23, third pass\")")
    parser.add_argument("--floor", action="store_true",
                        help="give the graph the floor the objects stand on (objects.layout = \"ground\": the plane "
                        "z = 0 of the first pose's world frame), as a robot with a level camera at a known height "
                        "knows it: it measures the map's scale, which the masks cannot")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes")
    parser.add_argument("--scheduler", default=None, help="Dask scheduler address tcp://HOST:PORT (overrides --workers)")
    parser.add_argument("--no-figures", action="store_true", help="no top-down figures")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args):
    from ..world.scene import load_scene, scene_overrides

    options = _parse_options(args.options)
    scene = load_scene(args.scene, scene_overrides(args.set))
    summary = run_slam(scene, args.output, sequences=args.sequences, seed=args.seed,
                       methods=parse_methods(args.methods), options=options, floor=args.floor,
                       scene_odometry_noise=args.scene_odometry_noise, workers=args.workers,
                       scheduler=args.scheduler, progress=not args.no_progress, figures=not args.no_figures)
    print(Path(args.output, "table.md").read_text())
    print(f"wrote {Path(args.output) / 'summary.json'}, table.md and sequences/NNNNNN/ "
          f"({len(summary['sequences'])} sequences)")
    return 0


def _parse_options(text):
    if text is None:
        return {}
    try:
        options = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--options is not valid JSON ({exc})") from None
    if not isinstance(options, dict):
        raise ValueError(f"--options must be a JSON object of GraphOptions fields, got {text!r}")
    from sqfit.graph import GraphOptions

    GraphOptions.coerce(options)  # unknown keys and bad values fail here, before any work
    return options


def scene_graph_options(scene, options=None, *, floor=False, odometry_noise=False):
    """The ``sqfit.graph.GraphOptions`` fields a sequence scene implies, overridden by ``options``.

    With ``odometry_noise`` the odometry's noise, the sensor's specification, is given to the graph:
    the scene's ``noise.odometry_translation_m`` and ``noise.odometry_rotation_deg`` (per step and
    axis) become ``odometry_sigma_m`` and ``odometry_sigma_deg`` where they are positive. The graph's
    defaults (5 mm and 0.5 deg) are five times too confident for ``scenes/sequence-eval.toml``'s
    2.5 cm, and the true sigma gives better trajectories there; but on household objects, whose
    silhouettes no superquadric follows, the looser odometry lets them pull the poses and the maps
    get worse (docs/slam-history.md, "Issue 23, third pass"), so it is not the default. With ``floor`` the plane the objects
    stand on is given too (``floor_z = 0``: ``objects.layout = "ground"`` rests every object on the
    plane z = 0 of the world frame of the first pose, which the graph holds at the first odometry
    pose, the true one): what a robot with a level camera at a known height over the floor knows.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
    options : dict, optional
        Explicit ``GraphOptions`` fields; they win over the scene's.
    floor, odometry_noise : bool

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        ``floor`` on a scene whose objects do not stand on a floor.
    """
    implied = {}
    if odometry_noise and scene.noise.odometry_translation_m > 0:
        implied["odometry_sigma_m"] = float(scene.noise.odometry_translation_m)
    if odometry_noise and scene.noise.odometry_rotation_deg > 0:
        implied["odometry_sigma_deg"] = float(scene.noise.odometry_rotation_deg)
    if floor:
        if scene.objects.layout != "ground":
            raise ValueError(f"{scene.source}: --floor needs objects.layout = \"ground\" (objects resting on the "
                             f"plane z = 0), got {scene.objects.layout!r}")
        implied["floor_z"] = 0.0
    return {**implied, **dict(options or {})}


def parse_methods(text):
    """Method list from ``--methods`` (``None``: every method of ``sqfit.graph.METHODS``)."""
    from sqfit.graph import METHODS

    if text is None:
        return list(METHODS)
    methods = list(dict.fromkeys(m.strip() for m in text.split(",") if m.strip()))
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise ValueError(f"--methods: unknown or empty {unknown or text!r}; valid: {','.join(METHODS)}")
    return methods


# --------------------------------------------------------------------------- driver

def run_slam(scene, output, *, sequences=None, seed=None, methods=None, options=None, floor=False,
             scene_odometry_noise=False, workers=1, scheduler=None, progress=True, figures=True):
    """Run (or resume) the SLAM evaluation of a sequence scene and write all outputs (module docstring).

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
        A sequence scene.
    output : str or Path
    sequences, seed : int, optional
        Overrides of the scene's ``experiment.trials`` and ``experiment.seed``.
    methods : list of str, optional
        Default: every method.
    options : dict, optional
        ``sqfit.graph.GraphOptions`` fields; they override those the scene implies
        (:func:`scene_graph_options`). ``slam.json`` records the options used.
    floor, scene_odometry_noise : bool
        Give the graph the floor the objects stand on, the scene's odometry noise
        (:func:`scene_graph_options`).
    workers : int
    scheduler : str, optional
        Dask scheduler address.
    progress, figures : bool

    Returns
    -------
    summary : dict
        The ``summary.json`` content.
    """
    from ..world.trajectory import is_sequence

    if not is_sequence(scene):
        raise ValueError(f"{scene.source}: trajectory.kind = {scene.trajectory.kind!r} is not a sequence scene; "
                         "sqsim slam needs trajectory.kind = \"orbit\" or \"waypoints\" (e.g. scenes/sequence.toml)")
    methods = parse_methods(None) if methods is None else parse_methods(",".join(methods))
    from sqfit.graph import GraphOptions

    GraphOptions.coerce(dict(options or {}))
    options = scene_graph_options(scene, options, floor=floor, odometry_noise=scene_odometry_noise)
    n = scene.experiment.trials if sequences is None else int(sequences)
    if n < 1:
        raise ValueError(f"--sequences must be >= 1, got {sequences}")
    if int(workers) < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    seed = scene.experiment.seed if seed is None else int(seed)
    scene = scene.with_overrides({"experiment.seed": seed, "experiment.trials": n})
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    installs = check_or_write_run_config(out / "slam.json", {"format": FORMAT, "version": FORMAT_VERSION,
                                                             "scene": scene.to_dict(), "methods": methods,
                                                             "options": options},
                                         scene, "slam run", "scene, seed, methods or options")
    pending = [i for i in range(n) if not (_sequence_dir(out, i) / "record.json").exists()]
    args = [(scene.to_dict(), seed, i, methods, options) for i in pending]
    _map(args, out, workers, scheduler, progress, figures)
    records = [json.loads((_sequence_dir(out, i) / "record.json").read_text()) for i in range(n)]
    from ..reports.slam import summarize, table_markdown

    summary = {**summarize(records, methods, scene.experiment.name, seed, options), "installs": installs}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))
    atomic_write_text(out / "table.md", table_markdown(summary))
    return summary


def _sequence_dir(out, index):
    return Path(out) / "sequences" / f"{int(index):06d}"


def _map(args, out, workers, scheduler, progress, figures):
    from tqdm import tqdm

    if not args:
        return
    bar = tqdm(total=len(args), desc="sequences", unit="seq", disable=not progress, dynamic_ncols=True)
    try:
        if scheduler is None and int(workers) == 1:
            results = (slam_sequence(*a) for a in args)
        else:
            from .parallel import map_unordered

            results = map_unordered(slam_sequence, args, workers=workers, scheduler=scheduler)
        for record in results:
            _write_sequence(out, record, figures)
            bar.update(1)
    except KeyboardInterrupt:
        print("\ninterrupted: finished sequences are saved; re-run the same command to resume", file=sys.stderr)
        raise
    finally:
        bar.close()


def _write_sequence(out, record, figures):
    """Write one sequence's files; ``record.json`` last (atomically), so a kill leaves it unfinished."""
    from sqfit.formats.tum import write_tum

    d = _sequence_dir(out, record["index"])
    d.mkdir(parents=True, exist_ok=True)
    t = np.asarray(record["timestamps"])
    trajectories = {"true": record["true_poses"], "odometry": record["odometry_poses"],
                    **{m: r["poses"] for m, r in record["methods"].items() if m != "odometry"}}
    for name, poses in trajectories.items():
        if poses is not None:
            write_tum(d / f"{name}.tum", t, np.asarray(poses))
    objects = {"true": record["true_objects"],
               "methods": {m: r["objects"] for m, r in record["methods"].items()}}
    atomic_write_text(d / "objects.json", json.dumps(objects, indent=1))
    if figures:
        from ..reports.slam import plot_topdown

        tmp = d / f".topdown.tmp-{os.getpid()}.png"
        plot_topdown(record, tmp)
        os.replace(tmp, d / "topdown.png")
    slim = {k: v for k, v in record.items() if k not in ("true_poses", "odometry_poses", "timestamps")}
    slim["methods"] = {m: {k: v for k, v in r.items() if k != "poses"} for m, r in record["methods"].items()}
    atomic_write_text(d / "record.json", json.dumps(slim, indent=1))


# --------------------------------------------------------------------------- one sequence (worker)

def slam_sequence(scene_dict, seed, index, methods, options):
    """Simulate sequence ``index`` of ``seed`` and evaluate every method on it (runs in a worker).

    Returns
    -------
    record : dict
        Plain data (:func:`evaluate_sequence`), plus the index, seed and simulation counts.
    """
    from ..world.scene import child_seed, parse_scene, trial_seed
    from ..imaging.sequence import simulate_sequence

    scene = parse_scene(scene_dict, source="slam.json")
    seq = simulate_sequence(scene, seed=seed, index=index)
    rng = np.random.default_rng(child_seed(trial_seed(seed, index), OBSERVATION_STREAM))
    record = evaluate_sequence(seq, methods, options, min_area_px=scene.masks.min_area_px, rng=rng)
    record.update(index=int(index), seed=int(seed), resampled=int(seq.resampled))
    return record


def evaluate_sequence(seq, methods, options=None, min_area_px=1, rng=None):
    """Run ``methods`` on a sequence with ground truth and score them.

    Parameters
    ----------
    seq : sqfit.views.sequence.Sequence
        With ``true_poses``; a ``sqsim.imaging.sequence.SimulatedSequence`` also gives mesh ground truth.
    methods : list of str
    options : dict or GraphOptions, optional
    min_area_px : int
        Instances with fewer pixels in a frame are no observation.
    rng : None, int or numpy.random.Generator
        Seeds the observations' contour samples.

    Returns
    -------
    record : dict
        ``name, frames, timestamps, true_poses, odometry_poses`` (lists), ``observations``,
        ``true_objects`` ``{id: {"kind", "params", "footprint"}}``, ``warnings`` and per method
        ``methods[m]``: ``status, message, poses, objects {id: params}, skipped, warnings, seconds,
        cpu_seconds, frame_ms_median, frame_cpu_ms_median, iterations, outline_offsets {id: px} (graph
        methods estimating them), ate_m, ate_se3_m, rpe_m, rpe_deg, iou {id: value}, iou_median,
        missing``.

    Raises
    ------
    ValueError
        No true poses, or the graph's input checks (e.g. a frame without a pose: a non-finite
        odometry pose), naming the frame.
    """
    from sqfit import graph

    if seq.true_poses is None:
        raise ValueError(f"sequence {seq.name!r} has no true poses: nothing to score the trajectories against")
    observations = graph.observations_from_instances(seq.intrinsics, _finite_or_identity(seq.odometry_poses),
                                                     seq.images, min_area_px=max(int(min_area_px), 1), rng=rng)
    results = graph.run(seq.intrinsics, seq.odometry_poses, observations, methods, options)
    truth = _true_objects(seq)
    record = {"name": seq.name, "frames": int(seq.n_frames), "timestamps": np.asarray(seq.timestamps).tolist(),
              "true_poses": np.asarray(seq.true_poses).tolist(), "odometry_poses": np.asarray(seq.odometry_poses).tolist(),
              "observations": len(observations),
              "border_views": int(sum(o.touches_border for o in observations.values())),
              "true_objects": {str(k): v for k, v in truth.items()},
              "methods": {}, "warnings": []}
    for m, res in results.items():
        record["methods"][m] = _score(m, res, seq, truth)
        record["warnings"] += [f"{m}: {w}" for w in res.warnings if not w.startswith("frame ")]
    never = [int(oid) for oid, seen in zip(seq.object_ids, seq.observed.any(axis=0)) if not seen]
    record["warnings"] += [f"object {oid}: never observed" for oid in never]
    return record


def _finite_or_identity(poses):
    """Poses for the observations' cameras (the graph uses only their pixels and checks the poses itself)."""
    poses = np.array(poses, dtype=np.float64)
    bad = ~np.isfinite(poses).all(axis=(1, 2))
    poses[bad] = np.eye(4)
    return poses


def _true_objects(seq):
    from sqfit.geometry.superquadric import to_mesh

    scene_objects = {o.id: o for o in (getattr(seq, "scene_objects", None) or [])}
    truth = {}
    for oid in (int(i) for i in seq.object_ids):
        sq = seq.objects.get(oid)
        obj = scene_objects.get(oid)
        if obj is not None:
            xy = np.asarray(obj.mesh.vertices)[:, :2]
        elif sq is not None:
            xy = np.asarray(to_mesh(sq, 12).vertices)[:, :2]
        else:
            xy = None
        truth[oid] = {"kind": seq.object_kinds.get(oid, "superquadric"),
                      "params": None if sq is None else sq.to_vector().tolist(),
                      "footprint": None if xy is None else footprint_hull(xy).tolist()}
    return truth


def _score(method, res, seq, truth):
    from sqfit.metrics import iou_3d, iou_3d_mesh

    row = {"status": res.status, "message": res.message, "poses": np.asarray(res.poses).tolist(),
           "objects": {str(k): sq.to_vector().tolist() for k, sq in res.objects.items()},
           "skipped": {str(k): v for k, v in res.skipped.items()}, "warnings": list(res.warnings),
           "seconds": float(res.seconds), "cpu_seconds": float(res.cpu_seconds), "iterations": int(res.iterations),
           "frame_ms_median": None, "frame_cpu_ms_median": None, "frame_cpu_ms_max": None,
           "outline_offsets": {str(k): float(v) for k, v in res.outline_offsets.items()},
           "odometry_chi2": None if res.odometry_chi2 is None else float(res.odometry_chi2)}
    if res.frame_seconds is not None:
        row.update(frame_ms_median=1e3 * float(np.median(res.frame_seconds)),
                   frame_cpu_ms_median=1e3 * float(np.median(res.frame_cpu_seconds)),
                   frame_cpu_ms_max=1e3 * float(np.max(res.frame_cpu_seconds)))
    row.update(trajectory_errors(seq.true_poses, res.poses, seq.timestamps))
    ious, missing = {}, []
    if method != "odometry":
        meshes = {o.id: o.mesh for o in (getattr(seq, "scene_objects", None) or [])}
        for oid, t in truth.items():
            fitted = res.objects.get(oid)
            if fitted is None:
                missing.append(oid)
                ious[str(oid)] = 0.0
            elif seq.objects.get(oid) is not None:
                ious[str(oid)] = iou_3d(fitted, seq.objects[oid])
            elif oid in meshes:
                ious[str(oid)] = iou_3d_mesh(fitted, meshes[oid])
    row.update(iou=ious, iou_median=float(np.median(list(ious.values()))) if ious else None, missing=missing)
    return row


def trajectory_errors(true_poses, poses, timestamps):
    """ATE and RPE of a trajectory against the truth, with evo.

    Parameters
    ----------
    true_poses, poses : (n, 4, 4) float
        ``T_world_camera``.
    timestamps : (n,) float

    Returns
    -------
    errors : dict
        ``ate_m`` (RMS camera-centre error, no alignment: both trajectories start at the true first
        pose), ``ate_se3_m`` (after SE(3) Umeyama alignment; None when the camera centres are
        collinear and the alignment is not unique), ``rpe_m`` and ``rpe_deg`` (RMS of the
        frame-to-frame translation error and rotation angle).
    """
    import copy

    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    t = np.asarray(timestamps, dtype=np.float64)
    ref = PoseTrajectory3D(poses_se3=list(np.asarray(true_poses)), timestamps=t)
    est = PoseTrajectory3D(poses_se3=list(np.asarray(poses)), timestamps=t)

    def stat(metric, a, b):
        metric.process_data((a, b))
        return float(metric.get_statistic(metrics.StatisticsType.rmse))

    from evo.core.geometry import GeometryException

    out = {"ate_m": stat(metrics.APE(metrics.PoseRelation.translation_part), ref, est), "ate_se3_m": None}
    aligned = copy.deepcopy(est)
    try:
        aligned.align(ref)
    except GeometryException:  # collinear or too few camera centres: no unique alignment
        pass
    else:
        out["ate_se3_m"] = stat(metrics.APE(metrics.PoseRelation.translation_part), ref, aligned)
    if len(t) > 1:
        out["rpe_m"] = stat(metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames), ref, est)
        out["rpe_deg"] = stat(metrics.RPE(metrics.PoseRelation.rotation_angle_deg, 1, metrics.Unit.frames), ref, est)
    else:
        out["rpe_m"] = out["rpe_deg"] = 0.0
    return out
