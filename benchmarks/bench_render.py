"""Rendering throughput of one process: 640 x 480 instance masks per second.

Samples observable trials of a scene (default: scenes/paper.toml, 3 views each), then times
``Renderer.render(objects, cameras)`` alone (the number the README quotes, target >= 150
masks/s per process) and the whole ``simulate_trial`` (sampling, meshing, re-sampling,
rendering, noise) for reference; ``bench_trial.py`` times whole trials including writing, in
wall-clock and CPU time.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_render.py [--trials 100] [--renderer osmesa]

A sequence scene (``trajectory.kind = "orbit"`` or ``"waypoints"``) is timed per frame: every frame
of ``--trials`` sequences rendered at once (``Renderer.render(objects, cameras of all frames)``),
and the whole ``simulate_sequence`` (layout, re-draws, rendering, visibility, odometry):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_render.py --scene scenes/sequence.toml --trials 5
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from _common import scene_parser  # noqa: E402



def main():
    parser = scene_parser(__doc__, "timing repetitions (best is reported)")
    args = parser.parse_args()

    from sqsim.imaging.render import get_renderer
    from sqsim.world.scene import load_scene
    from sqsim.imaging.trial import sample_trial, simulate_trial

    scene = load_scene(args.scene)
    if args.renderer:
        scene = scene.with_overrides({"masks.renderer": args.renderer})
    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    k = scene.intrinsics
    if scene.trajectory.kind != "circle":
        return bench_sequences(scene, renderer, args)
    trials = [sample_trial(scene, i, renderer) for i in range(args.trials)]
    n_masks = sum(len(cams) for _, cams, _, _ in trials)
    best = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        for objects, cams, _, _ in trials:
            renderer.render(objects, cams)
        best = min(best, time.perf_counter() - t0)
    t0 = time.perf_counter()
    for i in range(args.trials):
        simulate_trial(scene, i, renderer)
    full = time.perf_counter() - t0
    print(f"renderer={scene.masks.renderer}  image={k.width}x{k.height}  trials={args.trials}  "
          f"masks={n_masks}")
    print(f"render only:         {n_masks / best:8.1f} masks/s  ({1e3 * best / n_masks:.2f} ms/mask)")
    print(f"simulate_trial (all): {n_masks / full:8.1f} masks/s  ({1e3 * full / args.trials:.1f} ms/trial, "
          "incl. sampling, meshing, re-sampling)")


def bench_sequences(scene, renderer, args):
    import sqfit
    from sqsim.imaging.sequence import sample_sequence, simulate_sequence

    k = scene.intrinsics
    drawn = [sample_sequence(scene, index=i, renderer=renderer) for i in range(args.trials)]
    cameras = [[sqfit.Camera(k, T) for T in poses] for _, _, poses, _, _, _ in drawn]
    n_frames = sum(len(c) for c in cameras)
    best = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        for (objects, *_), cams in zip(drawn, cameras):
            renderer.render(objects, cams)
        best = min(best, time.perf_counter() - t0)
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(args.trials):
        simulate_sequence(scene, index=i, renderer=renderer)
    full, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"renderer={scene.masks.renderer}  image={k.width}x{k.height}  sequences={args.trials}  "
          f"frames={n_frames}  objects={scene.objects.count}")
    print(f"render only:              {n_frames / best:8.1f} frames/s  ({1e3 * best / n_frames:.2f} ms/frame)")
    print(f"simulate_sequence (all):  {n_frames / full:8.1f} frames/s  ({1e3 * full / n_frames:.2f} ms/frame wall, "
          f"{1e3 * cpu / n_frames:.2f} ms/frame CPU of this process; incl. layout, re-draws, visibility, odometry)")


if __name__ == "__main__":
    main()
