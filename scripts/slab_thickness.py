"""How thick the default fits a slab (a table's top, a monitor's screen), and which thickness the masks ask for.

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/slab_thickness.py [--scene scenes/household.toml] \
        [--kinds table monitor] [--trials 20] [--seed 0] [--limits DIR]

Per trial it fits the default chain and, where the fit is a slab (:func:`sqfit.geometry.slab.thin_section`), takes
the fit *before* stage 3W's thickness step (:func:`sqfit.fitting.weighted_overlap.slab_thickness`: the factor its
message names undone; where the step kept the thickness, the message's reason is printed: e.g. ``its input a
squared slab``), scales its thin half-axis by each factor of ``--factors`` and scores the candidates three
ways: the silhouettes' mean IoU with the full mask contours (``full``), the same with the masks' thin parts opened
away (``open``, :func:`sqfit.fitting.least_volume.bulk_observations`) and 3W's excess-weighted overlap with the
opened masks (``weighted``, :func:`sqfit.fitting.weighted_overlap.weighted_ious`, the step's score). It prints the
factor each score picks and that candidate's 3D IoU against the mesh, the factor of the best 3D IoU (known from the
mesh only), the step's factor, and, with ``--limits`` (a limit cache directory, e.g. ``DIR/limits`` of an
``sqsim experiment`` run of the same scene, kind and seed; the search runs where the cache has no entry), the
thin half-axis before the step over the limit superquadric's thinnest. Then per kind the medians.
Measured: docs/real-objects.md, "Tables: the top's thickness".
"""

from __future__ import annotations

import argparse
import os
import re

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import sqfit  # noqa: E402
from sqfit.fitting.costs import ObservationSet  # noqa: E402
from sqfit.fitting.least_volume import bulk_observations  # noqa: E402
from sqfit.fitting.stages import r_iou_m, to_superquadric  # noqa: E402
from sqfit.fitting.weighted_overlap import thickness_candidates, weighted_ious  # noqa: E402
from sqfit.geometry.slab import thin_section  # noqa: E402
from sqfit.metrics import iou_3d_mesh  # noqa: E402
from sqsim.imaging.trial import observations, simulate_trial  # noqa: E402
from sqsim.world.limit import LimitCache, object_limit  # noqa: E402
from sqsim.world.scene import load_scene  # noqa: E402

#: The factors tried on the thin half-axis of the fit before the step.
FACTORS = np.round(np.arange(0.3, 1.2001, 0.05), 2)
#: The step's factor in the default's last stage message.
STEP_FACTOR = re.compile(r"thickness x ([0-9.]+)")
#: Why the step kept the thickness, in that message (the step's own words, up to ": thickness kept").
STEP_KEPT = re.compile(r"; ([^;]*): thickness kept")


def trial_row(scene, index, factors, cache):
    """One trial's record (module docstring), or None where the default's fit is no slab."""
    sim = simulate_trial(scene, index)
    obj = sim.objects[0]
    obs = ObservationSet(list(observations(sim, obj.id, scene)))
    result = sqfit.fit(obs)
    x = result.superquadric.to_vector()
    section = thin_section(x)
    if section is None:
        return None
    axis = section[0]
    found = STEP_FACTOR.search(result.stages[-1].message)
    step = float(found.group(1)) if found else 1.0
    kept = STEP_KEPT.search(result.stages[-1].message)
    before = x.copy()
    before[axis] /= step
    X = thickness_candidates(before, axis, factors)
    candidates = [to_superquadric(v) for v in X]
    iou = np.array([iou_3d_mesh(c, obj.mesh) for c in candidates])
    bulk = bulk_observations(obs)
    scores = {"full": r_iou_m(candidates, obs, "contour")}
    if bulk is not None:
        scores["open"] = r_iou_m(candidates, bulk, "contour")
        scores["weighted"] = weighted_ious(X, bulk).mean(axis=1)
    row = {"trial": index, "default": iou_3d_mesh(result.superquadric, obj.mesh), "step": step,
           "kept": kept.group(1) if kept else None,
           "best_3d": (float(factors[np.argmax(iou)]), float(iou.max()))}
    for name, score in scores.items():
        pick = int(np.argmax(score))
        row[name] = (float(factors[pick]), float(iou[pick]))
    if cache is not None:
        row["to_limit"] = float(before[axis] / np.min(object_limit(obj, cache).superquadric.size))
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="scenes/household.toml")
    parser.add_argument("--kinds", nargs="+", default=["table", "monitor"])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--limits", default=None, help="a limit cache directory (adds the thickness over the limit's)")
    parser.add_argument("--factors", type=float, nargs="+", default=None,
                        help="factors on the thin half-axis (default 0.3 to 1.2 in steps of 0.05)")
    args = parser.parse_args(argv)
    if args.trials < 1:
        parser.error(f"--trials must be >= 1, got {args.trials}")
    factors = FACTORS if args.factors is None else np.array(sorted(set(args.factors)), dtype=np.float64)
    if np.any(factors <= 0):
        parser.error("--factors must be > 0")
    base = load_scene(args.scene)
    cache = None if args.limits is None else LimitCache(args.limits)
    picks = ("full", "open", "weighted", "best_3d")
    for kind in args.kinds:
        scene = base.with_overrides({"objects.catalogue": [kind], "experiment.seed": args.seed,
                                     "experiment.limit": False})
        rows = []
        for index in range(args.trials):
            row = trial_row(scene, index, factors, cache)
            if row is None:
                print(f"{kind} {index:3d}: no slab", flush=True)
                continue
            rows.append(row)
            text = ", ".join(f"{name} x{row[name][0]:.2f} -> {row[name][1]:.3f}" for name in picks if name in row)
            limit = f", before the step {row['to_limit']:.2f} x the limit's thickness" if "to_limit" in row else ""
            step = f"step x{row['step']:.2f}" if row["kept"] is None else f"step: {row['kept']}"
            print(f"{kind} {index:3d}: default {row['default']:.3f} ({step}){limit}; {text}", flush=True)
        if not rows:
            continue
        medians = ", ".join(f"{name} {np.median([r[name][1] for r in rows if name in r]):.3f}"
                            for name in picks if any(name in r for r in rows))
        limit = (f", thickness before the step over the limit's {np.median([r['to_limit'] for r in rows]):.2f}"
                 if cache is not None else "")
        print(f"{kind} medians over {len(rows)} slabs: default {np.median([r['default'] for r in rows]):.3f}, "
              f"3D IoU at each score's pick: {medians}{limit}", flush=True)


if __name__ == "__main__":
    main()
