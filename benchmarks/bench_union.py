"""CPU milliseconds of stage 3U's union fit: one evaluation's parts, an evaluation, the union fit per object.

Renders trials ``0 .. N-1`` of a scene (default ``scenes/household.toml`` with ``--set
objects.catalogue=[lamp]``: one household object, four elevated views), fits each with chain ``whole``,
and on the opened masks 3U fits (``sqfit.fitting.least_volume.bulk_observations``) times, for each kernel
choice (``--kernels``, default ``numba,numpy``: :mod:`sqfit.kernels.backend`): the silhouettes with
their touching points, the vertices' velocities, the union's overlap with the contours and its
gradient's edge sums (compiled only), one whole evaluation (``sqfit.fitting.two_parts.union_gradient``),
each at 3U's first start, the fastest of ``--repeat`` runs of 50 calls, and ``fit_union`` from the first
start (mean per evaluation). CPU time (``time.process_time``), one process. Prints a table of medians
over the objects, and how far the two kernel choices' gradients are apart.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_union.py [--trials 6] [--set objects.catalogue=[chair]]
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from _common import household_parser, rendered_objects  # noqa: E402

CALLS = 50


def _per_call(fn, repeat):
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(CALLS):
            fn()
        best = min(best, (time.process_time() - t0) / CALLS)
    return 1e3 * best


def main(argv=None):
    parser = household_parser(__doc__, "runs of each measurement (the fastest is kept)", trials=6)
    parser.add_argument("--kernels", default="numba,numpy", help="kernel choices to compare")
    args = parser.parse_args(argv)
    args.overrides = args.overrides or ["objects.catalogue=[lamp]"]

    import sqfit
    from sqfit.fitting import two_parts
    from sqfit.fitting.costs import ObservationSet
    from sqfit.fitting.least_volume import bulk_observations
    from sqfit.geometry.silhouette import (E_RANGE, MAX_NEWTON, NEWTON_TOL, ZNEAR, batch_silhouettes,
                                           rotation_stack, vertex_velocities)
    from sqfit.kernels import backend

    cases = []
    for obs in rendered_objects(args):
        result = sqfit.fit(obs, "whole")
        if result.superquadric is None:
            continue
        bulk = bulk_observations(ObservationSet(obs)) or ObservationSet(obs)
        start = two_parts.l_starts(np.asarray(result.superquadric.to_vector(), dtype=np.float64))[0]
        cases.append((bulk, start))

    threads = os.environ.get("OPENBLAS_NUM_THREADS")
    print(f"# {len(cases)} objects of {args.scene} {' '.join(args.overrides)}, CPU ms per call (median over the "
          f"objects), best of {args.repeat} x {CALLS} calls, OPENBLAS_NUM_THREADS={threads}")
    print("| kernels | silhouettes | velocities | overlap | evaluation | `fit_union` per evaluation (evaluations) |")
    print("|---|---|---|---|---|---|")
    gradients = {}
    for name in args.kernels.split(","):
        previous = backend.set_kernels(name)
        try:
            rows, grads = [], []
            for bulk, X in cases:
                two_parts.union_gradient(X, bulk)  # warm-up: compiled kernels
                cams = (bulk.rotations, bulk.centers, bulk.intrinsics)
                R, dR = rotation_stack(X)
                sil, moving = backend.compiled("silhouettes"), backend.compiled("velocities")
                if sil is None:
                    def silhouettes():
                        return batch_silhouettes(X, *cams, two_parts.VERTICES, touching=True)

                    def velocities():
                        return vertex_velocities(X, unit, points, bulk.rotations, bulk.intrinsics)

                    polys, valid, _, unit, points = silhouettes()
                else:
                    def silhouettes():
                        return sil.touching_silhouettes(X, R, *cams, two_parts.VERTICES, NEWTON_TOL, MAX_NEWTON,
                                                        ZNEAR, *E_RANGE)

                    def velocities():
                        return moving.vertex_velocities(X, R, dR, unit, points, bulk.rotations, bulk.intrinsics,
                                                        *E_RANGE)

                    polys, valid, unit, points = silhouettes()
                row = [_per_call(silhouettes, args.repeat), _per_call(velocities, args.repeat),
                       _per_call(lambda: two_parts.union_overlap(X[None], bulk, (polys, valid)), args.repeat),
                       _per_call(lambda: two_parts.union_gradient(X, bulk), args.repeat)]
                t0 = time.process_time()
                nfev = two_parts.fit_union(X, bulk, two_parts.MU, 1.0)[3]
                row += [1e3 * (time.process_time() - t0) / max(nfev, 1), nfev]
                rows.append(row)
                grads.append(two_parts.union_gradient(X, bulk))
            gradients[name] = grads
        finally:
            backend.set_kernels(previous)
        r = np.median(np.array(rows), axis=0)
        print(f"| {name} | {r[0]:.3f} | {r[1]:.3f} | {r[2]:.3f} | {r[3]:.3f} | {r[4]:.3f} ({r[5]:.0f}) |", flush=True)
    names = list(gradients)
    for other in names[1:]:
        gaps = [max(np.abs(a[0] - b[0]).max(), np.abs(a[1] - b[1]).max())
                for a, b in zip(gradients[names[0]], gradients[other])]
        print(f"\n{names[0]} against {other}: largest difference of the IoUs and gradients "
              f"{max(gaps, default=0.0):.2g}")


if __name__ == "__main__":
    main()
