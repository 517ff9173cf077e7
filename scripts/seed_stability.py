"""Does a chain give one answer? The same dataset fitted with two sampling seeds, fit against fit.

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/seed_stability.py DATASET --seeds 0 1 [--chain default] \
        [--out DIR] [--json OUT.json]
    python scripts/seed_stability.py DATASET --fits fits_seed0.jsonl fits_seed1.jsonl

``DATASET`` is a directory written by ``sqsim generate``. For each seed the dataset is fitted as
``sqfit fit DATASET -o DIR/fits_seedS.jsonl --seed S --chain C`` does (``--out``, default a
temporary directory), or existing ``fits.jsonl`` files are compared (``--fits``). Per object (the
records of both files with the same ``trial`` and ``object_id`` and status ``ok``) it computes the
3D IoU between the two fits (:func:`sqfit.metrics.iou_3d`) and each fit's 3D IoU against the
ground truth (``gt.json``, superquadric objects only). Prints the fraction of objects whose two
fits agree at 3D IoU >= ``--threshold`` (issue 22: 0.98, for >= 99 % of objects), the median and
10th percentile of the IoU against the truth per seed, and one line per disagreeing object
("flip"): both fits' IoU against the truth, their final costs, and the 3D IoU of the two seeds'
snapshots after each stage (where the two runs part).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sqfit import DEFAULT_CHAIN, Superquadric  # noqa: E402
from sqfit.cli.fit import fit_dataset  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402
from sqfit.views.dataset import load_trial, trial_dirs  # noqa: E402

#: Two fits of one object "agree" at this 3D IoU or above (issue 22, point 3).
AGREE_IOU = 0.98


def read_fits(path):
    """``{(trial, object_id): record}`` of the records with status ``ok`` in a fits.jsonl file."""
    out = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            if rec.get("status") == "ok" and rec.get("params") is not None:
                out[(rec["trial"], rec["object_id"])] = rec
    return out


def ground_truth(dataset):
    """``{(trial, object_id): Superquadric}`` of the superquadric objects of a dataset's gt.json files."""
    out = {}
    for path in trial_dirs(dataset):
        trial = load_trial(path)
        for obj in trial.objects:
            if obj.get("kind", "superquadric") == "superquadric" and obj.get("params") is not None:
                out[(trial.name, obj["id"])] = Superquadric.from_vector(obj["params"])
    return out


def compare(fits_a, fits_b, truth, threshold=AGREE_IOU):
    """Per object present in both fits: fit-vs-fit IoU, IoU against the truth, costs, stage IoUs.

    Returns
    -------
    rows : list of dict
        ``key``, ``iou_ab`` (3D IoU of the two fits), ``iou_a`` / ``iou_b`` (against the truth; None
        without one), ``cost_a`` / ``cost_b`` and ``stages`` (``[(name, iou of the two snapshots)]``,
        only for objects whose fits disagree, IoU ``< threshold``), sorted by ``key``.
    """
    rows = []
    for key in sorted(set(fits_a) & set(fits_b), key=str):
        a, b = fits_a[key], fits_b[key]
        sa, sb = Superquadric.from_vector(a["params"]), Superquadric.from_vector(b["params"])
        gt = truth.get(key)
        row = {"key": key, "iou_ab": iou_3d(sa, sb), "cost_a": a.get("cost"), "cost_b": b.get("cost"),
               "iou_a": None if gt is None else iou_3d(sa, gt), "iou_b": None if gt is None else iou_3d(sb, gt)}
        if row["iou_ab"] < threshold:
            row["stages"] = [(x["name"], _snapshot_iou(x, y)) for x, y in zip(a["stages"], b["stages"])]
        rows.append(row)
    return rows


def _snapshot_iou(x, y):
    if x["superquadric"] is None or y["superquadric"] is None:
        return None
    return iou_3d(Superquadric.from_vector(x["superquadric"]), Superquadric.from_vector(y["superquadric"]))


