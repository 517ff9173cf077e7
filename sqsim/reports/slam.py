"""Reports of ``sqsim slam``: the summary over sequences, its Markdown table, the top-down figure.

``summary.json`` (the stable interface)::

    {"scene": "sequence", "seed": 0, "sequences": [0, 1, ...], "options": {...},
     "alignment": "none (every method starts at the known first pose); ate_se3_m: SE(3) Umeyama",
     "methods": {"graph": {"ate_m": {"median": .., "mean": .., "per_sequence": [..]},
                           "ate_se3_m": {..}, "rpe_m": {..}, "rpe_deg": {..},
                           "ate_change_vs_odometry": {..},   # (ATE - ATE_odometry) / ATE_odometry
                           "iou": {"median": .., "mean": .., "objects": n},  # over every object of every sequence
                           "iou_median_per_sequence": [..],
                           "cpu_seconds": {..}, "seconds": {..},
                           "frame_cpu_ms_median": {..},       # iSAM2 only
                           "failed": k, "missing_objects": k, "skipped": {"NNNNNN": {id: reason}},
                           "off_odometry": k}},  # runs whose estimate disagrees with the odometry:
                                                  # SlamResult.odometry_chi2 > batch_odometry_chi2
     "warnings": {"NNNNNN": [...]}}
"""

from __future__ import annotations

import numpy as np

from .figures import finish_topdown

__all__ = ["summarize", "table_markdown", "plot_topdown", "ALIGNMENT"]

ALIGNMENT = ("ate_m: none (every method starts at the known first pose, which the graph's prior fixes); "
             "ate_se3_m: SE(3) Umeyama alignment (evo)")

LABELS = {"odometry": "odometry", "fixed": "fixed (per-object fits on odometry poses)",
          "quadric": "quadric (QuadricSLAM, boxes)", "graph": "graph (superquadrics, batch LM)",
          "graph-isam2": "graph-isam2 (superquadrics, iSAM2)"}


def _stats(values):
    values = [v for v in values if v is not None]
    if not values:
        return {"median": None, "mean": None, "per_sequence": []}
    return {"median": float(np.median(values)), "mean": float(np.mean(values)), "per_sequence": values}


def summarize(records, methods, name, seed, options):
    """The ``summary.json`` content from the per-sequence records (module docstring)."""
    from sqfit.graph import GraphOptions

    records = sorted(records, key=lambda r: r["index"])
    chi2_limit = GraphOptions.coerce(options).batch_odometry_chi2
    out = {"scene": name, "seed": seed, "sequences": [r["index"] for r in records], "options": options,
           "alignment": ALIGNMENT, "methods": {},
           "observations": [r["observations"] for r in records],
           "border_views": [r.get("border_views", 0) for r in records],
           "warnings": {f"{r['index']:06d}": r["warnings"] for r in records if r["warnings"]}}
    odometry_ate = [r["methods"]["odometry"]["ate_m"] if "odometry" in r["methods"] else None for r in records]
    for m in methods:
        rows = [r["methods"][m] for r in records]
        ious = [v for row in rows for v in row["iou"].values()]
        s = {key: _stats([row[key] for row in rows]) for key in ("ate_m", "ate_se3_m", "rpe_m", "rpe_deg",
                                                                 "seconds", "cpu_seconds")}
        s["ate_change_vs_odometry"] = _stats([row["ate_m"] / o - 1.0 if o else None
                                              for row, o in zip(rows, odometry_ate)])
        s["iou"] = {"median": float(np.median(ious)) if ious else None,
                    "mean": float(np.mean(ious)) if ious else None, "objects": len(ious)}
        s["iou_median_per_sequence"] = [row["iou_median"] for row in rows]
        if any(row["frame_cpu_ms_median"] is not None for row in rows):
            s["frame_cpu_ms_median"] = _stats([row["frame_cpu_ms_median"] for row in rows])
            s["frame_ms_median"] = _stats([row["frame_ms_median"] for row in rows])
        s["failed"] = sum(row["status"] != "ok" for row in rows)
        # runs whose estimate disagrees with the odometry (sqfit SlamResult.odometry_chi2; flagged by a warning)
        s["off_odometry"] = sum(row.get("odometry_chi2") is not None and row["odometry_chi2"] > chi2_limit
                                for row in rows)
        s["missing_objects"] = sum(len(row["missing"]) for row in rows)
        s["skipped"] = {f"{r['index']:06d}": row["skipped"] for r, row in zip(records, rows) if row["skipped"]}
        out["methods"][m] = s
    return out


def _f(v, spec=".3f"):
    return "–" if v is None else format(v, spec)


