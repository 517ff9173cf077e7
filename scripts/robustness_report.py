"""Combine finished sweeps into one robustness figure and a Markdown table (README "Robustness").

Usage::

    python scripts/robustness_report.py runs/sweep-* --figure docs/figures/robustness.png \
        --table docs/robustness.md

Each argument is a ``sqsim sweep`` output directory (with ``sweep.jsonl``) of a single axis. The
figure has one panel per sweep: median 3D IoU with its inter-quartile band (left axis) and the
success rate (right axis, dotted) against the swept value, one colour per chain.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def load(directory):
    path = Path(directory) / "sweep.jsonl"
    if not path.is_file():
        raise SystemExit(f"{directory}: no sweep.jsonl (is the sweep finished?)")
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    keys = {k for r in rows for k in r["point"]}
    if len(keys) != 1:
        raise ValueError(f"{directory}: expected a one-axis sweep, got axes {sorted(keys)}")
    return keys.pop(), rows


def figure(sweeps, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 3
    nrows = math.ceil(len(sweeps) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.3 * cols, 3.1 * nrows), squeeze=False)
    colours = {}
    for ax, (key, rows) in zip(axes.ravel(), sweeps):
        twin = ax.twinx()
        for chain in dict.fromkeys(r["chain"] for r in rows):
            sel = [r for r in rows if r["chain"] == chain]
            x = [r["point"][key] for r in sel]
            colour = colours.setdefault(chain, f"C{len(colours)}")
            ax.plot(x, [r["iou"]["median"] for r in sel], "o-", color=colour, label=chain)
            ax.fill_between(x, [r["iou"]["q25"] for r in sel], [r["iou"]["q75"] for r in sel],
                            color=colour, alpha=0.18)
            twin.plot(x, [100 * r["success_rate"] for r in sel], ":", color=colour)
        ax.set_ylim(0, 1)
        twin.set_ylim(0, 105)
        ax.set_xlabel(key)
        ax.set_ylabel("3D IoU (median, IQR)")
        twin.set_ylabel("success [%] (dotted)")
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(sweeps):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=8, loc="lower left")
    fig.suptitle(f"Paper scene, {sweeps[0][1][0]['trials']} trials per point: fit quality under mask and pose noise")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def table(sweeps, chain):
    lines = [f"| sweep | values | median 3D IoU ({chain}) | success |", "|---|---|---|---|"]
    for key, rows in sweeps:
        sel = [r for r in rows if r["chain"] == chain]
        lines.append(f"| `{key}` | " + " / ".join(str(r["point"][key]) for r in sel) + " | "
                     + " / ".join(f"{r['iou']['median']:.2f}" for r in sel) + " | "
                     + " / ".join(f"{100 * r['success_rate']:.0f}" for r in sel) + " % |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweeps", nargs="+", help="sweep output directories")
    parser.add_argument("--figure", required=True, help="PNG to write")
    parser.add_argument("--table", help="Markdown table to write (default chain's medians)")
    parser.add_argument("--chain", default=None, help="chain for the table (default: sqfit.DEFAULT_CHAIN)")
    args = parser.parse_args(argv)
    import sqfit

    sweeps = [load(d) for d in args.sweeps]
    figure(sweeps, args.figure)
    text = table(sweeps, args.chain or sqfit.DEFAULT_CHAIN)
    if args.table:
        Path(args.table).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
