"""CPU milliseconds per object of the visual hull (stage ``HULL``): carving, EMS fit, whole chain.

Renders trials ``0 .. N-1`` of a scene (default ``scenes/household.toml``: one household object, four
elevated views) once, then times, per object and for each kernel choice (``--kernels``, default
``numba,numpy``: :mod:`sqfit.kernels.backend`), the carving (``sqfit.fitting.hull.object_hull``),
the EMS fit of its surface points (``sqfit.fitting.pointcloud.fit_points``) and a whole ``sqfit.fit``
of ``--chain`` (default ``hull``), each the fastest of ``--repeat`` runs on fresh ``Observation``
objects. CPU time (``time.process_time``), one process. Prints a table of medians and means, and
whether the kernel choices gave the same hulls and fits (they should: ``tests/test_hull_kernels.py``).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_hull.py [--trials 20] [--set objects.catalogue=[lamp]]
"""

from __future__ import annotations

import os
import time
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from _common import household_parser, rendered_objects  # noqa: E402


def _best(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t0)
    return 1e3 * best, out


def main(argv=None):
    parser = household_parser(__doc__, "runs per measurement (the fastest is kept)", trials=20)
    parser.add_argument("--chain", default="hull", help="the chain timed whole (default: hull)")
    parser.add_argument("--kernels", default="numba,numpy", help="kernel choices to compare")
    args = parser.parse_args(argv)

    import sqfit
    from sqfit.fitting.costs import ObservationSet
    from sqfit.fitting.hull import object_hull
    from sqfit.fitting.pointcloud import fit_points
    from sqfit.kernels import backend

    objects = rendered_objects(args)

    print(f"# {len(objects)} objects of {args.scene} {' '.join(args.overrides)}, CPU ms per object, "
          f"best of {args.repeat}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"| kernels | carving median / mean | EMS median / mean | `{args.chain}` median / mean |")
    print("|---|---|---|---|")
    results = {}
    for name in args.kernels.split(","):
        previous = backend.set_kernels(name)
        try:
            sqfit.fit(objects[0], args.chain)  # warm-up: imports, compiled kernels
            rows, hulls, fits = [], [], []
            for obs in objects:
                def fresh():
                    return ObservationSet([replace(o) for o in obs])
                carve_ms, hull = _best(lambda: object_hull(fresh()), args.repeat)
                points = hull.surface_points()
                ems_ms, fit = _best(lambda: fit_points(points), args.repeat) if len(points) >= 11 else (np.nan, None)
                chain_ms, result = _best(lambda: sqfit.fit([replace(o) for o in obs], args.chain), args.repeat)
                rows.append((carve_ms, ems_ms, chain_ms))
                hulls.append(hull.occupied)
                fits.append(None if result.superquadric is None else result.superquadric.to_vector())
            results[name] = (hulls, fits)
        finally:
            backend.set_kernels(previous)
        r = np.array(rows)
        cells = " | ".join(f"{np.nanmedian(c):.1f} / {np.nanmean(c):.1f}" for c in r.T)
        print(f"| {name} | {cells} |", flush=True)
    names = list(results)
    for other in names[1:]:
        (h0, f0), (h1, f1) = results[names[0]], results[other]
        same_hulls = sum(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(h0, h1))
        gaps = [np.max(np.abs(a - b)) for a, b in zip(f0, f1) if a is not None and b is not None]
        print(f"\n{names[0]} against {other}: the same hull on {same_hulls} of {len(h0)} objects; "
              f"largest parameter difference of the `{args.chain}` fits {max(gaps, default=0.0):.2g}")


if __name__ == "__main__":
    main()
