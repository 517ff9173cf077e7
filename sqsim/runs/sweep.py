"""``sqsim sweep``: run the experiment over a grid of scene values and draw degradation curves.

A sweep is a list of axes, each a scene key (``section.key``) with values; several axes form a
grid (their Cartesian product). Each grid point is a complete ``sqsim experiment`` in its own
sub-directory ``DIR/points/<key>=<value>[,...]``, so a sweep resumes like an experiment does.

Axes come from the command line (``--param KEY --values V1,V2,...``, repeatable) or from a sweep
file: a TOML with a ``[sweep]`` table naming a base scene and the axes, plus any scene sections
to merge over the base (keys given here replace the base's)::

    [sweep]
    base = "paper.toml"             # relative to this file
    [[sweep.axis]]
    param = "noise.erosion_px"
    values = [0, 1, 2, 3, 4, 5]

    [experiment]
    trials = 30

Outputs: ``sweep.jsonl`` (one line per grid point and chain: medians, quartiles and means of
IOU, R-IOU, R-IOU-M and time, success rate, errors), ``sweep.md`` (a table) and ``sweep.png``
(median and inter-quartile band of IOU and R-IOU and the success rate against the first axis,
one line per chain).
"""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import numpy as np

from ..data.files import atomic_figure, atomic_write_text, read_records
from .experiment import parse_chains, run_experiment

QUANTITIES = ("iou", "r_iou", "r_iou_m", "time_s")


def add_arguments(parser):
    from ..world.scene import add_set_option

    parser.add_argument("scene", help="scene TOML, or a sweep file with a [sweep] table (see scenes/sweep-*.toml)")
    add_set_option(parser, "applies to the scene every grid point starts from")
    parser.add_argument("-o", "--output", required=True, help="output directory (resumed if it exists)")
    parser.add_argument("--param", action="append", default=[], metavar="KEY",
                        help="scene key to sweep, e.g. noise.boundary_jitter_px (repeat for a grid)")
    parser.add_argument("--values", action="append", default=[], metavar="V1,V2,...",
                        help="comma-separated values of the preceding --param")
    parser.add_argument("--trials", type=int, default=None, help="trials per grid point (default: the scene's)")
    parser.add_argument("--chains", default=None, help="chains, as for 'sqsim experiment' (default: the scene's)")
    parser.add_argument("--seed", type=int, default=None, help="experiment seed (default: the scene's)")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes")
    parser.add_argument("--scheduler", default=None, help="Dask scheduler address tcp://HOST:PORT")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args):
    from ..world.scene import scene_overrides

    scene, axes = load_sweep(args.scene, scene_overrides(args.set))
    if args.param or args.values:
        axes = parse_axes(args.param, args.values)
    if not axes:
        raise ValueError(f"{args.scene}: nothing to sweep: give --param KEY --values V1,V2,... "
                         "or a sweep file with [[sweep.axis]] tables")
    rows = run_sweep(scene, axes, args.output, trials=args.trials, chains=parse_chains(args.chains),
                     seed=args.seed, workers=args.workers, scheduler=args.scheduler,
                     progress=not args.no_progress)
    print(sweep_markdown(rows, axes))
    print(f"wrote {Path(args.output) / 'sweep.jsonl'}, sweep.md, sweep.png")
    return 0


def parse_value(text):
    """A command-line value: true/false, an int if it looks like one, then float, else the string."""
    text = text.strip()
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_axes(params, values):
    """Pair ``--param`` and ``--values`` arguments into ``[(key, [values...]), ...]``."""
    if len(params) != len(values):
        raise ValueError(f"every --param needs one --values (got {len(params)} --param, {len(values)} --values)")
    axes = []
    for key, text in zip(params, values):
        vals = [parse_value(v) for v in text.split(",") if v.strip()]
        if not vals:
            raise ValueError(f"--values for {key} is empty")
        axes.append((key, vals))
    keys = [k for k, _ in axes]
    if len(set(keys)) != len(keys):
        raise ValueError(f"a scene key is swept twice: {keys}")
    return axes


def load_sweep(path, overrides=None):
    """Scene and axes from a sweep file (or a plain scene, which has no axes), with ``overrides``
    (``{"section.key": value}``, the command's ``--set``) replacing keys before the scene is validated,
    as :func:`sqsim.world.scene.load_scene` does.

    Returns
    -------
    scene : sqsim.world.scene.Scene
    axes : list of (str, list)
    """
    from ..world.scene import parse_scene, read_toml

    path = Path(path)
    data = read_toml(path)
    spec = data.pop("sweep", None)
    if spec is None:
        return parse_scene(data, source=str(path), overrides=overrides), []
    if not isinstance(spec, dict):
        raise ValueError(f"{path}: [sweep] must be a table")
    unknown = set(spec) - {"base", "axis"}
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {sorted(unknown)} in [sweep] (known: base, axis)")
    merged = {}
    if "base" in spec:
        base = read_toml(path.parent / str(spec["base"]))
        if "sweep" in base:
            raise ValueError(f"{path}: the base scene {spec['base']} must not itself be a sweep")
        merged = base
    for section, values in data.items():
        if not isinstance(values, dict):
            raise ValueError(f"{path}: [{section}] must be a table of keys")
        merged.setdefault(section, {}).update(values)
    axes = []
    for n, axis in enumerate(spec.get("axis", []), 1):
        if not isinstance(axis, dict) or set(axis) != {"param", "values"}:
            raise ValueError(f"{path}: [[sweep.axis]] #{n} needs exactly the keys 'param' and 'values'")
        if not isinstance(axis["values"], list) or not axis["values"]:
            raise ValueError(f"{path}: [[sweep.axis]] #{n} values must be a non-empty list")
        axes.append((str(axis["param"]), list(axis["values"])))
    return parse_scene(merged, source=str(path), overrides=overrides), axes


