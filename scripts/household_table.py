"""Per household kind or mesh file: the default against the visual-hull baseline and the representation limit.

Usage::

    python scripts/household_table.py RUN_DIR [RUN_DIR ...] [--chains default,hull] [--ratio 0.95] [--margin 0.03] \
        [--silhouettes]

Each ``RUN_DIR`` is an ``sqsim experiment`` output of a household or mesh-file scene (e.g. one per
kind: README "Real objects", "Where the default stands"); their records are pooled by kind
(``gt.item``, or the mesh file's name for ``objects.kind = "mesh"``) and by seed (the scene's
``experiment.seed`` in ``experiment.json``). Prints one Markdown row per
kind: the first chain's, the second chain's and the limit's median 3D IoU, the first chain's IoU
over the limit (ratio of the medians), the first chain minus the second, and both chains' median ms
per object; each cell gives the seeds in ascending order, separated by ``/``. Bold where the issue
"Real objects"'s targets hold: IoU / limit at least ``--ratio``, the difference at least ``--margin``.
A run without limits (``experiment.limit = false``) leaves those cells empty.

``--silhouettes``: a second table, whether the masks favour the first chain's fit or the limit: per
kind the median mean IoU of the first chain's silhouettes with the mask contours
(``metrics.r_iou_m_contour``), the same of the limit superquadric's (``metrics.r_iou_m_contour_limit``,
written by ``sqsim experiment`` since 2026-12-02) and on how many objects the limit's match better.
Where the limit's match worse on every object, matching the masks better does not lead towards it: what
separates fit and limit is not in the masks (README "Real objects", "Do the masks favour the limit?").
"""

from __future__ import annotations

import argparse
import json
import re
from collections import defaultdict
from pathlib import Path

import numpy as np

from sqfit.fitting import CHAIN_ALIASES
from sqsim.data.files import read_records

#: Row order: the furniture first, as the README's tables.
KINDS = ("table", "monitor", "lamp", "toy", "chair", "laptop", "bowl", "mug", "bottle", "plant_pot", "book", "can")


def _runs(run_dirs):
    """``{kind: {seed: {chain: [record, ...]}}}`` of the household and mesh-file records of ``run_dirs``."""
    pooled = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for run_dir in run_dirs:
        path, config = Path(run_dir) / "trials.jsonl", Path(run_dir) / "experiment.json"
        if not path.is_file() or not config.is_file():
            raise SystemExit(f"{run_dir}: not an sqsim experiment output (trials.jsonl and experiment.json)")
        seed = int(json.loads(config.read_text())["scene"]["experiment"]["seed"])
        try:
            records = read_records(path)  # as a resumed run reads them: a line cut short by a kill is dropped
        except ValueError as exc:
            raise SystemExit(str(exc)) from None
        for r in records:
            gt = r.get("gt", {})
            kind = gt.get("item") or (Path(gt["path"]).stem if gt.get("path") else None)
            if kind is not None:
                pooled[kind][seed][r["chain"]].append(r)
    if not pooled:
        raise SystemExit(f"{', '.join(map(str, run_dirs))}: no household or mesh-file objects")
    return pooled


def _median(records, value):
    values = [value(r) for r in records]
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def _kinds(pooled):
    """The kinds of ``pooled`` in the README's order (:data:`KINDS`), others (mesh files) after them."""
    return sorted(pooled, key=lambda k: KINDS.index(k) if k in KINDS else len(KINDS))


def kind_rows(pooled, first, second):
    """Per kind and seed the medians: ``{kind: {seed: dict(a, b, limit, ms_a, ms_b)}}`` (None where missing)."""
    out = {}
    for kind in _kinds(pooled):
        out[kind] = {}
        for seed, chains in sorted(pooled[kind].items()):
            a, b = chains.get(first, []), chains.get(second, [])
            out[kind][seed] = {"a": _median(a, lambda r: r["metrics"]["iou"]),
                               "b": _median(b, lambda r: r["metrics"]["iou"]),
                               "limit": _median(a, lambda r: (r.get("limit") or {}).get("iou")),
                               "ms_a": _median(a, lambda r: 1e3 * r["time_s"]),
                               "ms_b": _median(b, lambda r: 1e3 * r["time_s"]), "n": len(a)}
    return out


