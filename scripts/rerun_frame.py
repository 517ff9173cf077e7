"""Draw one frame of a sqkit rerun recording (``.rrd``) as a PNG, from the recording's contents.

The rerun viewer cannot run headless on a machine without a GPU or display server (``rerun
--headless`` panics with "Failed to get render context" on Mesa llvmpipe), so this script reads
the recording back with rerun's own reader (``rerun.chunk.RrdReader``) and draws with matplotlib
what the viewer shows for one trial at one point of the ``stage`` timeline: the cameras, the
ground-truth meshes, the estimates after that stage, and each camera's instance mask with the
estimates' silhouettes. It is not a screenshot of the viewer.

    .venv/bin/python scripts/rerun_frame.py fits.rrd -o frame.png [--trial 000000] [--stage -1]
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np


def read_recording(path):
    """``{entity: [(stage or None, {component: value})]}`` of a recording (first row per chunk row)."""
    from rerun.chunk import RrdReader

    rows = defaultdict(list)
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch().to_pydict()
        stages = batch.get("stage", [None] * chunk.num_rows)
        for r in range(chunk.num_rows):
            values = {k: v[r] for k, v in batch.items()
                      if k not in ("rerun.controls.RowId", "log_time", "stage") and v[r] is not None}
            rows[chunk.entity_path].append((stages[r], values))
    return rows


def latest(rows, stage):
    """The latest-at value of an entity at ``stage`` (static rows count as always present)."""
    best, best_stage = None, None
    for s, values in rows:
        if s is None or (s <= stage and (best_stage is None or s >= best_stage)):
            if s is not None:
                best_stage = s
            best = {**(best or {}), **values} if s is None else values
    return best


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("recording", help="a .rrd written by --rerun")
    parser.add_argument("-o", "--output", required=True, help="PNG to write")
    parser.add_argument("--trial", default=None, help="trial name (default: the first)")
    parser.add_argument("--stage", type=int, default=-1, help="one stage index (default: one panel per stage)")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_recording(args.recording)
    trials = sorted({e.split("/")[2] for e in rows if e.startswith("/trials/")})
    if not trials:
        raise SystemExit(f"{args.recording}: no trials recorded")
    trial = args.trial or trials[0]
    if trial not in trials:
        raise SystemExit(f"{args.recording}: no trial {trial!r}; recorded: {', '.join(trials)}")
    root = f"/trials/{trial}"
    stage = args.stage if args.stage >= 0 else 10**9
    views = sorted(e for e in rows if e.startswith(f"{root}/cameras/view_") and e.count("/") == 4)
    fits = sorted(e for e in rows if e.startswith(f"{root}/fits/"))
    truths = sorted(e for e in rows if e.startswith(f"{root}/ground_truth/"))

    n_stages = 1 + max((s for e in fits for s, _ in rows[e] if s is not None), default=0)
    shown = range(n_stages) if args.stage < 0 else [args.stage]
    cols = max(len(shown), len(views))
    fig = plt.figure(figsize=(3.6 * cols, 7.2))
    colors = plt.cm.tab10.colors
    chains = sorted({e.split("/")[4] for e in fits})
    for col, stage in enumerate(shown):
        ax = fig.add_subplot(2, cols, col + 1, projection="3d")
        for e in truths:
            v = latest(rows[e], stage)
            if v and "Mesh3D:vertex_positions" in v:
                p, f = np.asarray(v["Mesh3D:vertex_positions"]), np.asarray(v["Mesh3D:triangle_indices"])
                ax.plot_trisurf(p[:, 0], p[:, 1], p[:, 2], triangles=f, color=(0.2, 0.8, 0.35, 0.35), linewidth=0)
        names = {}
        for e in fits:
            v = latest(rows[e], stage)
            if v and "Mesh3D:vertex_positions" in v:
                chain = e.split("/")[4]
                p, f = np.asarray(v["Mesh3D:vertex_positions"]), np.asarray(v["Mesh3D:triangle_indices"])
                ax.plot_trisurf(p[:, 0], p[:, 1], p[:, 2], triangles=f,
                                color=colors[chains.index(chain) % 10] + (0.45,), linewidth=0)
                names[chain] = (v.get("stage_name") or ["?"])[0]
        for e in views:
            v = latest(rows[e], stage)
            t = np.asarray(v["Transform3D:translation"][0])
            R = np.asarray(v["Transform3D:mat3x3"][0]).reshape(3, 3).T  # stored column-major
            w, h = v["Pinhole:resolution"][0]
            K = np.asarray(v["Pinhole:image_from_camera"][0]).reshape(3, 3).T
            corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float)
            world = (np.c_[(corners - K[:2, 2]) / np.diag(K)[:2], np.ones(4)] * 1.5) @ R.T + t
            for c in world:
                ax.plot(*np.c_[t, c], color="k", lw=0.6)
            ax.plot(*np.r_[world, world[:1]].T, color="k", lw=0.6)
        ax.set_box_aspect((1, 1, 0.6))
        ax.tick_params(labelsize=6)
        ax.set_title(f"stage {stage}: " + ", ".join(f"{c} after {names.get(c, '-')}" for c in chains), fontsize=8)
    for k, e in enumerate(views):
        sub = fig.add_subplot(2, cols, cols + k + 1)
        v = latest(rows[e], 0)
        w, h = (int(x) for x in v["Pinhole:resolution"][0])
        mask = latest(rows.get(f"{e}/mask", []), 0)
        if mask:
            buffer = np.asarray(mask["SegmentationImage:buffer"][0], dtype=np.uint8)
            dtype = {1: np.uint8, 2: np.uint16, 4: np.uint32}[len(buffer) // (w * h)]
            sub.imshow(np.frombuffer(buffer.tobytes(), dtype).reshape(h, w) > 0, cmap="Greys", vmin=0, vmax=2.5)
        for o in sorted(x for x in rows if x.startswith(f"{e}/fits/")):
            for stage in shown:
                line = latest(rows[o], stage)
                if line and "LineStrips2D:strips" in line:
                    s = np.asarray(line["LineStrips2D:strips"][0])
                    alpha = 0.35 + 0.65 * (stage + 1) / len(shown)
                    sub.plot(s[:, 0], s[:, 1], color=colors[chains.index(o.split("/")[6]) % 10], lw=1.0, alpha=alpha)
        sub.set_xlim(0, w)
        sub.set_ylim(h, 0)
        sub.set_title(f"{e.rsplit('/', 1)[1]}: mask, silhouette after each stage", fontsize=8)
        sub.set_xticks([])
        sub.set_yticks([])
    fig.suptitle(f"trial {trial} of {args.recording.rsplit('/', 1)[-1]}: ground truth (green), estimates; "
                 "drawn from the recording's contents (not a viewer screenshot)", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