def summary(rows, threshold=AGREE_IOU):
    """``dict``: objects compared, the fraction that agree, and per seed the median and 10th
    percentile of the IoU against the truth."""
    agree = np.array([r["iou_ab"] >= threshold for r in rows])
    out = {"objects": len(rows), "agree": int(agree.sum()), "agree_fraction": float(agree.mean()) if len(rows) else 0.0}
    for side in ("a", "b"):
        ious = np.array([r[f"iou_{side}"] for r in rows if r[f"iou_{side}"] is not None])
        if len(ious):
            out[f"median_{side}"] = float(np.median(ious))
            out[f"p10_{side}"] = float(np.percentile(ious, 10))
    return out


def _fmt(x, spec=".3f"):
    return "-" if x is None else format(x, spec)


def report(rows, seeds, threshold=AGREE_IOU):
    """The printed report (str)."""
    s = summary(rows, threshold)
    lines = [f"objects: {s['objects']}; fits agree (3D IoU >= {threshold}): {s['agree']} "
             f"({s['agree_fraction']:.1%})"]
    for side, seed in zip(("a", "b"), seeds):
        if f"median_{side}" in s:
            lines.append(f"seed {seed}: IoU vs truth median {s[f'median_{side}']:.4f}, "
                         f"10th percentile {s[f'p10_{side}']:.4f}")
    flips = [r for r in rows if r["iou_ab"] < threshold]
    if flips:
        lines.append(f"flips (trial/object: IoU of the fits; vs truth seed {seeds[0]} / {seeds[1]}; "
                     f"final cost {seeds[0]} / {seeds[1]}; per-stage IoU of the two seeds' snapshots):")
    for r in flips:
        stages = " ".join(f"{name}:{_fmt(iou, '.2f')}" for name, iou in r["stages"])
        lines.append(f"  {r['key'][0]}/{r['key'][1]}: {r['iou_ab']:.3f}; {_fmt(r['iou_a'])} / {_fmt(r['iou_b'])}; "
                     f"{_fmt(r['cost_a'], '.2e')} / {_fmt(r['cost_b'], '.2e')}; {stages}")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", help="dataset directory written by sqsim generate (for gt.json)")
    parser.add_argument("--seeds", type=int, nargs=2, default=(0, 1), help="the two sampling seeds")
    parser.add_argument("--chain", default="default", help="chain to fit ('default' = sqfit.DEFAULT_CHAIN)")
    parser.add_argument("--fits", nargs=2, metavar="JSONL", help="compare these fits.jsonl files instead of fitting")
    parser.add_argument("--out", help="directory for the fits_seedS.jsonl files (default: a temporary one)")
    parser.add_argument("--threshold", type=float, default=AGREE_IOU, help="fit-vs-fit 3D IoU that counts as agreeing")
    parser.add_argument("--json", help="also write the summary and per-object rows here")
    args = parser.parse_args(argv)
    if not 0 < args.threshold <= 1:
        parser.error(f"--threshold must be in (0, 1], got {args.threshold}")
    if args.fits:
        paths = [Path(p) for p in args.fits]
    else:
        chain = DEFAULT_CHAIN if args.chain == "default" else args.chain
        out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="seed_stability_"))
        paths = [out / f"fits_seed{s}.jsonl" for s in args.seeds]
        for seed, path in zip(args.seeds, paths):
            fit_dataset(args.dataset, path, chain, seed=seed, progress=False)
    rows = compare(read_fits(paths[0]), read_fits(paths[1]), ground_truth(args.dataset), args.threshold)
    print(report(rows, args.seeds, args.threshold))
    if args.json:
        data = {"summary": summary(rows, args.threshold), "fits": [str(p) for p in paths],
                "rows": [{**r, "key": list(r["key"])} for r in rows]}
        Path(args.json).write_text(json.dumps(data, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