def silhouette_rows(pooled, first):
    """Per kind and seed: ``{kind: {seed: dict(fit, limit, better, n)}}``, the medians of the first chain's
    and of the limit's silhouette IoU with the mask contours and the objects where the limit's is higher,
    over the records that carry both (None and 0 where none do)."""
    out = {}
    for kind in _kinds(pooled):
        out[kind] = {}
        for seed, chains in sorted(pooled[kind].items()):
            both = [r["metrics"] for r in chains.get(first, []) if "r_iou_m_contour_limit" in r["metrics"]]
            fit = np.array([m["r_iou_m_contour"] for m in both])
            limit = np.array([m["r_iou_m_contour_limit"] for m in both])
            out[kind][seed] = {"fit": float(np.median(fit)) if both else None,
                               "limit": float(np.median(limit)) if both else None,
                               "better": int((limit > fit).sum()), "n": len(both)}
    return out


def silhouette_markdown(rows, name):
    """The Markdown table of :func:`silhouette_rows`."""
    lines = [f"| kind | {name}'s silhouettes | the limit's | the limit's match better |", "|---|---|---|---|"]
    for kind, seeds in rows.items():
        s = list(seeds.values())
        better = " / ".join(f"{x['better']} of {x['n']}" if x["n"] else "–" for x in s)
        lines.append(f"| {kind.replace('_', ' ')} | {_cell([x['fit'] for x in s], '{:.3f}')} | "
                     f"{_cell([x['limit'] for x in s], '{:.3f}')} | {better} |")
    return "\n".join(lines)


def _cell(values, fmt, target=None):
    """``values`` joined by " / ", each in ``fmt``, in bold at or above ``target``; a value below ``target``
    that ``fmt`` would round up to it gets more decimals until it does not (0.9496 of a 0.95 target:
    "0.9496", not bold), so that no cell reads as the target where it is missed."""
    def one(v):
        if v is None:
            return "–"
        text, places = fmt.format(v), fmt
        while target is not None and v < target and float(text) >= target:
            places = re.sub(r"\.(\d+)f", lambda m: f".{int(m.group(1)) + 1}f", places)
            text = places.format(v)
        text = text.replace("-", "−")
        return f"**{text}**" if target is not None and v >= target else text
    return " / ".join(one(v) for v in values)


def markdown(rows, names, ratio, margin):
    """The Markdown table of :func:`kind_rows`."""
    a, b = names
    lines = [f"| kind | {a} | {b} | limit | {a} / limit | {a} − {b} | ms, {a} / {b} |",
             "|---|---|---|---|---|---|---|"]
    for kind, seeds in rows.items():
        s = list(seeds.values())
        get = lambda key: [x[key] for x in s]  # noqa: E731
        over = [x["a"] / x["limit"] if x["a"] is not None and x["limit"] else None for x in s]
        diff = [x["a"] - x["b"] if x["a"] is not None and x["b"] is not None else None for x in s]
        ms = ", ".join(_cell([x["ms_a"], x["ms_b"]], "{:.0f}") for x in s)
        lines.append(f"| {kind.replace('_', ' ')} | {_cell(get('a'), '{:.3f}')} | {_cell(get('b'), '{:.3f}')} | "
                     f"{_cell(get('limit'), '{:.3f}')} | {_cell(over, '{:.2f}', ratio)} | "
                     f"{_cell(diff, '{:+.3f}', margin)} | {ms} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    parser.add_argument("--chains", default="default,hull", help="the two chains to compare, as recorded "
                        "(aliases are expanded: default = sqfit.DEFAULT_CHAIN, hull = the visual-hull baseline)")
    parser.add_argument("--ratio", type=float, default=0.95, help="bold IoU / limit at or above this")
    parser.add_argument("--margin", type=float, default=0.03, help="bold the difference at or above this")
    parser.add_argument("--silhouettes", action="store_true", help="also the table of the first chain's and the "
                        "limit's silhouettes against the masks (module docstring)")
    args = parser.parse_args(argv)
    names = args.chains.split(",")
    if len(names) != 2:
        raise SystemExit(f"--chains needs two chains, got {args.chains!r}")
    chains = [CHAIN_ALIASES.get(c, c) for c in names]
    pooled = _runs(args.run_dirs)
    rows = kind_rows(pooled, *chains)
    labels = [f"`{n}`" if n in CHAIN_ALIASES else n for n in names]
    print(markdown(rows, labels, args.ratio, args.margin))
    if args.silhouettes:
        print("\n" + silhouette_markdown(silhouette_rows(pooled, chains[0]), labels[0]))
    seeds = sorted({seed for seeds in rows.values() for seed in seeds})
    counts = sorted({x["n"] for seeds in rows.values() for x in seeds.values()})
    print(f"\nseeds {' / '.join(map(str, seeds))}; objects per kind and seed: {', '.join(map(str, counts))}")


if __name__ == "__main__":
    main()
