"""Summaries, tables and figures of an experiment (the paper's Table II, Figures 4 and 5).

Everything here reads the per-record dictionaries that ``sqsim.runs.experiment`` writes to
``trials.jsonl``; nothing is recomputed from the fits.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _read_paper_table():
    rows = Path(__file__).with_name("paper_table2.csv").read_text(encoding="utf-8").splitlines()
    data = [r.split(",") for r in rows if r and not r.startswith("#")][1:]
    return {r[0]: tuple(float(x) for x in r[1:]) for r in data}


#: The paper's Table II (Tschopp et al.): chain -> (IOU M, A, Std, R-IOU M, A, Std,
#: R-IOU-M M, A, Std, Time M, A, Std [s], success rate), from ``paper_table2.csv`` beside this module.
PAPER_TABLE_II = _read_paper_table()

METRICS = ("iou", "r_iou", "r_iou_m", "time_s")
METRIC_LABELS = {"iou": "IOU", "r_iou": "R-IOU", "r_iou_m": "R-IOU-M", "time_s": "Time [s]"}


def stats(values):
    """``{"median", "mean", "std"}`` of a sequence (population std, as numpy); NaN if empty."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return {"median": float("nan"), "mean": float("nan"), "std": float("nan")}
    return {"median": float(np.median(v)), "mean": float(np.mean(v)), "std": float(np.std(v))}


def summarize(records, chains, scene_name, seed, trials, resampled):
    """The ``summary.json`` dictionary from experiment records (shape: ``sqsim.runs.experiment`` docstring).

    Parameters
    ----------
    records : list of dict
        ``trials.jsonl`` records; one per (trial, object, chain).
    chains : list of str
        Chains to summarise, in output order.

    Returns
    -------
    summary : dict
        With representation limits in the records of non-superquadric ground truths
        (``metrics.iou_limit``), also ``iou_limit`` (over objects) at the top, ``iou_limit`` and
        ``iou_over_limit`` (per-record IOU / limit) per chain, and per chain ``by_item``: the same
        with ``iou``, ``r_iou_m_contour`` and ``fits`` per household kind (``gt.item``); where the
        records carry ``metrics.r_iou_m_contour_limit`` (the limit's silhouettes against the mask
        contours), its stats beside ``iou_limit``.
    """
    out = {"scene": scene_name, "trials": int(trials), "resampled": int(resampled), "seed": int(seed), "chains": {}}
    limited = has_limits(records)
    if limited:
        objects = {(r["trial"], r["object"]): r["metrics"]["iou_limit"] for r in records if "iou_limit" in r["metrics"]}
        out["iou_limit"] = stats(list(objects.values()))
    for chain in chains:
        rows = [r for r in records if r["chain"] == chain]
        entry = {m: stats([r["metrics"][m] for r in rows]) for m in METRICS}
        entry["r_iou_m_contour"] = stats([r["metrics"]["r_iou_m_contour"] for r in rows])
        entry["success_rate"] = float(np.mean([r["metrics"]["success"] for r in rows])) if rows else float("nan")
        entry["errors"] = int(sum(r["status"] != "ok" for r in rows))
        entry["fits"] = len(rows)
        if limited:
            entry.update(_limit_stats(rows))
            by_item = {}
            for r in rows:
                if r["gt"].get("item") is not None:
                    by_item.setdefault(r["gt"]["item"], []).append(r)
            if by_item:
                entry["by_item"] = {item: {"fits": len(sub), "iou": stats([r["metrics"]["iou"] for r in sub]),
                                           "r_iou_m_contour": stats([r["metrics"]["r_iou_m_contour"] for r in sub]),
                                           **_limit_stats(sub)} for item, sub in sorted(by_item.items())}
        out["chains"][chain] = entry
    return out


def has_limits(records):
    """Whether some record carries a representation limit (non-superquadric ground truths only)."""
    return any("iou_limit" in r["metrics"] for r in records)


def _limit_stats(rows):
    """``iou_limit`` and ``iou_over_limit`` stats of the rows that carry a limit, and where they carry
    it, ``r_iou_m_contour_limit``: the mean IoU of the limit's silhouettes with the mask contours (to
    set beside a chain's ``r_iou_m_contour``: whether the masks favour the fit or the limit)."""
    rows = [r for r in rows if "iou_limit" in r["metrics"]]
    limits = np.array([r["metrics"]["iou_limit"] for r in rows])
    ious = np.array([r["metrics"]["iou"] for r in rows])
    out = {"iou_limit": stats(limits), "iou_over_limit": stats(ious / np.maximum(limits, 1e-12))}
    agreeing = [r for r in rows if "r_iou_m_contour_limit" in r["metrics"]]
    if agreeing:
        out["r_iou_m_contour_limit"] = stats([r["metrics"]["r_iou_m_contour_limit"] for r in agreeing])
    return out


def _row_values(entry):
    vals = [entry[m][k] for m in METRICS for k in ("median", "mean", "std")]
    return vals + [entry["success_rate"]]


def _chain_label(chain, tex=False):
    return chain.replace("-", r"$\rightarrow$" if tex else " → ")


