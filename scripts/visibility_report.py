"""Partial visibility measurements (README "Partial visibility"): truncation sweep and occlusion curves.

Usage::

    # One view in three cut by the image border (sqfit.testing.truncated_trial), no OpenGL:
    python scripts/visibility_report.py truncation --cuts 0,0.1,0.2,0.3,0.4,0.5 --trials 100 \
        --chains default,1-2-3D-3A --json runs/visibility/truncation.json

    # Occlusion: IoU against each object's visible fraction from finished sqsim experiments
    # (scenes/occlusion.toml with fit.occlusion_aware true and false):
    python scripts/visibility_report.py occlusion --aware runs/occlusion --unaware runs/occlusion-unaware \
        --single runs/occlusion-single --figure docs/figures/visibility.png --truncation runs/visibility/truncation.json

``truncation`` prints, per cut fraction, chain and labels used or ignored (``FitOptions.occlusion_aware``), the
median 3D IoU over the trials; ``--stage12 drop|weight|all`` sets how stages 1 and 2 treat cut views
(``sqfit.fitting.stages.CUT_VIEWS``). ``occlusion`` takes an object's visible fraction as the mean over views
of ``visible_fraction`` in trials.jsonl (pixels seen / pixels rendered alone) and prints the median IoU
per visible-fraction bin, the unoccluded objects (every view >= 0.999) and the 80-95 % visible ones.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

BINS = [(0.0, 0.5), (0.5, 0.7), (0.7, 0.8), (0.8, 0.9), (0.9, 0.95), (0.95, 0.999), (0.999, 1.0001)]


def truncation(args):
    import sqfit
    from sqfit.fitting import stages
    from sqfit.metrics import iou_3d
    from sqfit.testing import truncated_trial

    stages.CUT_VIEWS = args.stage12
    cuts = [float(c) for c in args.cuts.split(",")]
    chains = [sqfit.DEFAULT_CHAIN if c == "default" else c for c in args.chains.split(",")]
    rows = []
    for cut in cuts:
        ious = {(c, a): [] for c in chains for a in (True, False)}
        for seed in range(args.seed, args.seed + args.trials):
            t = truncated_trial(seed, cut, args.cut_views)
            for chain in chains:
                for aware in (True, False):
                    r = sqfit.fit(t.observations, chain, options={"occlusion_aware": aware})
                    ious[chain, aware].append(iou_3d(r.superquadric, t.gt) if r.superquadric is not None else 0.0)
        for (chain, aware), values in ious.items():
            rows.append({"cut": cut, "chain": chain, "aware": aware, "median_iou": float(np.median(values)),
                         "mean_iou": float(np.mean(values)), "trials": len(values)})
            print(f"cut {cut:4.2f}  {chain:10s} {'aware  ' if aware else 'unaware'}  median IoU "
                  f"{np.median(values):.3f}  mean {np.mean(values):.3f}  (n={len(values)})", flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"stage12": args.stage12, "cut_views": args.cut_views,
                                               "rows": rows}, indent=1))


def _objects(run):
    path = Path(run) / "trials.jsonl"
    if not path.is_file():
        raise SystemExit(f"{run}: no trials.jsonl (is the experiment finished?)")
    out = []
    for line in path.read_text().splitlines():
        r = json.loads(line)
        vis = np.asarray(r["visible_fraction"], dtype=float)
        out.append((float(vis.mean()), float(vis.min()), float(r["metrics"]["iou"]), r["chain"]))
    return out


def _summary(objects, name):
    vis = np.array([o[0] for o in objects])
    low = np.array([o[1] for o in objects])
    iou = np.array([o[2] for o in objects])
    whole = low >= 0.999
    band = (vis >= 0.8) & (vis <= 0.95)
    print(f"{name}: {len(iou)} objects, median IoU {np.median(iou):.3f}; unoccluded {whole.sum()}: "
          f"{np.median(iou[whole]) if whole.any() else float('nan'):.3f}; 80-95 % visible {band.sum()}: "
          f"{np.median(iou[band]) if band.any() else float('nan'):.3f}")
    curve = []
    for lo, hi in BINS:
        sel = (vis >= lo) & (vis < hi)
        curve.append((0.5 * (lo + min(hi, 1.0)), float(np.median(iou[sel])) if sel.sum() >= 3 else np.nan,
                      int(sel.sum())))
        print(f"  visible {lo:.3f}-{min(hi, 1.0):.3f}: n={sel.sum():4d}  median IoU "
              f"{np.median(iou[sel]) if sel.any() else float('nan'):.3f}")
    return curve


def occlusion(args):
    curves = {}
    if args.single:
        _summary(_objects(args.single), "single object")
    curves["occlusion-aware"] = _summary(_objects(args.aware), "occlusion-aware")
    if args.unaware:
        curves["not aware"] = _summary(_objects(args.unaware), "not aware")
    if args.figure:
        _figure(curves, args.truncation, args.figure)


def _figure(curves, truncation_json, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 2 if truncation_json else 1
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 3.6), squeeze=False)
    ax = axes[0, 0]
    for name, curve in curves.items():
        x, y, _ = zip(*curve)
        ax.plot(x, y, "o-" if name == "occlusion-aware" else "s--", label=name)
    ax.set_xlabel("visible fraction of the object (mean over views)")
    ax.set_ylabel("median 3D IoU (default chain)")
    ax.set_title("occlusion: 4 objects, 4 views")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend()
    if truncation_json:
        data = json.loads(Path(truncation_json).read_text())
        ax = axes[0, 1]
        for chain in dict.fromkeys(r["chain"] for r in data["rows"]):
            for aware in (True, False):
                rows = [r for r in data["rows"] if r["chain"] == chain and r["aware"] == aware]
                ax.plot([r["cut"] for r in rows], [r["median_iou"] for r in rows], "o-" if aware else "s--",
                        label=f"{chain} {'aware' if aware else 'not aware'}")
        ax.set_xlabel(f"cut fraction of the object in {data['cut_views']} view(s) of 3")
        ax.set_ylabel("median 3D IoU")
        ax.set_title("truncation by the image border")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("truncation")
    t.add_argument("--cuts", default="0.3")
    t.add_argument("--cut-views", type=int, default=1)
    t.add_argument("--trials", type=int, default=100)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--chains", default="default", help="comma-separated chains; 'default' = sqfit.DEFAULT_CHAIN")
    t.add_argument("--stage12", choices=("drop", "weight", "all"), default="weight")
    t.add_argument("--json", default=None)
    o = sub.add_parser("occlusion")
    o.add_argument("--aware", required=True)
    o.add_argument("--unaware", default=None)
    o.add_argument("--single", default=None)
    o.add_argument("--figure", default=None)
    o.add_argument("--truncation", default=None, help="JSON written by the truncation command (second panel)")
    args = parser.parse_args(argv)
    truncation(args) if args.command == "truncation" else occlusion(args)


if __name__ == "__main__":
    sys.exit(main())
