"""Where do runs 1e-9 apart part? Issue 23's stability, traced on one sequence.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/graph_divergence.py frames --scene scenes/sequence-eval.toml \
        --seed 0 --sequence 2 --floor --scene-odometry-noise [--method graph-isam2] [--runs 2] [--shared-fits] \
        [--shapes 5,2]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/graph_divergence.py fits --scene scenes/sequence-eval.toml \
        --seed 0 --sequence 0 --floor --scene-odometry-noise [--eps 1e-11] [--most 40]

``frames``: the method runs ``--runs`` times with ``silhouette_sigma`` scaled by ``1 + k 1e-9`` (the
README's perturbation) and, after each frame, the largest difference between run 0 and run k of the
camera positions, the landmark positions and the landmark size/shape vectors (metres; the shape's
exponents unitless) is printed: the frame where they jump is where the runs part. ``--shared-fits``:
the runs share their landmark fits (the first run's :func:`sqfit.fit` of an object on a list of
frames is reused by the others for the same object and frames), so that only the graph's own
iterations can part them. ``--shapes``: each run's size/shape vector of these objects per frame.

``fits``: the batch's landmark fits (initial fits and re-fits) of the sequence are recorded and
each is fitted again with every camera centre moved by ``--eps`` metres (seeded, normal per axis);
per fit the largest change of a parameter (size, shape, position, rotation) and, where it exceeds
1e-6, the first stage whose snapshot differs by more than that and the fit's message.

Both replace public functions of :mod:`sqfit.graph` for the duration of the run
(``growth.landmark_fit``, ``refit.landmark_fit``, ``growth.Growth.update``): a diagnostic, not
something the graph offers.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import gtsam  # noqa: E402

from sqfit import graph  # noqa: E402
from sqfit.fitting import pipeline  # noqa: E402
from sqfit.geometry.camera import Camera  # noqa: E402
from sqfit.graph import growth, refit  # noqa: E402

def _patch(module, name, value):
    old = getattr(module, name)
    setattr(module, name, value)
    return old


def shared_fits():
    """Make every later :func:`landmark_fit` of the same object (its first mask's samples) on the
    same frames return the first one's result; returns the function that undoes it."""
    cache, original = {}, growth.landmark_fit

    def fit(obs, options, pose_noise_refit, where):
        views = obs.observations if hasattr(obs, "observations") else obs
        key = (where, len(views), hashlib.sha1(np.ascontiguousarray(views[0].samples).tobytes()).hexdigest())
        if key not in cache:
            cache[key] = original(obs, options, pose_noise_refit, where)
        return cache[key]

    _patch(growth, "landmark_fit", fit)
    _patch(refit, "landmark_fit", fit)
    return lambda: (_patch(growth, "landmark_fit", original), _patch(refit, "landmark_fit", original))


def run_frames(seq, options, method, runs, shared):
    """Per run, per frame: ``{(kind, index): vector}`` of the estimate after that frame."""
    snapshots, original = [], growth.Growth.update

    def update(self, estimate, n):
        snap = {}
        for key in estimate.keys():
            sym = gtsam.Symbol(key)
            kind, index = chr(sym.chr()), sym.index()
            if kind in "xl":
                snap[kind, index] = np.array(estimate.atPose3(key).translation())
            elif kind == "s":
                snap[kind, index] = np.array(estimate.atVector(key))
        snapshots[-1].append(snap)
        return original(self, estimate, n)

    undo = shared_fits() if shared else (lambda: None)
    growth.Growth.update = update
    try:
        sigma = graph.GraphOptions.coerce(options).silhouette_sigma
        for k in range(runs):
            snapshots.append([])
            given = {**options, "silhouette_sigma": sigma * (1.0 + k * 1e-9)} if k else options
            graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method], given)
    finally:
        growth.Growth.update = original
        undo()
    return snapshots


def print_frames(snapshots, shapes):
    for k in range(1, len(snapshots)):
        print(f"run 0 against run {k}: largest difference after each frame")
        print(f"{'frame':>5s} {'cameras [m]':>12s} {'landmarks [m]':>14s} {'size/shape':>11s}")
        for f, (a, b) in enumerate(zip(snapshots[0], snapshots[k])):
            common = set(a) & set(b)
            diff = {kind: max((float(np.abs(a[q] - b[q]).max()) for q in common if q[0] == kind), default=0.0)
                    for kind in "xls"}
            extra = sorted(set(a) ^ set(b))
            print(f"{f:5d} {diff['x']:12.2e} {diff['l']:14.2e} {diff['s']:11.2e}"
                  + (f"   variables in one run only: {extra}" if extra else ""))
    for oid in shapes:
        print(f"object {oid}: size/shape after each frame, per run")
        for f in range(len(snapshots[0])):
            cells = [np.round(run[f][("s", oid)], 3).tolist() if f < len(run) and ("s", oid) in run[f] else "-"
                     for run in snapshots]
            if any(c != "-" for c in cells):
                print(f"{f:5d} " + "  ".join(str(c) for c in cells))