def _limited(summary):
    return "iou_limit" in summary


def table_markdown(summary, with_paper=True):
    """Table II layout in Markdown; with ``with_paper``, the paper's row follows each chain.

    With representation limits (:func:`summarize`), two more columns (medians of the limit and of
    IOU / limit) and a table per household kind follow.
    """
    limited = _limited(summary)
    head = ["Stages"] + [f"{METRIC_LABELS[m]} {k}" for m in METRICS for k in ("M", "A", "Std")] + ["σ"]
    head += ["Limit M", "IOU/Limit M"] if limited else []
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for chain, entry in summary["chains"].items():
        vals = _row_values(entry)
        extra = f" {entry['iou_limit']['median']:.3f} | {entry['iou_over_limit']['median']:.3f} |" if limited else ""
        lines.append(f"| {_chain_label(chain)} | " + " | ".join(f"{v:.3f}" for v in vals[:-1])
                     + f" | {100 * vals[-1]:.0f} % |" + extra)
        if with_paper and chain in PAPER_TABLE_II:
            ref = PAPER_TABLE_II[chain]
            lines.append("| *paper* | " + " | ".join(f"*{v:.3f}*" for v in ref[:-1]) + f" | *{100 * ref[-1]:.0f} %* |"
                         + (" | |" if limited else ""))
    if limited:
        lines += ["", item_table_markdown(summary)]
    return "\n".join(lines) + "\n"


def item_table_markdown(summary):
    """Markdown: per chain and household kind, fits and the medians of IOU, limit and IOU / limit.

    Without household kinds, one row per chain.
    """
    lines = ["| chain | kind | fits | IOU M | Limit M | IOU/Limit M |", "|---|---|---|---|---|---|"]
    for chain, entry in summary["chains"].items():
        groups = entry.get("by_item") or {"all": {**entry}}
        for item, e in groups.items():
            lines.append(f"| {_chain_label(chain)} | {item} | {e['fits']} | {e['iou']['median']:.3f} | "
                         f"{e['iou_limit']['median']:.3f} | {e['iou_over_limit']['median']:.3f} |")
    return "\n".join(lines)


def paper_comparison(summary):
    """Markdown: medians of each chain next to the paper's Table II, with the IOU difference.

    Chains the paper did not run get an empty paper column.
    """
    lines = ["| chain | IOU M (paper) | ΔIOU | R-IOU M (paper) | R-IOU-M M (paper) | time M [s] (paper) | σ (paper) |",
             "|---|---|---|---|---|---|---|"]
    for chain, e in summary["chains"].items():
        ref = PAPER_TABLE_II.get(chain)
        def cell(ours, k, fmt="{:.3f}"):
            return fmt.format(ours) + ("" if ref is None else " (" + fmt.format(ref[k]) + ")")
        delta = "" if ref is None else f"{e['iou']['median'] - ref[0]:+.3f}"
        lines.append(f"| {_chain_label(chain)} | {cell(e['iou']['median'], 0)} | {delta} | "
                     f"{cell(e['r_iou']['median'], 3)} | {cell(e['r_iou_m']['median'], 6)} | "
                     f"{cell(e['time_s']['median'], 9)} | "
                     f"{100 * e['success_rate']:.0f} %" + ("" if ref is None else f" ({100 * ref[12]:.0f} %)") + " |")
    return "\n".join(lines) + "\n"


def table_latex(summary):
    """Table II layout as a LaTeX ``table*`` (booktabs), values after the last stage."""
    lines = [
        r"\begin{table*}[]",
        r"\centering",
        rf"\caption{{Permutation experiment on scene \texttt{{{summary['scene']}}}: {summary['trials']} trials, "
        r"values after the last stage. M: median, A: average, Std: standard deviation.}",
        r"\begin{tabular}{l|ccc|ccc|ccc|ccc|c}",
        r"\toprule",
        r"&\multicolumn{3}{c|}{IOU}&\multicolumn{3}{c|}{R-IOU}&\multicolumn{3}{c|}{R-IOU-M}"
        r"&\multicolumn{3}{c|}{Time [s]}&$\sigma$\\",
        r"\texttt{Stages} &M&A&Std&M&A&Std&M&A&Std&M&A&Std \\",
        r"\midrule",
    ]
    limited = _limited(summary)
    if limited:  # medians of the representation limit and of IOU / limit after the rate
        lines[3] = lines[3].replace("|c}", "|c|cc}")
        lines[5] = lines[5].replace(r"&$\sigma$\\", r"&$\sigma$&Limit&IOU/Limit\\")
        lines[6] = lines[6].replace(r"&M&A&Std \\", r"&M&A&Std &&M&M\\")
    for chain, entry in summary["chains"].items():
        vals = _row_values(entry)
        cells = "&".join(f"{v:.3f}" for v in vals[:-1])
        extra = f"&{entry['iou_limit']['median']:.3f}&{entry['iou_over_limit']['median']:.3f}" if limited else ""
        lines.append(rf"\texttt{{{_chain_label(chain, tex=True)}}}&{cells}&${100 * vals[-1]:.0f}\,\%${extra}\\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table*}"]
    return "\n".join(lines) + "\n"


