"""``sqsim demo``: sample a superquadric, project it into a circle of cameras, print a summary."""

from __future__ import annotations

import numpy as np

import sqfit
from sqfit.views.observation import convex_hull
from sqfit.geometry.polygon import polygon_area
from sqfit.geometry.superquadric import sample_surface_uniform, volume


def add_arguments(parser):
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--views", type=int, default=3, help="number of cameras on the circle")


def run(args):
    if args.views < 1:
        raise ValueError(f"--views must be >= 1, got {args.views}")
    rng = np.random.default_rng(args.seed)
    sq = sqfit.Superquadric(rng.uniform(0.1, 5.0, 3), rng.uniform(0.1, 1.9, 2),
                            rng.uniform(-5, 5, 3), rng.uniform(-np.pi, np.pi, 3))
    intr = sqfit.Intrinsics(640, 480, 400.0, 300.0, 320.0, 240.0)
    points = sample_surface_uniform(sq, 5000, rng)
    print(f"superquadric  a={np.round(sq.size, 3)}  e={np.round(sq.shape, 3)}  "
          f"p={np.round(sq.position, 3)}  r={np.round(sq.rotation, 3)}  volume={volume(sq):.3f} m^3")
    for k, angle in enumerate(np.linspace(0, 2 * np.pi, args.views, endpoint=False)):
        eye = 10.0 * np.array([np.cos(angle), np.sin(angle), 0.0])
        cam = sqfit.Camera(intr, sqfit.look_at(eye, [0.0, 0.0, 0.0]))
        uv, depth = sqfit.project(cam, points)
        area = abs(polygon_area(convex_hull(uv)))
        inside = np.mean((uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480))
        print(f"view {k}: camera at {np.round(eye, 2)}  silhouette area {area:9.0f} px  "
              f"bbox u[{uv[:, 0].min():7.1f}, {uv[:, 0].max():7.1f}] v[{uv[:, 1].min():7.1f}, "
              f"{uv[:, 1].max():7.1f}]  depth {depth.min():.2f}-{depth.max():.2f} m  "
              f"in image {100 * inside:.0f}%")
    return 0
