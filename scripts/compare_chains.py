"""Two chains on the same observations of a dataset: accuracy, time, and which objects changed.

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/compare_chains.py DATASET [--chains default,tolerant] [--seed 0]

``DATASET`` is a directory written by ``sqsim generate``. Every object is observed once (samples
drawn as ``sqfit fit DATASET --seed S`` draws them) and fitted with both chains. For superquadric
ground truths it prints per chain the median, 10th percentile and mean 3D IoU against the truth and
the median CPU time, then every object whose IoU moved by more than 0.01; for other ground truths
(meshes, household objects: score those with ``sqsim experiment``) the objects whose fits differ.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.geometry.superquadric import Superquadric  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402
from sqfit.views.dataset import iter_trials, object_rng, observations  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--chains", default="default,tolerant", help="two chains, comma-separated")
    parser.add_argument("--seed", type=int, default=0, help="sampling seed (as sqfit fit --seed)")
    args = parser.parse_args(argv)
    chains = args.chains.split(",")
    if len(chains) != 2:
        parser.error("--chains needs exactly two chains")
    iou, seconds, changed = {c: [] for c in chains}, {c: [] for c in chains}, []
    for trial in iter_trials(args.dataset):
        for oid in trial.object_ids:
            obs = observations(trial, oid, rng=object_rng(args.seed, trial.name, oid))
            truth = next((o for o in trial.objects if int(o["id"]) == oid), {})
            gt = (Superquadric(truth["size"], truth["shape"], truth["position"], truth["rotation"])
                  if "shape" in truth else None)
            fits = []
            for chain in chains:
                t0 = time.process_time()
                result = sqfit.fit(obs, chain)
                seconds[chain].append(time.process_time() - t0)
                fits.append(result)
                if gt is not None:
                    iou[chain].append(iou_3d(result.superquadric, gt) if result.superquadric else 0.0)
            a, b = (f.superquadric.to_vector() if f.superquadric else None for f in fits)
            if gt is not None and abs(iou[chains[1]][-1] - iou[chains[0]][-1]) > 0.01:
                changed.append(f"{trial.name}/{oid}: IoU {iou[chains[0]][-1]:.3f} -> {iou[chains[1]][-1]:.3f}; "
                               f"{fits[1].stages[-1].message[:90]}")
            elif gt is None and (a is None or b is None or not np.array_equal(a, b)):
                changed.append(f"{trial.name}/{oid} ({truth.get('item', truth.get('kind', '?'))}): fits differ; "
                               f"{fits[1].stages[-1].message[:90]}")
    print(f"# {args.dataset}, {len(seconds[chains[0]])} objects, sampling seed {args.seed}")
    print("| chain | median IoU | 10th percentile | mean IoU | median CPU ms |")
    print("|---|---|---|---|---|")
    for chain in chains:
        v = np.array(iou[chain]) if iou[chain] else np.full(1, np.nan)
        print(f"| {chain} | {np.median(v):.3f} | {np.quantile(v, 0.1):.3f} | {v.mean():.3f} | "
              f"{1000 * np.median(seconds[chain]):.1f} |")
    print(f"\n{len(changed)} objects changed" + (":" if changed else ""))
    for line in changed:
        print("  " + line)


if __name__ == "__main__":
    main()