def screen_summary(summary):
    """A compact one-screen text table: medians, success rate and errors per chain."""
    lines = [f"scene {summary['scene']}: {summary['trials']} trials (seed {summary['seed']}, "
             f"{summary['resampled']} re-sampled)",
             f"{'chain':<14}{'IOU':>7}{'R-IOU':>8}{'R-IOU-M':>9}{'time ms':>9}{'success':>9}{'errors':>8}"
             + (f"{'limit':>7}{'IOU/lim':>9}" if _limited(summary) else "")]
    for chain, e in summary["chains"].items():
        lines.append(f"{chain:<14}{e['iou']['median']:>7.3f}{e['r_iou']['median']:>8.3f}"
                     f"{e['r_iou_m']['median']:>9.3f}{1000 * e['time_s']['median']:>9.1f}"
                     f"{100 * e['success_rate']:>8.0f}%{e['errors']:>8d}"
                     + (f"{e['iou_limit']['median']:>7.3f}{e['iou_over_limit']['median']:>9.3f}"
                        if _limited(summary) else ""))
    lines.append("(medians; full table with means and std in table.md)")
    return "\n".join(lines)


def best_chain(summary):
    """The most reliable chain: highest success rate, then highest median 3D IoU, then fastest."""
    def key(chain):
        e = summary["chains"][chain]
        return (e["success_rate"], e["iou"]["median"], -e["time_s"]["median"])
    return max(summary["chains"], key=key)


def violin_figure(records, chain, path):
    """Figure 4: distributions of IOU, R-IOU and R-IOU-M after each stage of ``chain``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in records if r["chain"] == chain and r["stages"]]
    stage_names = chain.split("-")
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, metric in zip(axes, ("iou", "r_iou", "r_iou_m")):
        data = []
        for k in range(len(stage_names)):
            data.append([r["stages"][k][metric] for r in rows if len(r["stages"]) > k])
        positions = [k for k, d in enumerate(data) if d]
        if positions:
            parts = ax.violinplot([data[k] for k in positions], positions=positions, showmedians=True,
                                  widths=0.8)
            for body in parts["bodies"]:
                body.set_alpha(0.5)
        ax.set_xticks(range(len(stage_names)), stage_names)
        ax.set_xlabel("after stage")
        ax.set_title(METRIC_LABELS[metric])
        ax.set_ylim(0, 1)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"Metric distributions after each stage of {_chain_label(chain)} ({len(rows)} fits)")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def example_figure(record, cameras, path):
    """Figure 5: cameras, ground truth and the estimate after each stage of one trial.

    Parameters
    ----------
    record : dict
        One ``trials.jsonl`` record with a superquadric ground truth.
    cameras : list of sqfit.Camera
        The trial's true cameras.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sqfit import Superquadric
    from sqfit.geometry.superquadric import to_mesh

    gt = Superquadric.from_vector(record["gt"]["params"])
    stages = [s for s in record["stages"] if s.get("params") is not None]
    n = 1 + len(stages)
    fig = plt.figure(figsize=(3.4 * n, 3.8))
    gt_mesh = to_mesh(gt, 12)

    def draw(ax, mesh, color, alpha):
        ax.plot_trisurf(*mesh.vertices.T, triangles=mesh.faces, color=color, alpha=alpha, linewidth=0.1,
                        edgecolor=color)

    def frame(ax, centre, radius):
        for k, set_lim in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
            set_lim(centre[k] - radius, centre[k] + radius)
        ax.set_box_aspect((1, 1, 1))
        ax.tick_params(labelsize=6)

    ax = fig.add_subplot(1, n, 1, projection="3d")
    draw(ax, gt_mesh, "tab:green", 0.35)
    if stages:
        draw(ax, to_mesh(Superquadric.from_vector(stages[-1]["params"]), 12), "tab:red", 0.35)
    for cam in cameras:
        c, R = cam.center, cam.rotation
        for axis, color in zip(R.T, ("r", "g", "b")):
            ax.plot(*np.stack([c, c + 1.5 * axis]).T, color=color, linewidth=2)
    centres = np.array([cam.center for cam in cameras] + [gt.position])
    frame(ax, centres.mean(axis=0), np.ptp(centres, axis=0).max() / 2 + 1.0)
    ax.set_title("overview: cameras (RGB = xyz),\nground truth (green), final (red)", fontsize=8)

    radius = 1.3 * max(gt.size)
    for k, stage in enumerate(stages):
        ax = fig.add_subplot(1, n, k + 2, projection="3d")
        draw(ax, gt_mesh, "tab:green", 0.25)
        draw(ax, to_mesh(Superquadric.from_vector(stage["params"]), 12), "tab:red", 0.4)
        frame(ax, np.asarray(gt.position), radius)
        ax.set_title(f"after stage {stage['name']}\nIOU {stage['iou']:.2f}  R-IOU {stage['r_iou']:.2f}",
                     fontsize=8)
    fig.suptitle(f"trial {record['trial']}, chain {_chain_label(record['chain'])}")
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    fig.savefig(path, dpi=130)
    plt.close(fig)
