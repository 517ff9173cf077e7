"""Stage 3S against plain 3G: accuracy and time for several gate settings, single process.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_multistart.py [--trials 100] [--triggers 0.01,0.04]

Trials are ``sqfit.testing.paper_trial`` (as ``bench_fit.py``). For every trial, ``1-2-3G`` and
``1-2-3G-3S`` at each ``sqfit.fitting.restarts.TRIGGER_MISFIT`` are timed alternately, best of
``--repeat``, so load changes on a shared machine hit all of them alike (``bench_fit.py`` times
one chain after the other). Prints per setting: fits that triggered, 3D IoU median / mean, counts
below 0.7 and 0.5, median and mean seconds, and the median time relative to ``1-2-3G``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.fitting import restarts  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402
from sqfit.testing import paper_trial  # noqa: E402

BASE, MULTI = "1-2-3G", "1-2-3G-3S"


def _time(trial, chain, trigger):
    if trigger is not None:
        restarts.TRIGGER_MISFIT = trigger
    t0 = time.perf_counter()
    result = sqfit.fit(trial.observations, chain)
    return time.perf_counter() - t0, result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="first trial seed")
    parser.add_argument("--triggers", default="0.01,0.02,0.03,0.04", help="TRIGGER_MISFIT values")
    parser.add_argument("--repeat", type=int, default=2, help="fits per trial and setting; the fastest is kept")
    parser.add_argument("--json", metavar="PATH", help="write per-trial figures here")
    args = parser.parse_args(argv)
    default = restarts.TRIGGER_MISFIT
    settings = [(BASE, None)] + [(MULTI, float(t)) for t in args.triggers.split(",")]
    trials = [paper_trial(args.seed + i) for i in range(args.trials)]
    sqfit.fit(trials[0].observations, MULTI)  # warm-up: imports and caches
    seconds = np.full((len(trials), len(settings)), np.inf)
    iou = np.zeros_like(seconds)
    triggered = np.zeros_like(seconds, dtype=bool)
    try:
        for i, trial in enumerate(trials):
            for rep in range(args.repeat):
                for k, (chain, trigger) in enumerate(settings):
                    s, result = _time(trial, chain, trigger)
                    seconds[i, k] = min(seconds[i, k], s)
                    if rep == 0:
                        iou[i, k] = iou_3d(result.superquadric, trial.gt) if result.superquadric else 0.0
                        # The gate's message is "3S: misfit m <= TRIGGER_MISFIT: kept".
                        triggered[i, k] = chain == MULTI and "<=" not in result.stages[-1].message
    finally:
        restarts.TRIGGER_MISFIT = default
    print(f"# {len(trials)} paper trials (seeds {args.seed}..{args.seed + len(trials) - 1}), alternating, "
          f"best of {args.repeat}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print("| chain | TRIGGER_MISFIT | triggered | IoU median | IoU mean | IoU < 0.7 | IoU < 0.5 | "
          "median s | mean s | median time / 1-2-3G |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, (chain, trigger) in enumerate(settings):
        s, q = seconds[:, k], iou[:, k]
        print(f"| {chain} | {'-' if trigger is None else trigger} | {triggered[:, k].sum()} | {np.median(q):.3f} | "
              f"{q.mean():.3f} | {(q < 0.7).sum()} | {(q < 0.5).sum()} | {np.median(s):.4f} | {s.mean():.4f} | "
              f"{np.median(s) / np.median(seconds[:, 0]):.2f} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"seed": args.seed, "settings": settings, "seconds": seconds.tolist(), "iou": iou.tolist(),
                       "triggered": triggered.tolist()}, f)


if __name__ == "__main__":
    main()
