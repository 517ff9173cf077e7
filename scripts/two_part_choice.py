"""Which of its two parts stage 3U should keep, and whether the masks can say (household kinds).

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/two_part_choice.py [--scene scenes/household.toml] \
        [--kinds chair laptop monitor] [--trials 20] [--seed 0] [--records FILE]

Stage 3U (:mod:`sqfit.fitting.two_parts`) fits the union of two superquadrics to an object's opened masks
from its starts (:func:`~sqfit.fitting.two_parts.starts`), polishes without the volume term those that
ended near the lowest objective, keeps the
union that then matches the masks best (:func:`~sqfit.fitting.two_parts.polish`) and of it the larger part, or
the smaller where more of it lies inside the masks' visual hull (:func:`~sqfit.fitting.two_parts.pick_part`).
This script repeats those steps from stage 3V's
fit (chain ``1-2M-3H-3R-3V``, 3U's input; like ``scripts/two_part_probe.py`` it ignores 3U's trigger), and
where the union passes 3U's gate (:func:`~sqfit.fitting.two_parts.passes_gate`) polishes *every* start and
scores each part against the mesh:

- ``iou``: its 3D IoU with the mesh (:func:`sqfit.metrics.iou_3d_mesh`);
- ``precision``: the share of its volume inside the mesh (a uniform interior sample of the mesh,
  :func:`sqfit.limit.interior_points`, gives the intersection);
- ``in_hull``: the share of its volume inside the visual hull of the masks
  (:func:`~sqfit.fitting.two_parts.hull_share` of :func:`sqfit.fitting.hull.object_hull`), which the fitter knows.

Per trial it prints, of the union of the lowest objective (the one 3U polished alone until 2026-12-03), the
larger part (``larger``), the other part (``other``), the part the visual hull picks (``by_hull``:
:func:`~sqfit.fitting.two_parts.pick_part` with the hull) and the better of the two (``best_of_two``, known from
the mesh only); the part 3U keeps (``kept``: of the union :func:`~sqfit.fitting.two_parts.polish` keeps, the
hull's pick); the best part of any start (``best_of_all``); the larger and the other part's precision and
in-hull share,
then per kind the medians and how the precise parts (precision >= 0.8) and the others sit in the hull.
``--records FILE`` appends one JSON line per trial. Measured: docs/real-objects.md, "Which part 3U keeps".
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.fitting.costs import ObservationSet  # noqa: E402
from sqfit.fitting.hull import object_hull  # noqa: E402
from sqfit.fitting.least_volume import bulk_observations  # noqa: E402
from sqfit.fitting.stages import to_superquadric  # noqa: E402
from sqfit.fitting.two_parts import (MU, fit_union, hull_share, near_best, passes_gate, pick_part,  # noqa: E402
                                     starts as union_starts, union_ious)
from sqfit.geometry.superquadric import contains, volume  # noqa: E402
from sqfit.limit import interior_points  # noqa: E402
from sqfit.metrics import iou_3d_mesh  # noqa: E402
from sqsim.imaging.render import get_renderer  # noqa: E402
from sqsim.imaging.trial import observations, simulate_trial  # noqa: E402
from sqsim.world.scene import load_scene  # noqa: E402

#: 3U's input: the default chain up to its stage 3V.
BASE_CHAIN = "1-2M-3H-3R-3V"
#: A part at least this much inside the mesh counts as precise in the summary.
PRECISE = 0.8


def part_scores(xi, mesh, mesh_sample, hull):
    """``{"iou", "precision", "in_hull"}`` of the part ``xi`` against ``mesh`` (module docstring)."""
    sq = to_superquadric(xi)
    inter = float(contains(sq, mesh_sample).mean()) * mesh.volume
    return {"iou": iou_3d_mesh(sq, mesh), "precision": min(inter / volume(sq), 1.0), "in_hull": hull_share(xi, hull)}


def trial_row(scene, index, renderer, seed):
    """One trial's figures (a dict); ``passes`` False and no parts where the union fails 3U's gate."""
    sim = simulate_trial(scene, index, renderer)
    obj = sim.objects[0]
    obs = ObservationSet(list(observations(sim, obj.id, scene)))
    base = sqfit.fit(obs.observations, chain=BASE_CHAIN).superquadric
    xi, reference = base.to_vector(), volume(base)
    bulk = bulk_observations(obs) or obs
    singles = union_ious(xi[None, None], bulk)[0]
    fits = [fit_union(start, bulk, MU, reference) for start in union_starts(xi)]
    best = int(np.argmin([fit[2] for fit in fits]))
    row = {"trial": index, "base": iou_3d_mesh(base, obj.mesh), "passes": passes_gate(singles, fits[best][1])}
    if not row["passes"]:
        return row
    hull, mesh_sample = object_hull(obs), interior_points(obj.mesh, 2**14, np.random.default_rng(seed))
    starts = []
    for X, _, objective, _ in fits:
        polished, ious, _, _ = fit_union(X, bulk, 0.0, reference)
        starts.append({"objective": objective, "parts": [part_scores(x, obj.mesh, mesh_sample, hull) for x in polished],
                       "larger": pick_part(polished), "by_hull": pick_part(polished, hull),
                       "mismatch": float((1.0 - ious).sum())})
    chosen = starts[min(near_best(fits), key=lambda i: starts[i]["mismatch"])]  # as polish() chooses
    parts, larger, by_hull = starts[best]["parts"], starts[best]["larger"], starts[best]["by_hull"]
    row.update(larger=parts[larger]["iou"], other=parts[1 - larger]["iou"], by_hull=parts[by_hull]["iou"],
               kept=chosen["parts"][chosen["by_hull"]]["iou"],
               best_of_two=max(p["iou"] for p in parts),
               best_of_all=max(p["iou"] for s in starts for p in s["parts"]),
               larger_precision=parts[larger]["precision"], larger_in_hull=parts[larger]["in_hull"],
               other_precision=parts[1 - larger]["precision"], other_in_hull=parts[1 - larger]["in_hull"],
               starts=starts, best_start=best)
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="scenes/household.toml")
    parser.add_argument("--kinds", nargs="+", default=["chair", "laptop", "monitor"])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--records", default=None, help="append one JSON line per trial to this file")
    args = parser.parse_args(argv)
    if args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    base = load_scene(args.scene)
    columns = ("base", "larger", "other", "by_hull", "best_of_two", "kept", "best_of_all", "larger_precision",
               "larger_in_hull", "other_precision", "other_in_hull")
    for kind in args.kinds:
        scene = base.with_overrides({"objects.catalogue": [kind], "experiment.seed": args.seed,
                                     "experiment.limit": False})
        renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
        rows = []
        for index in range(args.trials):
            row = trial_row(scene, index, renderer, args.seed)
            if args.records:
                with open(args.records, "a") as f:
                    f.write(json.dumps({"kind": kind, "seed": args.seed, **row}) + "\n")
            if not row["passes"]:
                print(f"{kind} {index:3d}: base {row['base']:.3f}, the union fails 3U's gate", flush=True)
                continue
            rows.append(row)
            print(f"{kind} {index:3d}: " + ", ".join(f"{c} {row[c]:.3f}" for c in columns), flush=True)
        if not rows:
            print(f"{kind}: no union passed 3U's gate", flush=True)
            continue
        medians = ", ".join(f"{c} {np.median([r[c] for r in rows]):.3f}" for c in columns)
        print(f"{kind} medians over the {len(rows)} unions that pass the gate: {medians}", flush=True)
        parts = [p for r in rows for p in r["starts"][r["best_start"]]["parts"]]
        for name, group in (("precise", [p for p in parts if p["precision"] >= PRECISE]),
                            ("other", [p for p in parts if p["precision"] < PRECISE])):
            if group:
                share = np.array([p["in_hull"] for p in group])
                print(f"{kind} {name} parts ({len(group)}, precision {'>=' if name == 'precise' else '<'} "
                      f"{PRECISE}): in the hull {share.min():.2f}-{share.max():.2f}, median {np.median(share):.2f}; "
                      f"3D IoU median {np.median([p['iou'] for p in group]):.3f}", flush=True)


if __name__ == "__main__":
    main()