def record_fits(seq, options):
    """The batch's landmark fits: ``[(observations, where)]`` in call order."""
    calls, original = [], growth.landmark_fit

    def fit(obs, options_, pose_noise_refit, where):
        calls.append((obs, options_, pose_noise_refit, where))
        return original(obs, options_, pose_noise_refit, where)

    _patch(growth, "landmark_fit", fit)
    _patch(refit, "landmark_fit", fit)
    try:
        graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], options)
    finally:
        _patch(growth, "landmark_fit", original)
        _patch(refit, "landmark_fit", original)
    return calls


def moved_views(obs, eps, rng):
    """The observations of ``obs`` with every camera centre moved by ``eps`` m (normal per axis)."""
    views = obs.observations if hasattr(obs, "observations") else obs
    out = []
    for o in views:
        pose = np.array(o.camera.pose)
        pose[:3, 3] += eps * rng.standard_normal(3)
        out.append(o.with_camera(Camera(o.camera.intrinsics, pose)))
    return out


def print_fits(calls, eps, most, seed=0):
    rng = np.random.default_rng(seed)
    moved = 0
    print(f"{'fit':>3s} {'views':>5s} {'where':>36s} {'largest change':>15s}  (parted at stage: message)")
    for j, (obs, options, pose_noise_refit, where) in enumerate(calls[:most or None]):
        fit_options = {"pose_noise_refit": bool(pose_noise_refit)}
        n_views = len(obs.observations if hasattr(obs, "observations") else obs)
        a = pipeline.fit(moved_views(obs, 0.0, rng), options.init_chain, options=fit_options)
        b = pipeline.fit(moved_views(obs, eps, rng), options.init_chain, options=fit_options)
        if a.superquadric is None or b.superquadric is None:
            print(f"{j:3d} {n_views:5d} {where[:36]:>36s} {'failed':>15s}  {a.status} / {b.status}")
            continue
        change = float(np.abs(a.superquadric.to_vector() - b.superquadric.to_vector()).max())
        note = ""
        if change > 1e-6:
            moved += 1
            stage = next((sa.name for sa, sb in zip(a.stages, b.stages) if sa.superquadric is not None
                          and sb.superquadric is not None
                          and np.abs(sa.superquadric.to_vector() - sb.superquadric.to_vector()).max() > 1e-6), "?")
            note = f"  ({stage}: {a.message[:120]})"
        print(f"{j:3d} {n_views:5d} {where[:36]:>36s} {change:15.2e}{note}")
    n = len(calls[:most or None])
    print(f"\n{moved} of {n} fits change by more than 1e-6 when the camera centres move by {eps:g} m")
    return moved, n


def main(argv=None):
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
    from bench_graph import scene_sequence
    from sqsim.runs.slam import scene_graph_options

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("frames", "fits"))
    parser.add_argument("--scene", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sequence", type=int, default=0)
    parser.add_argument("--options", default=None, help="GraphOptions fields as JSON; they override what "
                        "--scene-odometry-noise and --floor give")
    parser.add_argument("--scene-odometry-noise", action="store_true", help="the scene's odometry noise as the graph's "
                        "odometry sigmas (sqsim slam --scene-odometry-noise)")
    parser.add_argument("--floor", action="store_true", help="give the graph the floor (sqsim slam --floor)")
    parser.add_argument("--method", default="graph-isam2", choices=("graph", "graph-isam2"), help="frames: the method")
    parser.add_argument("--runs", type=int, default=2, help="frames: runs 1e-9 apart (>= 2)")
    parser.add_argument("--shared-fits", action="store_true", help="frames: the runs share their landmark fits")
    parser.add_argument("--shapes", default="", help="frames: objects whose size/shape to print per frame, e.g. 5,2")
    parser.add_argument("--eps", type=float, default=1e-11, help="fits: how far the camera centres move [m]")
    parser.add_argument("--most", type=int, default=0, help="fits: at most this many fits (0: all)")
    args = parser.parse_args(argv)
    if args.runs < 2:
        parser.error(f"--runs must be >= 2, got {args.runs}")
    if not args.eps >= 0:
        parser.error(f"--eps must be >= 0, got {args.eps}")
    shapes = [int(v) for v in args.shapes.split(",") if v.strip()]
    seq = scene_sequence(args.scene, args.seed, args.sequence)
    options = scene_graph_options(seq.scene, json.loads(args.options) if args.options else {}, floor=args.floor,
                                  odometry_noise=args.scene_odometry_noise)
    if args.mode == "frames":
        print_frames(run_frames(seq, options, args.method, args.runs, args.shared_fits), shapes)
    else:
        print_fits(record_fits(seq, graph.GraphOptions.coerce(options)), args.eps, args.most)


if __name__ == "__main__":
    main()
