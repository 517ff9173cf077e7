"""Where the batch graph's object IoU is lost, per object, on sequences of a sequence scene.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/graph_iou_breakdown.py --scene scenes/sequence-eval.toml \
        --seeds 0,1 --sequences 0,1,2 [--options JSON] [--json PATH]

Per object of each sequence, the 3D IoU against the truth of:

- ``graph``: the batch graph's object;
- ``g+scale``: the same after the least-squares scale of the graph's trajectory about its first
  camera (as ``scale_free_rmse``), applied to the objects too (positions about the first camera,
  sizes): what the scale error of the map alone costs;
- ``g+sim3``: the same after the least-squares similarity (Umeyama) of the trajectory to the truth;
- ``true-pose fit``: :func:`sqfit.fit` (the graph's ``init_chain``) on every frame that sees the
  object at the true poses: what the silhouettes allow with perfect poses;
- ``est-pose fit``: the same fit at the graph's poses, and that fit after the scale alignment.

With the views, the views whose mask touches the image border, the views with outline labelled
``instance`` (occluded), the object's mean silhouette fraction, its size and distance to frame 0.
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sqfit import graph  # noqa: E402
from sqfit.fitting import pipeline  # noqa: E402
from sqfit.geometry.superquadric import Superquadric, matrix_to_euler  # noqa: E402
from sqfit.graph.options import GraphOptions  # noqa: E402
from sqfit.graph.problem import observation_at  # noqa: E402
from sqfit.graph.testing import trajectory_scale  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402
from sqfit.views.visibility import INSTANCE  # noqa: E402


def _scale_about_first(poses, true_poses):
    """``(s, R, t)`` of :func:`sqfit.graph.testing.trajectory_scale` about the first camera centre."""
    s = trajectory_scale(poses, true_poses)
    return s, np.eye(3), (1.0 - s) * poses[0, :3, 3]


def _umeyama(poses, true_poses):
    """``(s, R, t)`` minimising ``sum |s R x + t - y|^2`` over the camera centres."""
    x, y = poses[:, :3, 3], true_poses[:, :3, 3]
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    U, d, Vt = np.linalg.svd(yc.T @ xc / len(x))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = float(np.trace(np.diag(d) @ S) / np.mean(np.sum(xc ** 2, 1)))
    return s, R, my - s * R @ mx


def _moved(sq, s, R, t):
    return Superquadric(np.asarray(sq.size) * s, sq.shape, s * R @ np.asarray(sq.position) + t,
                        matrix_to_euler(R @ sq.rotation_matrix))


def _fit(observations, frames, oid, poses, chain):
    res = pipeline.fit([observation_at(observations[f, oid], poses[f]) for f in frames], chain)
    return res.superquadric if res.ok and res.superquadric is not None else None


def _iou(sq, truth):
    return 0.0 if sq is None else float(iou_3d(sq, truth))


def breakdown(seq, options=None):
    """Per-object rows (module docstring) and the run's ATE / scale figures."""
    from sqfit.graph.testing import position_rmse

    opts = GraphOptions.coerce(options)
    result = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], options)["graph"]
    scale = _scale_about_first(result.poses, seq.true_poses)
    sim3 = _umeyama(result.poses, seq.true_poses)
    frames_of = {}
    for f, oid in seq.observations:
        frames_of.setdefault(oid, []).append(f)
    rows = []
    for oid, truth in seq.objects.items():
        frames = sorted(frames_of.get(oid, []))
        obs = [seq.observations[f, oid] for f in frames]
        est = result.objects.get(oid)
        true_fit = _fit(seq.observations, frames, oid, seq.true_poses, opts.init_chain) if len(frames) >= 2 else None
        est_fit = _fit(seq.observations, frames, oid, result.poses, opts.init_chain) if len(frames) >= 2 else None
        rows.append({
            "object": oid, "views": len(frames), "border": sum(o.touches_border for o in obs),
            "occluded": sum(bool(np.any(o.contour_labels == INSTANCE)) for o in obs),
            "silhouette_fraction": float(np.mean([o.silhouette_fraction for o in obs])) if obs else 0.0,
            "size": float(np.max(truth.size)),
            "distance": float(np.linalg.norm(np.asarray(truth.position) - seq.true_poses[0, :3, 3])),
            "graph": _iou(est, truth),
            "graph_scale": _iou(None if est is None else _moved(est, *scale), truth),
            "graph_sim3": _iou(None if est is None else _moved(est, *sim3), truth),
            "true_fit": _iou(true_fit, truth),
            "est_fit": _iou(est_fit, truth),
            "est_fit_scale": _iou(None if est_fit is None else _moved(est_fit, *scale), truth),
        })
    run = {"ate_m": position_rmse(result.poses, seq.true_poses), "scale": scale[0], "sim3_scale": sim3[0],
           "cpu_seconds": result.cpu_seconds, "warnings": [w for w in result.warnings if "re-initialised" in w]}
    return run, rows


COLUMNS = ("graph", "graph_scale", "graph_sim3", "true_fit", "est_fit", "est_fit_scale")


def main(argv=None):
    import sys

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
    from bench_graph import scene_sequence

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", action="append", required=True)
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--sequences", default="0")
    parser.add_argument("--options", default=None, help="GraphOptions fields as JSON; they override what "
                        "--scene-odometry-noise and --floor give")
    parser.add_argument("--scene-odometry-noise", action="store_true", help="the scene's odometry noise as the graph's "
                        "odometry sigmas (sqsim slam --scene-odometry-noise)")
    parser.add_argument("--floor", action="store_true", help="give the graph the floor (sqsim slam --floor)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    from sqsim.runs.slam import scene_graph_options

    given = json.loads(args.options) if args.options else {}
    everything = []
    for scene in args.scene:
        for seed in map(int, args.seeds.split(",")):
            for index in map(int, args.sequences.split(",")):
                seq = scene_sequence(scene, seed, index)
                run, rows = breakdown(seq, scene_graph_options(seq.scene, given, floor=args.floor,
                                                                  odometry_noise=args.scene_odometry_noise))
                name = f"{os.path.basename(scene)} {seed}/{index}"
                print(f"\n{name}: ATE {run['ate_m']:.4f} m, scale about frame 0 {run['scale']:.4f}, "
                      f"Sim(3) scale {run['sim3_scale']:.4f}, CPU {run['cpu_seconds']:.1f} s; {run['warnings']}")
                print(f"{'obj':>3s} {'views':>5s} {'bord':>4s} {'occl':>4s} {'silh':>5s} {'size':>5s} {'dist':>5s} "
                      + " ".join(f"{c:>13s}" for c in COLUMNS))
                for r in rows:
                    print(f"{r['object']:3d} {r['views']:5d} {r['border']:4d} {r['occluded']:4d} "
                          f"{r['silhouette_fraction']:5.2f} {r['size']:5.2f} {r['distance']:5.2f} "
                          + " ".join(f"{r[c]:13.3f}" for c in COLUMNS))
                med = {c: float(np.median([r[c] for r in rows])) for c in COLUMNS}
                print("median" + " " * 33 + " ".join(f"{med[c]:13.3f}" for c in COLUMNS))
                everything.append({"scene": scene, "seed": seed, "sequence": index, **run, "objects": rows})
    allrows = [r for s in everything for r in s["objects"]]
    print(f"\nall {len(allrows)} objects of {len(everything)} sequences: median / 10th percentile")
    for c in COLUMNS:
        v = np.array([r[c] for r in allrows])
        print(f"  {c:14s} {np.median(v):.3f} / {np.percentile(v, 10):.3f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(everything, fh, indent=1)


if __name__ == "__main__":
    main()
