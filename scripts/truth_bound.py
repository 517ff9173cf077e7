"""What the search of each chain leaves on the table: chains against 3G started at the ground truth.

Usage::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/truth_bound.py scenes/paper.toml --trials 100 \
        --chains default,1-2-3G,1-2-3G-3S,1-2-3D-3A [--seed 0] [--json OUT.json]

For each trial of the scene (rendered and corrupted exactly as ``sqsim experiment`` does, one
object) it fits every chain and ``sqfit.fit(obs, "3G", initial=truth)``, the "given the truth"
bound: what the default's last stage reaches when the search is perfect. ``truth`` is the ground
truth superquadric; for ``box`` and ``cylinder`` objects the superquadric closest to them in 3G's
shape bounds (``e = (e_min, e_min)`` and ``(e_min, 1)``, ``e_min =
sqfit.constants.SILHOUETTE_SHAPE_BOUNDS[0]``); other kinds have no bound. 3D IoU as
``sqsim experiment`` (grid IoU for superquadrics, mesh IoU otherwise).

A trial is *lost* by a chain when its IoU is more than :data:`LOST_MARGIN` below the bound. A lost
trial is a *search failure* when the 3G misfit (RMS grazing residual, 64 outline rays per view,
given cameras: :func:`sqfit.fitting.restarts.misfit`) at the truth-started answer is below
:data:`COST_RATIO` times the misfit at the chain's answer -- the cost itself tells them apart, so
a better search would have found it -- and *ambiguous* otherwise (the views cannot tell them
apart, or the chain's answer even fits them better). Prints a Markdown table; times are CPU
seconds per fit (``time.process_time``), single process.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.metrics import IOU_GRID_CELLS, iou_3d, iou_3d_mesh  # noqa: E402
from sqfit.fitting.restarts import misfit  # noqa: E402
from sqfit.views.rays import contour_rays  # noqa: E402

#: IoU margin below the truth-started bound from which a trial counts as lost.
LOST_MARGIN = 0.05
#: A lost trial is a search failure when the truth-started misfit is below this times the chain's.
COST_RATIO = 0.8
#: Outline rays per view of the misfit (as stage 3G).
N_RAYS = 64


def truth_superquadric(obj):
    """The ground truth as a superquadric (None for kinds without a close one)."""
    if obj.superquadric is not None:
        return obj.superquadric
    e_min = sqfit.constants.SILHOUETTE_SHAPE_BOUNDS[0]
    shapes = {"box": (e_min, e_min), "cylinder": (e_min, 1.0)}
    if obj.kind not in shapes:
        return None
    return sqfit.Superquadric(obj.size, shapes[obj.kind], obj.position, obj.rotation)


def main(argv=None):
    from sqsim.imaging.render import get_renderer
    from sqsim.world.scene import load_scene
    from sqsim.imaging.trial import observations, simulate_trial

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--trials", type=int, default=None, help="default: the scene's experiment.trials")
    parser.add_argument("--seed", type=int, default=None, help="default: the scene's experiment.seed")
    parser.add_argument("--chains", default="default,1-2-3G,1-2-3G-3S,1-2-3D-3A")
    parser.add_argument("--json", metavar="PATH", help="write per-trial figures here")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="a sqfit.FitOptions field for every fit (truth-started too), e.g. "
                             "outline_offset_sigma_px=0; repeatable")
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    if args.seed is not None:
        scene = replace(scene, experiment=replace(scene.experiment, seed=args.seed))
    trials = args.trials or scene.experiment.trials
    chains = [sqfit.DEFAULT_CHAIN if c == "default" else c for c in args.chains.split(",")]
    options = {"polygon": scene.fit.polygon, "penalty_riou": scene.fit.penalty_riou,
               "penalty_analytic": scene.fit.penalty_analytic, "pose_sigma_deg": scene.fit.pose_sigma_deg,
               "occlusion_aware": scene.fit.occlusion_aware,
               "outline_offset_sigma_px": scene.fit.outline_offset_sigma_px, "outline_offset": scene.fit.outline_offset,
               "outline_offset_view_sigma_px": scene.fit.outline_offset_view_sigma_px}
    options.update(_parse_option(o) for o in args.option)
    sqfit.FitOptions.coerce(options)  # an unknown key or a bad value fails here, before any fit
    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    rows = {c: [] for c in chains + ["truth"]}
    for i in range(trials):
        sim = simulate_trial(scene, i, renderer)
        obj = sim.objects[0]
        obs = observations(sim, obj.id, scene)
        rays = contour_rays(obs, N_RAYS)
        truth = truth_superquadric(obj)

        def score(sq):
            if sq is None:
                return 0.0
            return iou_3d(sq, obj.superquadric, IOU_GRID_CELLS) if obj.superquadric is not None else iou_3d_mesh(sq, obj.mesh)

        for chain in chains + (["truth"] if truth is not None else []):
            c0 = time.process_time()
            if chain == "truth":
                result = sqfit.fit(obs, "3G", initial=truth, options=options)
            else:
                result = sqfit.fit(obs, chain, options=options)
            seconds = time.process_time() - c0
            sq = result.superquadric
            with np.errstate(all="ignore"):
                fit_misfit = misfit(sq.to_vector(), rays, scene.fit.penalty_analytic) if sq is not None else np.inf
            rows[chain].append({"iou": score(sq), "misfit": fit_misfit, "seconds": seconds})
    print(f"# {args.scene}: {trials} trials, seed {scene.experiment.seed}, CPU seconds per fit, single process; "
          f"lost = IoU more than {LOST_MARGIN} below 3G-from-truth; search failure = truth-started misfit "
          f"< {COST_RATIO} x the chain's")
    bound = rows["truth"]
    header = "| chain | IoU median | IoU 10th pct | mean | success | CPU s median |"
    if bound:
        header += " 3G from truth: IoU median (10th pct) | lost | search failures | ambiguous |"
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for chain in chains:
        iou = np.array([r["iou"] for r in rows[chain]])
        s = np.array([r["seconds"] for r in rows[chain]])
        line = (f"| {chain} | {np.median(iou):.3f} | {np.percentile(iou, 10):.3f} | {iou.mean():.3f} | "
                f"{np.mean(iou > 0):.0%} | {np.median(s):.4f} |")
        if bound:
            b_iou = np.array([r["iou"] for r in bound])
            b_mis = np.array([r["misfit"] for r in bound])
            mis = np.array([r["misfit"] for r in rows[chain]])
            lost = iou < b_iou - LOST_MARGIN
            search = lost & (b_mis < COST_RATIO * mis)
            line += (f" {np.median(b_iou):.3f} ({np.percentile(b_iou, 10):.3f}) | {lost.sum()} | {search.sum()} | "
                     f"{(lost & ~search).sum()} |")
        print(line, flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"scene": args.scene, "seed": scene.experiment.seed, "trials": rows}, f)


def _parse_option(text):
    """``"KEY=VALUE"`` -> ``(KEY, VALUE)``, the value as a number where it reads as one."""
    key, sep, value = text.partition("=")
    if not sep:
        raise SystemExit(f"--option must be KEY=VALUE, got {text!r}")
    for kind in (int, float):
        try:
            return key.strip(), kind(value)
        except ValueError:
            pass
    return key.strip(), value.strip()


if __name__ == "__main__":
    main()
