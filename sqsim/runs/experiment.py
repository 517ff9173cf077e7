"""``sqsim experiment``: the paper's permutation experiment — simulate, fit every chain, evaluate.

Each trial is independent and seeded by ``trial_seed(seed, index)``, so its records do not depend
on the number of workers or the order trials finish in. Trials are mapped over a
``concurrent.futures`` executor: in-process for one worker, a spawn-context process pool for
several, or a Dask distributed cluster (``--scheduler tcp://HOST:PORT``).

Output directory:

- ``experiment.json``: the scene (with command-line overrides applied), seed and chains. A re-run
  into the same directory must use the same scene and seed; it then fits only the
  (trial, chain) pairs missing from ``trials.jsonl`` (resume after Ctrl-C or a kill).
- ``trials.jsonl``: one record per (trial, object, chain): ground truth, fitted parameters and
  metrics after every stage, seconds, status, the estimated outline offset
  (``outline_offset_px``, :attr:`sqfit.FitResult.outline_offset_px`), and per view the object's ``visible_fraction``
  (pixels seen / pixels rendered alone), ``cut_fraction`` (projected area outside the image) and
  ``border_cut`` (its mask touches the border; :mod:`sqsim.imaging.trial`). A line cut short by a kill is
  dropped on resume.
- ``summary.json``, ``table.md``, ``table.tex``, ``comparison.md`` (medians beside the paper's
  Table II), ``violin.png``, ``example.png``: rebuilt from
  all records at the end of every run. ``summary.json`` is the stable interface::

    {"scene": "paper", "trials": 100, "resampled": 7, "seed": 0,
     "chains": {"1-2-3D-3A": {"iou": {"median": .., "mean": .., "std": ..}, "r_iou": {..},
                              "r_iou_m": {..}, "r_iou_m_contour": {..}, "time_s": {..},
                              "success_rate": 1.0, "errors": 0, "fits": 100}},
     "installs": [{"python": "3.11.7", "sqkit": "0.1.0", "numpy": "2.4.6", "scipy": "1.17.1", ..}]}

  ``installs``: the library versions of each install that ran the run, as in ``experiment.json``
  (:mod:`sqsim.data.provenance`; more than one where a run was resumed under other versions).

Metrics (``sqfit.metrics``): IOU = 3D IoU with the ground truth; R-IOU = mean 2D IoU of the
fitted and true silhouettes in the true cameras; R-IOU-M = mean 2D IoU of the fitted silhouette
and the observation's hull of samples (paper), ``r_iou_m_contour`` the same against the full mask
contour. A fit that produced no superquadric scores 0 everywhere and counts as an error.
Intermediate stages are scored with a coarser 3D IoU grid (``STAGE_IOU_CELLS``, < 2 % error).

Representation limit (``experiment.limit = true``, the default): each object whose ground truth is
not a superquadric is searched once per trial for its best superquadric
(:func:`sqsim.world.limit.object_limit`; cached per mesh and pose in memory and in ``DIR/limits/``),
and every record of the object carries ``metrics.iou_limit`` (its 3D IoU with the mesh),
``metrics.r_iou_m_contour_limit`` (the limit's silhouettes against the mask contours, as
``r_iou_m_contour``: where it is below a chain's, the masks favour that chain's fit over the limit) and
``limit`` (``iou``, ``params``, ``seconds``, ``cached``). A superquadric ground truth has the
limit 1 by definition: nothing is searched or written (its records are unchanged). ``summary.json``
then adds ``iou_limit``, ``iou_over_limit`` (per-record IoU / limit) and ``r_iou_m_contour_limit`` to
each chain and, when the ground truths are household objects, the same per ``gt.item`` under
``by_item`` (:func:`sqsim.reports.experiment.summarize`).
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np

from ..data.files import atomic_figure, atomic_write_text, check_or_write_run_config, read_records

FORMAT = "sqkit-experiment"
FORMAT_VERSION = 1
STAGE_IOU_CELLS = 2**16


# --------------------------------------------------------------------------- command line

def add_arguments(parser):
    from ..world.scene import add_set_option

    parser.add_argument("scene", help="scene / experiment TOML file (see scenes/paper.toml)")
    add_set_option(parser)
    parser.add_argument("-o", "--output", required=True, help="output directory (created; resumed if it exists)")
    parser.add_argument("--trials", type=int, default=None, help="number of trials (default: the scene's)")
    parser.add_argument("--chains", default=None,
                        help="comma-separated chains, e.g. 1-2-3D-3A,1-2-3D; 'default' = sqfit.DEFAULT_CHAIN, "
                             "'whole' = one superquadric for the whole object (the default with 3V-3W for 3U, "
                             "the default until 2026-12-02), 'hull' = the visual-hull baseline (HULL), "
                             "'tolerant' = whole with 3RH for 3R (3R's re-fit also from the visual hull's fit) and "
                             "3T for 3V-3W (no part gate, no least-volume choice), "
                             "'paper' = all 13 chains of the paper's Table II (default: the scene's)")
    parser.add_argument("--seed", type=int, default=None, help="experiment seed (default: the scene's)")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes")
    parser.add_argument("--scheduler", default=None, help="Dask scheduler address tcp://HOST:PORT (overrides --workers)")
    from sqfit.recording import add_arguments as add_rerun_arguments

    add_rerun_arguments(parser, "cameras, masks, ground truth and every stage of every fit (re-running into a "
                                "finished output directory only records)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args):
    from ..world.scene import load_scene, scene_overrides

    scene = load_scene(args.scene, scene_overrides(args.set))
    summary = run_experiment(scene, args.output, trials=args.trials, chains=parse_chains(args.chains),
                             seed=args.seed, workers=args.workers, scheduler=args.scheduler,
                             progress=not args.no_progress, rerun=args.rerun,
                             rerun_trials=args.rerun_trials)
    from ..reports.experiment import screen_summary

    print(screen_summary(summary))
    print(f"wrote {Path(args.output) / 'summary.json'}, table.md, table.tex, violin.png, example.png")
    return 0


def check_chain(chain):
    """Raise ``ValueError`` unless every stage of ``chain`` (e.g. ``1-2-3D-3A``) is registered."""
    import sqfit

    unknown = [s for s in str(chain).split("-") if s not in sqfit.STAGES]
    if unknown or not chain:
        raise ValueError(f"chain {chain!r} has unknown stage(s) {unknown}; stages are {sorted(sqfit.STAGES)}")
    return chain


def parse_chains(text):
    """Chain list from ``--chains``: ``None`` keeps the scene's; ``paper`` and the names of
    ``sqfit.fitting.CHAIN_ALIASES`` (``default``, ``hull``) expand."""
    if text is None:
        return None
    import sqfit

    chains = []
    for item in (c.strip() for c in text.split(",")):
        if not item:
            continue
        if item in sqfit.fitting.CHAIN_ALIASES:
            chains.append(sqfit.fitting.CHAIN_ALIASES[item])
        elif item == "paper":
            chains.extend(sqfit.PAPER_CHAINS)
        else:
            chains.append(item)
    if not chains:
        raise ValueError("--chains is empty")
    return list(dict.fromkeys(chains))


# --------------------------------------------------------------------------- driver

def run_experiment(scene, output, *, trials=None, chains=None, seed=None, workers=1, scheduler=None,
                   progress=True, figures=True, rerun=None, rerun_trials=None):
    """Run (or resume) an experiment and write all outputs.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene
    output : str or Path
        Output directory.
    trials, chains, seed : optional overrides of the scene's ``[experiment]`` values.
    workers : int
        Local processes (1 = in this process).
    scheduler : str, optional
        Dask scheduler address; trials run on that cluster.
    progress : bool
        Show a progress bar with an ETA.
    figures : bool
        Also draw ``violin.png`` and ``example.png``.
    rerun : str or Path, optional
        Also write a rerun recording (``.rrd``) of all trials: the masks are simulated again
        (deterministic), the fits come from the records (:func:`record_rerun`); at most
        ``rerun_trials`` trials (default: all).

    Returns
    -------
    summary : dict
        The ``summary.json`` content.
    """
    import sqfit

    overrides = {}
    if trials is not None:
        overrides["experiment.trials"] = int(trials)
    if seed is not None:
        overrides["experiment.seed"] = int(seed)
    if chains is not None:
        overrides["experiment.chains"] = list(chains)
    if overrides:
        scene = scene.with_overrides(overrides)
    chains = list(dict.fromkeys(sqfit.fitting.CHAIN_ALIASES.get(c, c) for c in scene.experiment.chains))
    for chain in chains:
        check_chain(chain)
    if int(workers) < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if rerun is not None:
        from sqfit.recording import check_recording_path

        check_recording_path(rerun, rerun_trials)
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    installs = check_or_write_run_config(out / "experiment.json", {"format": FORMAT, "version": FORMAT_VERSION,
                                                                   "scene": scene.to_dict()},
                                         scene, "experiment", "scene or seed")

    jsonl = out / "trials.jsonl"
    records = read_records(jsonl)
    done = {(r["trial"], r["chain"]) for r in records}
    pending = {i: [c for c in chains if (i, c) not in done] for i in range(scene.experiment.trials)}
    pending = {i: c for i, c in pending.items() if c}
    scene_dict = scene.to_dict()

    limits = str(out / "limits") if scene.experiment.limit else None
    new = _map_trials(scene_dict, pending, jsonl, workers, scheduler, progress, limits)
    records += new
    summary = write_reports(out, scene, chains, records, figures, installs)
    if rerun is not None:
        kept = [r for r in records if r["trial"] < scene.experiment.trials and r["chain"] in chains]
        record_rerun(rerun, scene, kept, rerun_trials)
    return summary


def record_rerun(path, scene, records, max_trials=None):
    """Write a rerun recording of an experiment's trials (``sqfit.recording`` layout).

    Each trial is simulated again from the scene (its masks and noisy cameras are deterministic);
    ground truth and the per-stage estimates come from ``records`` (``trials.jsonl``).
    """
    from sqfit.recording import Recorder

    from ..imaging.render import get_renderer
    from ..imaging.trial import simulate_trial

    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    by_trial = {}
    for r in records:
        by_trial.setdefault(r["trial"], []).append(r)
    with Recorder(path, max_trials=max_trials) as recorder:
        for index in sorted(by_trial):
            name = f"{index:06d}"
            if not recorder.admits(name):
                recorder.skipped.add(name)
                continue
            sim = simulate_trial(scene, index, renderer)
            recorder.log_trial(name, sim.cameras, sim.images, sim.true_cameras, [o.to_dict() for o in sim.objects])
            for r in sorted(by_trial[index], key=lambda r: (r["object"], r["chain"])):
                recorder.log_fit(name, r["object"], r["chain"], r["stages"], sim.cameras)



def _map_trials(scene_dict, pending, jsonl, workers, scheduler, progress, limits=None):
    from tqdm import tqdm

    if not pending:
        return []
    new = []
    bar = tqdm(total=len(pending), desc="trials", unit="trial", disable=not progress, dynamic_ncols=True)
    with open(jsonl, "a") as fh:
        def write(records):
            fh.write("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
            fh.flush()
            os.fsync(fh.fileno())
            new.extend(records)
            bar.update(1)

        try:
            if scheduler is None and int(workers) == 1:
                for index, chains in pending.items():
                    write(fit_trial(scene_dict, index, chains, limits))
            else:
                _run_parallel(scene_dict, pending, workers, scheduler, write, limits)
        except KeyboardInterrupt:
            bar.close()
            print(f"\ninterrupted: {len(new)} records saved; re-run the same command to resume", file=sys.stderr)
            raise
        finally:
            bar.close()
    return new


def _run_parallel(scene_dict, pending, workers, scheduler, write, limits=None):
    from .parallel import map_unordered

    args = ((scene_dict, i, c, limits) for i, c in pending.items())
    for records in map_unordered(fit_trial, args, workers=workers, scheduler=scheduler):
        write(records)


# --------------------------------------------------------------------------- one trial (worker)

def chain_seed(seed_sequence, chain):
    """A per-chain generator seed, independent of the chain list and its order."""
    key = int.from_bytes(hashlib.sha256(chain.encode()).digest()[:4], "little")
    return np.random.SeedSequence(seed_sequence.entropy, spawn_key=tuple(seed_sequence.spawn_key) + (key,))


def fit_trial(scene_dict, index, chains, limits=None):
    """Simulate trial ``index``, fit each chain to each object, and score every stage.

    Runs in a worker; takes and returns plain data only. With ``experiment.limit``, each object's
    representation limit is found once (before its chains) and cached in ``limits`` (a
    directory; default: this process's memory).

    Returns
    -------
    records : list of dict
        One per (object, chain), as written to ``trials.jsonl``.
    """
    import sqfit
    from sqfit.metrics import IOU_GRID_CELLS, iou_3d, iou_3d_mesh, r_iou

    from ..imaging.render import get_renderer
    from ..world.scene import parse_scene, trial_seed
    from ..imaging.trial import observations, simulate_trial

    scene = parse_scene(scene_dict, source="<experiment>")
    sim = simulate_trial(scene, index, get_renderer(scene.masks.renderer, scene.intrinsics))
    seed = trial_seed(scene.experiment.seed, index)
    options = {"polygon": scene.fit.polygon, "penalty_riou": scene.fit.penalty_riou,
               "penalty_analytic": scene.fit.penalty_analytic, "pose_sigma_deg": scene.fit.pose_sigma_deg,
               "occlusion_aware": scene.fit.occlusion_aware,
               "outline_offset_sigma_px": scene.fit.outline_offset_sigma_px, "outline_offset": scene.fit.outline_offset,
               "outline_offset_view_sigma_px": scene.fit.outline_offset_view_sigma_px,
               "size_min_m": scene.fit.size_min_m, "n_contour": scene.fit.n_contour}
    limit_cache = None
    if scene.experiment.limit:
        from ..world.limit import LimitCache, object_limit

        limit_cache = LimitCache(limits) if limits is not None else None
    records = []
    for oi, obj in enumerate(sim.objects):
        limit = object_limit(obj, limit_cache) if scene.experiment.limit and obj.superquadric is None else None
        gt_polygons = _ground_truth_polygons(obj, sim)
        try:
            obs = observations(sim, obj.id, scene)
            obs_error = None
        except ValueError as exc:
            obs, obs_error = [], str(exc)

        cams, contours = [o.camera for o in obs], [o.contour for o in obs]

        def score(sq, cells):
            if sq is None:
                return {"iou": 0.0, "r_iou": 0.0, "r_iou_m": 0.0, "r_iou_m_contour": 0.0}
            iou = iou_3d(sq, obj.superquadric, cells) if obj.superquadric is not None else iou_3d_mesh(sq, obj.mesh)
            return {
                "iou": iou,
                "r_iou": r_iou(sq, sim.true_cameras, gt_polygons) if gt_polygons else 0.0,
                "r_iou_m": r_iou(sq, cams, [o.hull for o in obs]) if obs else 0.0,
                "r_iou_m_contour": r_iou(sq, cams, contours) if obs else 0.0,
            }

        limit_metrics = {}  # the same for every chain of the object
        if limit is not None:
            limit_metrics = {"iou_limit": limit.iou}
            if obs:  # how well the limit's silhouettes match the masks: do the masks favour it?
                limit_metrics["r_iou_m_contour_limit"] = r_iou(limit.superquadric, cams, contours)
        for chain in chains:
            base = {"trial": index, "object": obj.id, "chain": chain, "gt": obj.to_dict(),
                    "resampled": sim.resampled, "cameras": [c.pose.tolist() for c in sim.true_cameras],
                    "views_used": len(obs),
                    "visible_fraction": sim.visible_fraction[oi].round(4).tolist(),
                    "cut_fraction": sim.cut_fraction[oi].round(4).tolist(),
                    "border_cut": sim.border_cut[oi].tolist()}
            if limit is not None:
                base["limit"] = limit.to_dict()
            if obs_error is not None:
                records.append({**base, "status": "bad_observation", "message": obs_error, "warnings": [],
                                "params": None, "stages": [], "time_s": 0.0,
                                "metrics": {**score(None, IOU_GRID_CELLS), **limit_metrics, "time_s": 0.0,
                                            "success": False}})
                continue
            result = sqfit.fit(obs, chain, rng=np.random.default_rng(chain_seed(seed, chain)), options=options)
            stages = []
            for k, st in enumerate(result.stages):
                final = k == len(result.stages) - 1
                metrics = score(st.superquadric, IOU_GRID_CELLS if final else STAGE_IOU_CELLS)
                stages.append({"name": st.name, "status": st.status, "seconds": st.seconds,
                               "params": None if st.superquadric is None else st.superquadric.to_vector().tolist(),
                               **metrics})
            final_metrics = score(result.superquadric, IOU_GRID_CELLS)
            records.append({**base, "status": result.status, "message": result.message,
                            "warnings": list(result.warnings),
                            "params": None if result.superquadric is None else result.superquadric.to_vector().tolist(),
                            "stages": stages, "time_s": result.seconds,
                            "outline_offset_px": result.outline_offset_px,
                            "metrics": {**final_metrics, **limit_metrics, "time_s": result.seconds,
                                        "success": bool(final_metrics["iou"] > 0)}})
    return records


def _ground_truth_polygons(obj, sim):
    """True silhouettes in the true cameras: analytic for superquadrics, the clean mask otherwise."""
    from sqfit.metrics import METRIC_SILHOUETTE_DIRECTIONS
    from sqfit.views.observation import outer_contour
    from sqfit.geometry.silhouette import silhouette

    if obj.superquadric is not None:
        return [silhouette(obj.superquadric, cam, METRIC_SILHOUETTE_DIRECTIONS) for cam in sim.true_cameras]
    polygons = []
    for image in sim.clean_images:
        mask = image == obj.id
        if not mask.any():
            return []
        polygons.append(outer_contour(mask))
    return polygons


# --------------------------------------------------------------------------- outputs

def write_reports(out, scene, chains, records, figures=True, installs=None):
    """Write summary.json, table.md, table.tex, violin.png and example.png from all records; ``installs``
    (the run's, :func:`sqsim.data.files.check_or_write_run_config`) goes into summary.json as it is."""
    from ..reports import experiment as report

    trials = scene.experiment.trials
    records = sorted((r for r in records if r["trial"] < trials and r["chain"] in chains),
                     key=lambda r: (r["trial"], r["object"], chains.index(r["chain"])))
    resampled = sum({r["trial"]: r["resampled"] for r in records}.values())
    summary = report.summarize(records, chains, scene.experiment.name, scene.experiment.seed, trials, resampled)
    if installs is not None:
        summary["installs"] = installs
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))
    atomic_write_text(out / "table.md", report.table_markdown(summary))
    atomic_write_text(out / "table.tex", report.table_latex(summary))
    atomic_write_text(out / "comparison.md", report.paper_comparison(summary))
    best = report.best_chain(summary) if records else None
    if best is not None and figures:
        atomic_figure(report.violin_figure, out / "violin.png", records, best)
        example = _typical_record(records, best)
        if example is not None:
            from sqfit import Camera

            cams = [Camera(scene.intrinsics, np.asarray(T)) for T in example["cameras"]]
            atomic_figure(report.example_figure, out / "example.png", example, cams)
    return summary


def _typical_record(records, chain):
    """The record of ``chain`` whose IOU is closest to the chain's median (superquadric GT only)."""
    rows = [r for r in records if r["chain"] == chain and r["gt"].get("kind") == "superquadric" and r["stages"]]
    if not rows:
        return None
    median = np.median([r["metrics"]["iou"] for r in rows])
    return min(rows, key=lambda r: abs(r["metrics"]["iou"] - median))


