"""What camera-rotation noise costs the estimator: 3G started at the truth, with and without the noise.

Usage::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/pose_noise_bound.py scenes/paper-noisy.toml \
        --trials 100 [--seed 0]

For each trial of the scene (rendered and corrupted as ``sqsim experiment`` does; superquadric
objects, the first object) it fits ``sqfit.fit(obs, "3G", initial=truth)`` on the noisy masks

- ``given cameras``: through the noisy cameras, as the fitter sees them (``scripts/truth_bound.py``'s bound);
- ``... at true position``: that fit's shape and orientation moved to the true position;
- ``... at true pose``: its shape alone, at the true position and orientation;
- ``true cameras``: through the cameras the masks were rendered from (the masks' noise alone), with
  pose corrections and without (``pose_sigma_deg = 0``),

and prints the median, 10th percentile and mean of the 3D IoU of each, and the position error of
the first (metres).
"""

from __future__ import annotations

import argparse
import os
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.metrics import IOU_GRID_CELLS, iou_3d  # noqa: E402


def main(argv=None):
    from sqsim.imaging.render import get_renderer
    from sqsim.imaging.trial import observations, simulate_trial
    from sqsim.world.scene import load_scene

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--trials", type=int, default=None, help="default: the scene's experiment.trials")
    parser.add_argument("--seed", type=int, default=None, help="default: the scene's experiment.seed")
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    if args.seed is not None:
        scene = replace(scene, experiment=replace(scene.experiment, seed=args.seed))
    trials = args.trials or scene.experiment.trials
    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    rows = {k: [] for k in ("given cameras", "... at true position", "... at true pose", "true cameras",
                            "true cameras, no pose corrections", "position error [m]")}
    for i in range(trials):
        sim = simulate_trial(scene, i, renderer)
        obj = sim.objects[0]
        truth = obj.superquadric
        if truth is None:
            continue
        obs = observations(sim, obj.id, scene)
        exact = observations(replace(sim, cameras=sim.true_cameras), obj.id, scene)

        def iou(sq):
            return iou_3d(sq, truth, IOU_GRID_CELLS) if sq is not None else 0.0

        sq = sqfit.fit(obs, "3G", initial=truth).superquadric
        rows["given cameras"].append(iou(sq))
        rows["... at true position"].append(iou(sqfit.Superquadric(sq.size, sq.shape, truth.position, sq.rotation)))
        rows["... at true pose"].append(iou(sqfit.Superquadric(sq.size, sq.shape, truth.position, truth.rotation)))
        rows["true cameras"].append(iou(sqfit.fit(exact, "3G", initial=truth).superquadric))
        rows["true cameras, no pose corrections"].append(
            iou(sqfit.fit(exact, "3G", initial=truth, options={"pose_sigma_deg": 0.0}).superquadric))
        rows["position error [m]"].append(float(np.linalg.norm(np.subtract(sq.position, truth.position))))
    print(f"# {args.scene}: {len(rows['given cameras'])} trials, seed {scene.experiment.seed}; 3G started at the truth")
    print("| fit | median | 10th pct | mean |")
    print("|---|---|---|---|")
    for name, values in rows.items():
        v = np.array(values)
        print(f"| {name} | {np.median(v):.3f} | {np.percentile(v, 10):.3f} | {v.mean():.3f} |")


if __name__ == "__main__":
    main()
