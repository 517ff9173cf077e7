"""CPU time per object of one chain in two source trees, measured alternately (shared machines).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_alternate.py OLD_TREE NEW_TREE \
        [--chain 1-2-3G] [--trials 100] [--rounds 3] [--repeat 3]

Each round runs the same measurement once per tree, in a fresh process with that tree first on
``PYTHONPATH``, alternating the order, so both trees see the same load. A measurement fits the
paper trials ``0 .. trials-1`` (``sqfit.testing.paper_trial``: clean masks, 3 views) with the
chain, keeps the fastest of ``repeat`` fits per trial in CPU time (``time.process_time``, not
distorted by other users' processes) and reports the median and mean per object and the median
3D IoU. Prints one table row per tree and round, then the median over rounds and the ratio.
To get an old tree without touching another worktree: ``git archive COMMIT | tar -x -C DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

_MEASURE = r"""
import json, sys, time
import numpy as np
import sqfit
from sqfit.metrics import iou_3d
from sqfit.testing import paper_trial
chain, trials, repeat = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
times, ious = [], []
for seed in range(trials):
    t = paper_trial(seed)
    best = np.inf
    for _ in range(repeat):
        c = time.process_time()
        r = sqfit.fit(t.observations, chain)
        best = min(best, time.process_time() - c)
    times.append(best)
    ious.append(iou_3d(r.superquadric, t.gt) if r.superquadric is not None else 0.0)
print(json.dumps({"median_s": float(np.median(times)), "mean_s": float(np.mean(times)),
                  "median_iou": float(np.median(ious)), "file": sqfit.__file__}))
"""


def measure(tree, chain, trials, repeat):
    env = dict(os.environ, PYTHONPATH=os.path.abspath(tree), OPENBLAS_NUM_THREADS="1")
    # cwd=tree: ``python -c`` puts the working directory first on sys.path, ahead of PYTHONPATH
    out = subprocess.run([sys.executable, "-c", _MEASURE, chain, str(trials), str(repeat)], env=env,
                         capture_output=True, text=True, check=True, cwd=os.path.abspath(tree))
    result = json.loads(out.stdout.strip().splitlines()[-1])
    if not result["file"].startswith(os.path.abspath(tree) + os.sep):
        raise RuntimeError(f"measured {result['file']}, not the tree {tree}")
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("old")
    parser.add_argument("new")
    parser.add_argument("--chain", default="1-2-3G")
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    trees = {"old": args.old, "new": args.new}
    results = {"old": [], "new": []}
    print(f"# chain {args.chain}, {args.trials} paper trials, best of {args.repeat} fits per trial, CPU time")
    print("| round | tree | median ms/object | mean ms/object | median IoU |")
    print("|---|---|---|---|---|")
    for k in range(args.rounds):
        order = ("old", "new") if k % 2 == 0 else ("new", "old")
        for name in order:
            r = measure(trees[name], args.chain, args.trials, args.repeat)
            results[name].append(r)
            print(f"| {k} | {name} ({trees[name]}) | {1e3 * r['median_s']:.2f} | {1e3 * r['mean_s']:.2f} | "
                  f"{r['median_iou']:.3f} |", flush=True)
    old = np.median([r["median_s"] for r in results["old"]])
    new = np.median([r["median_s"] for r in results["new"]])
    print(f"median over rounds: old {1e3 * old:.2f} ms, new {1e3 * new:.2f} ms, new / old = {new / old:.3f}")


if __name__ == "__main__":
    sys.exit(main())