def table_markdown(summary):
    """Markdown table of a summary: one row per method."""
    n = len(summary["sequences"])
    lines = [f"{summary['scene']}, seed {summary['seed']}, {n} sequence(s); ATE/RPE: evo, alignment: "
             f"{summary['alignment']}. Medians over sequences (IoU: over all objects of all sequences).", "",
             "| method | ATE [m] | ATE vs odometry | ATE SE(3)-aligned [m] | RPE [m / deg] | object IoU median "
             "(mean) | CPU [s] | wall [s] | iSAM2 update, CPU [ms] | failed / off the odometry / missing objects |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for m, s in summary["methods"].items():
        change = s["ate_change_vs_odometry"]["median"]
        iou = s["iou"]
        frame = s.get("frame_cpu_ms_median", {}).get("median")
        lines.append(
            f"| {LABELS.get(m, m)} | {_f(s['ate_m']['median'])} | "
            f"{'–' if change is None else format(100 * change, '+.0f') + ' %'} | {_f(s['ate_se3_m']['median'])} | "
            f"{_f(s['rpe_m']['median'], '.4f')} / {_f(s['rpe_deg']['median'], '.2f')} | "
            f"{_f(iou['median'])} ({_f(iou['mean'])}) | {_f(s['cpu_seconds']['median'], '.2f')} | "
            f"{_f(s['seconds']['median'], '.2f')} | {_f(frame, '.0f')} | {s['failed']} / {s['off_odometry']} / "
            f"{s['missing_objects']} |")
    if summary["warnings"]:
        lines += ["", "Warnings (first 3 per sequence; all in summary.json):"]
        for k, ws in summary["warnings"].items():
            lines += [f"- {k}: {w}" for w in ws[:3]]
    return "\n".join(lines) + "\n"


#: Trajectory styles of the figure: method -> (colour, line style).
STYLES = {"true": ("black", "-"), "odometry": ("tab:red", "--"), "fixed": ("tab:gray", ":"),
          "quadric": ("tab:orange", "-."), "graph": ("tab:blue", "-"), "graph-isam2": ("tab:green", "-")}


def plot_topdown(record, path):
    """Top-down figure of one sequence record: trajectories of the true path, the odometry and every
    method that moves the poses, true object footprints (filled) and fitted ones (outlines).

    Parameters
    ----------
    record : dict
        From :func:`sqsim.runs.slam.evaluate_sequence`.
    path : str or os.PathLike
        PNG file.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sqfit.geometry.superquadric import Superquadric, to_mesh

    fig, ax = plt.subplots(figsize=(7.5, 8.2))
    for oid, t in record["true_objects"].items():
        if t["footprint"] is not None:
            xy = np.asarray(t["footprint"])
            ax.fill(xy[:, 0], xy[:, 1], color="0.75", lw=0)
            ax.text(*xy.mean(axis=0), oid, ha="center", va="center", fontsize=8)
    trajectories = {"true": record["true_poses"], "odometry": record["odometry_poses"]}
    trajectories.update({m: r["poses"] for m, r in record["methods"].items() if m not in ("odometry", "fixed")})
    for name, poses in trajectories.items():
        colour, style = STYLES.get(name, ("tab:purple", "-"))
        xy = np.asarray(poses)[:, :2, 3]
        ate = record["methods"].get(name, {}).get("ate_m")
        label = name if ate is None or name == "true" else f"{name} (ATE {ate:.3f} m)"
        ax.plot(xy[:, 0], xy[:, 1], style, color=colour, lw=1.3, label=label)
    for m, r in record["methods"].items():
        colour, style = STYLES.get(m, ("tab:purple", "-"))
        for params in r["objects"].values():
            xy = footprint_hull(np.asarray(to_mesh(Superquadric.from_vector(params), 10).vertices)[:, :2])
            ax.fill(xy[:, 0], xy[:, 1], fill=False, edgecolor=colour, ls=style, lw=1.0)
    ax.plot(*np.asarray(record["true_poses"])[0, :2, 3], "o", color="black", ms=5)
    # the view: the true scene and the odometry, with a margin (a diverged fit may be 100 m long)
    known = [np.asarray(record["true_poses"])[:, :2, 3], np.asarray(record["odometry_poses"])[:, :2, 3]]
    known += [np.asarray(t["footprint"]) for t in record["true_objects"].values() if t["footprint"] is not None]
    lo, hi = np.min([k.min(axis=0) for k in known], axis=0), np.max([k.max(axis=0) for k in known], axis=0)
    margin = 0.15 * float(np.max(hi - lo)) + 0.5
    ax.set_xlim(lo[0] - margin, hi[0] + margin)
    ax.set_ylim(lo[1] - margin, hi[1] + margin)
    ious = {m: r["iou_median"] for m, r in record["methods"].items() if r["iou_median"] is not None}
    ax.set_title(f"{record['name']}: {record['frames']} frames, {len(record['true_objects'])} objects "
                 "(grey: true; outlines: fitted)\nmedian object IoU: "
                 + ", ".join(f"{m} {v:.2f}" for m, v in ious.items()), fontsize=9)
    finish_topdown(fig, ax, path, 100)


def footprint_hull(xy):
    """Convex hull of a footprint: ``xy`` (n, 2) float -> its hull's vertices (k, 2), counter-clockwise."""
    from scipy.spatial import ConvexHull

    return xy[ConvexHull(xy).vertices]
