"""Two superquadrics for an object's masks, and the best single one of them (household kinds).

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/two_part_probe.py [--scene scenes/household.toml] \
        [--kinds chair laptop ...] [--trials 10] [--seed 0] [--mu 0.2] [--differences] \
        [--limits DIR] [--records FILE]

The measurement behind stage 3U (:mod:`sqfit.fitting.two_parts`, chain ``two-parts``), which it takes
its union fit from. An open laptop or a chair's seat and back are two slabs at an angle; their best
single superquadric (the representation limit) is one slab, but chain ``whole``'s fit (the default
before 3U joined it) fills the wedge between them. For each trial this fits the *union* of two
superquadrics to the opened masks from ``whole``'s fit much as 3U does from 3V's
(:func:`~sqfit.fitting.two_parts.fit_union` from each of :func:`~sqfit.fitting.two_parts.starts`;
``--mu`` the weight of the parts' volume; ``--differences`` for the IoUs' Jacobian by forward
differences), and reports what each rule would keep: the part of higher 3D IoU with the union, the
larger (3U's :func:`~sqfit.fitting.two_parts.pick_part`), the part whose own silhouettes match the masks
better, the better of the two parts (known only from the mesh), and the gated pick: the first rule's
part only where the union passes 3U's gate (:func:`~sqfit.fitting.two_parts.passes_gate`), else
``whole``'s fit (unlike 3U, the probe fits the union whether or not 3U's trigger holds).

Per trial it prints ``whole``'s 3D IoU against the mesh and its silhouettes' mean IoU with the
(opened) masks, the union's, the rules' picks, the better of the two parts, the gated pick and the
limit; then per kind the medians. ``--records FILE`` appends one JSON line per trial (parts'
parameters included).
Measured: docs/real-objects.md, "Two parts for two slabs".
"""

from __future__ import annotations

import argparse
import json
import os
import time
import tomllib

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.fitting.costs import ObservationSet  # noqa: E402
from sqfit.fitting.least_volume import bulk_observations  # noqa: E402
from sqfit.fitting.stages import to_superquadric  # noqa: E402
from sqfit.fitting.two_parts import fit_union, passes_gate, pick_part, starts, union_ious  # noqa: E402
from sqfit.geometry.superquadric import volume  # noqa: E402
from sqfit.metrics import iou_3d_mesh  # noqa: E402
from sqsim.imaging.render import get_renderer  # noqa: E402
from sqsim.imaging.trial import observations, simulate_trial  # noqa: E402
from sqsim.world.limit import LimitCache, object_limit  # noqa: E402
from sqsim.world.scene import parse_scene  # noqa: E402

def trial_row(scene, index, renderer, mu, cache, differences=False):
    """One trial's figures (a dict)."""
    sim = simulate_trial(scene, index, renderer)
    obj = sim.objects[0]
    obs = ObservationSet(list(observations(sim, obj.id, scene)))
    fit = sqfit.fit(obs.observations, chain="whole").superquadric
    xi = fit.to_vector()
    t0 = time.process_time()
    bulk = bulk_observations(obs) or obs
    singles = union_ious(xi[None, None], bulk)[0]
    best = min((fit_union(start, bulk, mu, volume(fit), differences) for start in starts(xi)), key=lambda t: t[2])
    X, unions = best[0], best[1]
    passes = passes_gate(singles, unions)
    parts = [to_superquadric(x) for x in X]
    seconds = time.process_time() - t0
    alone = union_ious(X[:, None], bulk).mean(axis=1)
    ious = [iou_3d_mesh(q, obj.mesh) for q in parts]
    return {"trial": index, "default": iou_3d_mesh(fit, obj.mesh), "single_sil": float(singles.mean()),
            "union_sil": float(unions.mean()), "passes": passes,
            "parts": ious, "by_union": ious[pick_part(X)], "by_silhouette": ious[int(np.argmax(alone))],
            "limit": object_limit(obj, cache).iou, "seconds": seconds, "parts_xi": X.tolist()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="scenes/household.toml")
    parser.add_argument("--kinds", nargs="+", default=["chair", "laptop"])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mu", type=float, default=0.2, help="weight of the parts' volume (default 0.2)")
    parser.add_argument("--differences", action="store_true",
                        help="the IoUs' Jacobian by forward differences (slower) instead of union_gradient")
    parser.add_argument("--limits", default=None, help="directory of cached limits (an experiment's DIR/limits)")
    parser.add_argument("--records", default=None, help="append one JSON line per trial to this file")
    args = parser.parse_args(argv)
    if not args.mu >= 0:
        parser.error(f"--mu must be >= 0, got {args.mu}")
    if args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    with open(args.scene, "rb") as f:
        scene_dict = tomllib.load(f)
    cache = LimitCache(args.limits) if args.limits else None
    columns = ("default", "single_sil", "union_sil", "by_union", "by_silhouette", "best_part", "gated", "limit",
               "seconds")
    for kind in args.kinds:
        scene = parse_scene({**scene_dict, "objects": {**scene_dict["objects"], "catalogue": [kind]},
                             "experiment": {**scene_dict["experiment"], "seed": args.seed}}, source=kind)
        renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
        rows = []
        for index in range(args.trials):
            row = trial_row(scene, index, renderer, args.mu, cache, args.differences)
            row["best_part"] = max(row["parts"])
            row["gated"] = row["by_union"] if row["passes"] else row["default"]
            rows.append(row)
            print(f"{kind} {index:3d}: " + ", ".join(f"{c} {row[c]:.3f}" for c in columns), flush=True)
            if args.records:
                with open(args.records, "a") as f:
                    f.write(json.dumps({"kind": kind, "seed": args.seed, "mu": args.mu, **row}) + "\n")
        medians = {c: float(np.median([r[c] for r in rows])) for c in columns}
        print(f"{kind} medians: " + ", ".join(f"{c} {v:.3f}" for c, v in medians.items()), flush=True)


if __name__ == "__main__":
    main()
