"""Odometry drift of a sequence scene's trajectory over many seeded draws (no rendering).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/sequence_drift.py [scenes/sequence.toml] [--draws 500]

Prints the RMS rotation and position error after k steps next to the random-walk prediction
sqrt(3 k) x the per-axis step noise (README, "Image sequences").
"""

import argparse

import numpy as np

from sqsim.world.odometry import integrate_odometry
from sqsim.world.scene import load_scene
from sqsim.reports.sequence import drift
from sqsim.world.trajectory import sequence_poses


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", nargs="?", default="scenes/sequence.toml")
    parser.add_argument("--draws", type=int, default=500)
    args = parser.parse_args()
    s = load_scene(args.scene)
    _, true = sequence_poses(s.trajectory)
    rot, trans = s.noise.odometry_rotation_deg, s.noise.odometry_translation_m
    T, R = [], []
    for seed in range(args.draws):
        t, r = drift(true, integrate_odometry(true, rot, trans, seed))
        T.append(t)
        R.append(r)
    T, R = np.array(T), np.array(R)
    n = len(true) - 1
    print(f"{args.scene}: {args.draws} draws, step noise {rot} deg / {trans} m per axis")
    print("k    rms rotation [deg]  sqrt(3k)*s_r   rms position [m]  sqrt(3k)*s_t")
    for k in sorted({1, n // 4, n // 2, 3 * n // 4, n}):
        print(f"{k:3d}  {np.sqrt((R[:, k] ** 2).mean()):18.2f}  {np.sqrt(3 * k) * rot:12.2f}"
              f"   {np.sqrt((T[:, k] ** 2).mean()):16.3f}  {np.sqrt(3 * k) * trans:12.3f}")


if __name__ == "__main__":
    main()
