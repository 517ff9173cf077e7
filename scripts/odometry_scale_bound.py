"""The ATE the odometry's scale error alone gives on a sequence scene, over many seeded draws (no rendering).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/odometry_scale_bound.py [scenes/sequence-eval.toml] [--draws 2000]

Silhouettes are scale-free: scaling every camera position, landmark position and landmark size about
the first camera leaves every silhouette unchanged, so a graph of odometry and silhouettes takes its
scale from the odometry alone. A method that got everything but the scale right would score the
true trajectory scaled by the odometry's own scale error (``sqfit.graph.testing.odometry_scale_rmse``:
the least-squares factor of the measured steps' translations along the true ones). This script draws
the scene's odometry noise ``--draws`` times on its trajectory and prints that ATE's median, 90th
percentile and the fraction of draws above ``--target`` metres (issue 23 asks for 0.015 m on every
sequence, without alignment).
"""

import argparse

import numpy as np

from sqfit.graph.testing import odometry_scale_rmse
from sqsim.world.odometry import integrate_odometry
from sqsim.world.scene import load_scene
from sqsim.world.trajectory import sequence_poses


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", nargs="?", default="scenes/sequence-eval.toml")
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--target", type=float, default=0.015)
    args = parser.parse_args()
    s = load_scene(args.scene)
    _, true = sequence_poses(s.trajectory)
    rot, trans = s.noise.odometry_rotation_deg, s.noise.odometry_translation_m
    ate = np.array([odometry_scale_rmse(integrate_odometry(true, rot, trans, seed), true) for seed in range(args.draws)])
    print(f"{args.scene}: {len(true)} frames, step noise {rot} deg / {trans} m per axis, {args.draws} draws: ATE of the "
          f"odometry's scale median {np.median(ate):.4f} m, 90th percentile {np.percentile(ate, 90):.4f} m, "
          f"above {args.target} m in {np.mean(ate > args.target):.0%} of the draws")


if __name__ == "__main__":
    main()