def point_name(point):
    """Directory name of a grid point, e.g. ``noise.erosion_px=2,trajectory.views=4``."""
    return ",".join(f"{k}={re.sub(r'[^A-Za-z0-9_.+-]', '_', str(v))}" for k, v in point.items())


def run_sweep(scene, axes, output, *, trials=None, chains=None, seed=None, workers=1, scheduler=None,
              progress=True):
    """Run every grid point's experiment and write ``sweep.jsonl``, ``sweep.md``, ``sweep.png``.

    Returns
    -------
    rows : list of dict
        One per (grid point, chain), as written to ``sweep.jsonl``.
    """
    out = Path(output)
    points = [dict(zip([k for k, _ in axes], combo)) for combo in itertools.product(*[v for _, v in axes])]
    # Validate every grid point before running any, so a typo fails at once.
    scenes = [scene.with_overrides(p) for p in points]
    rows = []
    for n, (point, point_scene) in enumerate(zip(points, scenes), 1):
        if progress:
            print(f"[{n}/{len(points)}] {point_name(point)}", flush=True)
        point_dir = out / "points" / point_name(point)
        summary = run_experiment(point_scene, point_dir, trials=trials, chains=chains, seed=seed,
                                 workers=workers, scheduler=scheduler, progress=progress, figures=False)
        records = read_records(point_dir / "trials.jsonl")
        for chain in summary["chains"]:
            rows.append(_row(point, chain, summary, records))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "sweep.jsonl", "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))
    atomic_write_text(out / "sweep.md", sweep_markdown(rows, axes))
    atomic_figure(sweep_figure, out / "sweep.png", rows, axes)
    return rows


def _row(point, chain, summary, records):
    trials = summary["trials"]
    values = {q: [r["metrics"][q] for r in records
                  if r["chain"] == chain and r["trial"] < trials] for q in QUANTITIES}
    row = {"point": point, "chain": chain, "trials": trials,
           "success_rate": summary["chains"][chain]["success_rate"],
           "errors": summary["chains"][chain]["errors"]}
    for q, v in values.items():
        v = np.asarray(v, dtype=np.float64)
        q25, q50, q75 = np.percentile(v, [25, 50, 75]) if v.size else (np.nan,) * 3
        row[q] = {"median": float(q50), "q25": float(q25), "q75": float(q75),
                  "mean": float(np.mean(v)) if v.size else float("nan")}
    return row


def sweep_markdown(rows, axes):
    """One table row per grid point and chain: medians (IQR) and success rate."""
    keys = [k for k, _ in axes]
    head = keys + ["chain", "IOU median (IQR)", "R-IOU median (IQR)", "R-IOU-M median", "success", "time ms"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [str(r["point"][k]) for k in keys] + [r["chain"]]
        for q in ("iou", "r_iou"):
            cells.append(f"{r[q]['median']:.3f} ({r[q]['q25']:.3f}–{r[q]['q75']:.3f})")
        cells += [f"{r['r_iou_m']['median']:.3f}", f"{100 * r['success_rate']:.0f} %",
                  f"{1000 * r['time_s']['median']:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sweep_figure(rows, axes, path):
    """Median and inter-quartile band of IOU and R-IOU, and the success rate, against the first axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x_key = axes[0][0]
    other = [k for k, _ in axes[1:]]
    groups = {}
    for r in rows:
        label = r["chain"] + "".join(f", {k}={r['point'][k]}" for k in other)
        groups.setdefault(label, []).append(r)
    numeric = all(isinstance(v, (int, float)) for v in axes[0][1])
    fig, axs = plt.subplots(1, 3, figsize=(13, 3.8))
    for label, group in groups.items():
        xs = [g["point"][x_key] for g in group]
        xpos = xs if numeric else list(range(len(xs)))
        for ax, q in zip(axs[:2], ("iou", "r_iou")):
            med = [g[q]["median"] for g in group]
            line, = ax.plot(xpos, med, marker="o", label=label)
            ax.fill_between(xpos, [g[q]["q25"] for g in group], [g[q]["q75"] for g in group],
                            color=line.get_color(), alpha=0.2)
        axs[2].plot(xpos, [100 * g["success_rate"] for g in group], marker="o", label=label)
    titles = ("3D IoU (median, IQR band)", "R-IOU (median, IQR band)", "success rate [%]")
    for ax, title in zip(axs, titles):
        ax.set_title(title)
        ax.set_xlabel(x_key)
        ax.grid(alpha=0.3)
        if not numeric:
            ax.set_xticks(range(len(axes[0][1])), [str(v) for v in axes[0][1]])
    axs[0].set_ylim(0, 1)
    axs[1].set_ylim(0, 1)
    axs[2].set_ylim(0, 102)
    axs[2].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)

