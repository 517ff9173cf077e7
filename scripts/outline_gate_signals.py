"""What stage 3T sees where it triggers: the signals a gate could use, and the 3D IoU it moves.

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/outline_gate_signals.py SCENE.toml --trials N --seed S \
        [--catalogue table] [--chain 1-2M-3H-3R] [-o out.jsonl]

Each trial is simulated and observed as ``sqsim experiment`` does (``sqsim.runs.experiment.fit_trial``), the
chain (default: the default without 3T) is fitted stage by stage, and where its last state would pass
3T's cost and outline trigger (:mod:`sqfit.fitting.outline`) the script records, before and after 3T's
G2 on the contours: the input's 3G cost, the contour R-IOU-M, the stretches of the outline rays
(:func:`sqfit.fitting.trimmed.stretches`), the mean fraction of each view's fitted silhouette that
lies outside the mask contour (known background), and the 3D IoU against the ground truth. One JSON
line per fit; every fit (triggered or not) has its 3G cost, 3D IoU and ``triggered``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from shapely.geometry import Polygon  # noqa: E402

from sqfit.fitting import outline, trimmed  # noqa: E402
from sqfit.fitting.costs import ObservationSet  # noqa: E402
from sqfit.fitting.grazing import outline_rays  # noqa: E402
from sqfit.fitting.pipeline import FitOptions, parse_chain  # noqa: E402
from sqfit.fitting.stages import STAGES, default_state, to_superquadric  # noqa: E402
from sqfit.geometry.silhouette import silhouette  # noqa: E402
from sqfit.metrics import iou_3d, iou_3d_mesh  # noqa: E402


def background_fraction(sq, obs):
    """Mean over views of the fraction of ``sq``'s silhouette area outside the mask contour."""
    out = []
    for o in obs:
        sil = silhouette(sq, o.camera)
        if len(sil) < 3:
            continue
        s, c = Polygon(sil).buffer(0), Polygon(o.contour).buffer(0)
        if s.area > 0:
            out.append(1.0 - s.intersection(c).area / s.area)
    return float(np.mean(out)) if out else float("nan")


def main(argv=None):
    from sqsim.imaging.render import get_renderer
    from sqsim.imaging.trial import observations, simulate_trial
    from sqsim.world.scene import load_scene

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene")
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--catalogue", default=None, help="household kinds, comma-separated")
    p.add_argument("--chain", default="1-2M-3H-3R", help="chain before 3T")
    p.add_argument("-o", "--output", default=None)
    args = p.parse_args(argv)
    over = {"experiment.trials": args.trials, "experiment.seed": args.seed, "experiment.limit": False}
    if args.catalogue:
        over["objects.catalogue"] = args.catalogue.split(",")
    scene = load_scene(args.scene).with_overrides(over)
    f = scene.fit
    options = FitOptions.coerce({"polygon": f.polygon, "penalty_riou": f.penalty_riou,
                                 "penalty_analytic": f.penalty_analytic, "pose_sigma_deg": f.pose_sigma_deg,
                                 "occlusion_aware": f.occlusion_aware, "outline_offset_sigma_px": f.outline_offset_sigma_px,
                                 "outline_offset": f.outline_offset,
                                 "outline_offset_view_sigma_px": f.outline_offset_view_sigma_px})
    names = parse_chain(args.chain)
    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    fh = open(args.output, "w") if args.output else sys.stdout
    pen = options.penalty_analytic
    for index in range(args.trials):
        sim = simulate_trial(scene, index, renderer)
        for obj in sim.objects:
            try:
                obs_list = observations(sim, obj.id, scene)
            except ValueError:
                continue
            obs = ObservationSet(obs_list)
            state = default_state(obs)
            for name in names:
                state = STAGES[name](state, obs, options)

            def score(xi):
                sq = to_superquadric(xi)
                return iou_3d(sq, obj.superquadric) if obj.superquadric is not None else iou_3d_mesh(sq, obj.mesh)

            rec = {"trial": index, "object": obj.id, "item": obj.to_dict().get("item", obj.to_dict().get("kind")),
                   "cost": state.cost, "iou_before": score(state.xi), "triggered": False}
            if outline.over_cost_trigger(state):
                before = outline.contour_score(state, obs)
                rec["r_iou_m_before"] = before
                if before < outline.TRIGGER_R_IOU_M:
                    rec["triggered"] = True
                    t0 = time.process_time()
                    new = STAGES["3T"](state, obs, options)
                    rec["seconds_3t"] = time.process_time() - t0
                    rec["message"] = new.message[:200]
                    rec["moved"] = not np.array_equal(new.xi, state.xi)
                    rec["r_iou_m_after"] = outline.contour_score(new, obs)
                    rec["iou_after"] = score(new.xi)
                    rays = outline_rays(obs)
                    for tag, xi in (("before", state.xi), ("after", new.xi)):
                        ev = trimmed.stretches(np.asarray(xi, dtype=np.float64), rays, pen)
                        rec[f"stretch_{tag}"] = [ev.stretch, ev.views, ev.contrary, ev.beyond]
                        rec[f"background_{tag}"] = background_fraction(to_superquadric(xi), obs_list)
                    rec["rays"] = len(rays)
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
