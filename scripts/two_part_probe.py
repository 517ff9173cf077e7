"""Two superquadrics for an object's masks, and the best single one of them (household kinds).

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/two_part_probe.py [--scene scenes/household.toml] \
        [--kinds chair laptop ...] [--trials 10] [--seed 0] [--mu 0.2] [--gate 0.12] [--differences] \
        [--limits DIR] [--records FILE]

A lead measured, not adopted (too slow and its choice of part unreliable), kept so that it can be
repeated. An open laptop or a chair's seat and back are two slabs at an angle; their best single
superquadric (the representation limit, :func:`sqfit.limit.best_superquadric`) is one slab, but the
default's fit, like the visual hull, fills the wedge between them (3D IoU about 0.09 against limits
of 0.45-0.66). The masks do show the two slabs: the default's silhouettes match them to a mean IoU
of 0.58-0.78 only (medians per kind and seed). So for each trial this fits the *union* of two
superquadrics to the masks, from twelve L-shaped starts (each pair of adjacent faces of the default
fit's box, each a slab :data:`THIN` of the box thick), by least squares (the IoUs' Jacobian from the
silhouettes' vertex velocities, :func:`union_gradient`; ``--differences`` for forward differences)
on ``1 - IoU`` per view of the union's silhouettes with the mask contours (the masks with their thin
parts opened away, :func:`sqfit.fitting.least_volume.bulk_observations`, where any view has one: a
chair's legs) plus ``mu`` times the parts' total volume over the default fit's (the least volume
that matches, as stage 3V picks), and keeps the start of the lowest objective. Then one of the two
parts is the answer; which one, the masks must say. Two rules are reported: the part of higher
estimated 3D IoU with the union (a uniform sample of the union), and the part whose own silhouettes
match the masks better. And a gate: the first rule's part only where the union matches the masks
better than the default's fit by at least ``--gate`` in mean silhouette IoU, else the default's fit.

Per trial it prints the default's 3D IoU against the mesh and its silhouettes' mean IoU with the
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
from scipy.optimize import least_squares  # noqa: E402

import sqfit  # noqa: E402
from sqfit.fitting.contour_overlap import CONVEX_TOL  # noqa: E402
from sqfit.fitting.costs import ObservationSet  # noqa: E402
from sqfit.fitting.least_volume import bulk_observations  # noqa: E402
from sqfit.fitting.stages import to_superquadric  # noqa: E402
from sqfit.geometry.silhouette import batch_silhouettes, vertex_velocities  # noqa: E402
from sqfit.geometry.superquadric import contains, euler_to_matrix, volume  # noqa: E402
from sqfit.kernels.backend import compiled  # noqa: E402
from sqfit.metrics import iou_3d_mesh  # noqa: E402
from sqsim.imaging.render import get_renderer  # noqa: E402
from sqsim.imaging.trial import observations, simulate_trial  # noqa: E402
from sqsim.world.limit import LimitCache, object_limit  # noqa: E402
from sqsim.world.scene import parse_scene  # noqa: E402

#: A start's slabs are this share of the default fit's box thick.
THIN = 0.15
#: Vertices per silhouette.
VERTICES = 48
#: Least-squares evaluations per start.
EVALUATIONS = 100
#: Forward-difference step of the Jacobian (relative, as scipy's ``diff_step``).
STEP = 1e-3
#: Midpoints per silhouette edge of the union's gradient (:func:`union_gradient`).
EDGE_POINTS = 8
#: Points of the union's uniform sample (the rules' IoU estimate).
UNION_POINTS = 20000
#: Seed of that sample.
SEED = 0
#: Default of ``--gate``: the union's silhouette gain over the default's fit that lets a part replace it.
GATE = 0.12


def l_starts(xi, thin=THIN):
    """``(12, 2, 11)``: for each pair of adjacent faces of the box of the fit ``xi`` (its frame and
    half-axes), a slab along each face, ``thin`` of the box thick, with boxy exponents."""
    a, R, p = np.abs(xi[0:3]), euler_to_matrix(xi[8:11]), xi[5:8]
    starts = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        for si in (-1.0, 1.0):
            for sj in (-1.0, 1.0):
                pair = []
                for axis, sign in ((i, si), (j, sj)):
                    size = a.copy()
                    size[axis] *= thin
                    centre = p + R[:, axis] * sign * a[axis] * (1.0 - thin)
                    pair.append(np.r_[size, 0.2, 0.2, centre, xi[8:11]])
                starts.append(pair)
    return np.array(starts)


def union_overlap(X, obs, silhouettes=None):
    """``(inter, union, valid)``, each ``(b, v)``: the area of the union of each row's superquadrics'
    silhouettes (``X`` ``(b, m, 11)``) in each view of ``obs`` (an ObservationSet whose views the
    image border does not cut) overlapping the mask contour, the union's area, and whether every
    silhouette is valid. ``silhouettes``: ``(polys, valid)`` of ``X``'s rows as
    :func:`sqfit.geometry.silhouette.batch_silhouettes` returns them for ``X.reshape(-1, 11)``, where
    the caller has them. Two parts: compiled inclusion-exclusion where the kernels are and the
    contour is simple (:func:`sqfit.kernels.silhouette_kernels.union_overlaps`), else shapely."""
    import shapely

    b, m = X.shape[:2]
    if silhouettes is None:
        silhouettes = batch_silhouettes(X.reshape(b * m, 11), obs.rotations, obs.centers, obs.intrinsics, VERTICES)
    polys, valid = silhouettes[0], silhouettes[1]
    polys, valid = polys.reshape(b, m, *polys.shape[1:]), valid.reshape(b, m, -1).all(axis=1)
    stacked, starts, simple, _ = obs.contour_arrays()
    inter, union = np.zeros((b, len(obs))), np.ones((b, len(obs)))
    todo = valid.copy()
    kernels = compiled("silhouettes")
    if kernels is not None and m == 2 and todo.any():
        rows, views = np.nonzero(todo & simple)
        got_inter, got_area, ok = kernels.union_overlaps(np.ascontiguousarray(polys), np.stack([rows, views], axis=1),
                                                        stacked, starts, CONVEX_TOL)
        inter[rows[ok], views[ok]], union[rows[ok], views[ok]] = got_inter[ok], got_area[ok]
        todo[rows[ok], views[ok]] = False
    shapes = obs.contour_shapes()
    for row, view in zip(*np.nonzero(todo)):
        parts = shapely.union_all(shapely.make_valid(shapely.polygons(polys[row, :, view])))
        inter[row, view] = shapely.area(shapely.intersection(parts, shapes[view]))
        union[row, view] = shapely.area(parts)
    return inter, union, valid


def union_ious(X, obs):
    """``(b, v)``: IoU of the union of each row's superquadrics' silhouettes (``X`` ``(b, m, 11)``)
    with each view's mask contour (:func:`union_overlap`); 0 where a silhouette is not valid."""
    inter, union, valid = union_overlap(X, obs)
    iou = inter / (union + obs.contour_arrays()[3][None] - inter)
    return np.where(valid, iou, 0.0)


def union_gradient(X, obs):
    """IoU per view of the union of the two parts ``X`` ``(2, 11)`` with the mask contours of
    ``obs``, and its gradient: ``(v,)`` and ``(v, 22)``. Moving a silhouette's boundary outward by
    ``w`` changes the union's area by the integral of ``w`` along the stretch of that boundary
    outside the other silhouette, and its overlap with the mask by the integral along the stretch
    outside the other silhouette and inside the contour. ``w`` is the normal component of the
    vertices' velocities (:func:`sqfit.geometry.silhouette.vertex_velocities`), linear along each
    edge; the integrals are midpoint sums of :data:`EDGE_POINTS` points per edge."""
    import shapely

    polys, valid, _, unit_points, points = batch_silhouettes(X, obs.rotations, obs.centers, obs.intrinsics, VERTICES,
                                                             touching=True)
    inter, union, ok = (q[0] for q in union_overlap(X[None], obs, (polys, valid)))
    areas = obs.contour_arrays()[3]
    iou = np.where(ok, inter / (union + areas - inter), 0.0)
    grad = np.zeros((len(obs), 22))
    if not valid.all():
        return iou, grad
    velocities = vertex_velocities(X, unit_points, points, obs.rotations, obs.intrinsics)  # (2, v, K, 2, 11)
    shapes = obs.contour_shapes()
    s = (np.arange(EDGE_POINTS) + 0.5) / EDGE_POINTS
    for view in range(len(obs)):
        d_inter, d_union = np.zeros(22), np.zeros(22)
        for part in range(2):
            P, other = polys[part, view], polys[1 - part, view]
            edge = np.roll(P, -1, axis=0) - P
            length = np.hypot(edge[:, 0], edge[:, 1])
            normal = np.zeros_like(edge)  # outward: the polygons run counter-clockwise
            keep = length > 1e-12
            normal[keep] = np.column_stack([edge[keep, 1], -edge[keep, 0]]) / length[keep, None]
            x = (P[:, None, :] + s[None, :, None] * edge[:, None, :]).reshape(-1, 2)
            o_edge = np.roll(other, -1, axis=0) - other
            cross = (o_edge[None, :, 0] * (x[:, None, 1] - other[None, :, 1])
                     - o_edge[None, :, 1] * (x[:, None, 0] - other[None, :, 0]))
            outside = ~np.all(cross >= 0.0, axis=1).reshape(len(P), -1)
            in_mask = shapely.contains_xy(shapes[view], x[:, 0], x[:, 1]).reshape(len(P), -1)
            vel = velocities[part, view]  # (K, 2, 11)
            w0 = np.einsum("kc,kcp->kp", normal, vel)  # each edge's normal speed at its two ends
            w1 = np.einsum("kc,kcp->kp", normal, np.roll(vel, -1, axis=0))
            w = (1.0 - s)[None, :, None] * w0[:, None, :] + s[None, :, None] * w1[:, None, :]  # (K, n, 11)
            weight = (length / EDGE_POINTS)[:, None] * outside
            cols = slice(11 * part, 11 * part + 11)
            d_union[cols] = np.einsum("kn,knp->p", weight, w)
            d_inter[cols] = np.einsum("kn,knp->p", weight * in_mask, w)
        i, u, a = inter[view], union[view], areas[view]
        grad[view] = (d_inter * (u + a) - i * d_union) / (u + a - i) ** 2
    return iou, grad


def _volumes(X):
    return np.array([[volume(to_superquadric(x)) for x in row] for row in X]).sum(axis=1)


def fit_union(start, obs, mu, reference, differences=False):
    """Least squares from ``start`` ``(2, 11)``: ``1 - IoU`` per view and ``mu`` x the parts' volume
    over ``reference``; the IoUs' Jacobian from :func:`union_gradient`, or by forward differences
    (``differences``; the volume's always). Returns the parts ``(2, 11)``, the union's mean silhouette
    IoU and the objective (the sum of the residuals)."""
    shape = start.shape
    lower = np.tile(np.r_[[1e-3] * 3, 0.05, 0.05, [-np.inf] * 6], shape[0])
    upper = np.tile(np.r_[[np.inf] * 3, 1.9, 1.9, [np.inf] * 6], shape[0])

    def rows(X):
        return np.column_stack([1.0 - union_ious(X, obs), mu * _volumes(X) / reference])

    def residuals(x):
        return rows(x.reshape(1, *shape))[0]

    def jacobian(x):
        h = STEP * np.maximum(np.abs(x), 1.0)
        h = np.where(x + h > upper, -h, h)  # stay inside the bounds
        X = np.vstack([x, x + np.diag(h)]).reshape(-1, *shape)
        if differences:
            r = rows(X)
            return ((r[1:] - r[0]) / h[:, None]).T
        v = mu * _volumes(X) / reference
        return np.vstack([-union_gradient(X[0], obs)[1], (v[1:] - v[0]) / h])

    x0 = np.clip(start.ravel(), lower + 1e-6, upper - 1e-6)
    res = least_squares(residuals, x0, jac=jacobian, bounds=(lower, upper), x_scale="jac", max_nfev=EVALUATIONS)
    return res.x.reshape(shape), 1.0 - res.fun[:-1].mean(), float(res.fun.sum())


def union_sample(parts, n, rng):
    """A uniform sample of the union of ``parts`` (superquadrics) and its volume."""
    lo = np.min([q.position - 1.8 * np.abs(q.size).max() for q in parts], axis=0)
    hi = np.max([q.position + 1.8 * np.abs(q.size).max() for q in parts], axis=0)
    points, kept, drawn = [], 0, 0
    while kept < n:
        u = rng.uniform(lo, hi, (100000, 3))
        inside = np.zeros(len(u), dtype=bool)
        for q in parts:
            inside |= contains(q, u)
        points.append(u[inside])
        kept, drawn = kept + inside.sum(), drawn + len(u)
    return np.vstack(points)[:n], float(np.prod(hi - lo) * kept / drawn)


def trial_row(scene, index, renderer, mu, cache, differences=False):
    """One trial's figures (a dict)."""
    sim = simulate_trial(scene, index, renderer)
    obj = sim.objects[0]
    obs = ObservationSet(list(observations(sim, obj.id, scene)))
    fit = sqfit.fit(obs.observations).superquadric
    xi = fit.to_vector()
    t0 = time.process_time()
    bulk = bulk_observations(obs) or obs
    single = union_ious(xi[None, None], bulk)[0].mean()
    best = min((fit_union(start, bulk, mu, volume(fit), differences) for start in l_starts(xi)), key=lambda t: t[2])
    X, union = best[0], best[1]
    parts = [to_superquadric(x) for x in X]
    seconds = time.process_time() - t0
    rng = np.random.default_rng(SEED)
    sample, vol = union_sample(parts, UNION_POINTS, rng)
    share = [contains(q, sample).mean() * vol for q in parts]
    estimate = [s / (volume(q) + vol - s) for s, q in zip(share, parts)]
    alone = union_ious(X[:, None], bulk).mean(axis=1)
    ious = [iou_3d_mesh(q, obj.mesh) for q in parts]
    return {"trial": index, "default": iou_3d_mesh(fit, obj.mesh), "single_sil": float(single), "union_sil": float(union),
            "parts": ious, "by_union": ious[int(np.argmax(estimate))], "by_silhouette": ious[int(np.argmax(alone))],
            "limit": object_limit(obj, cache).iou, "seconds": seconds, "parts_xi": X.tolist()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="scenes/household.toml")
    parser.add_argument("--kinds", nargs="+", default=["chair", "laptop"])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--mu", type=float, default=0.2, help="weight of the parts' volume (default 0.2)")
    parser.add_argument("--gate", type=float, default=GATE,
                        help=f"silhouette gain of the union that lets a part replace the default's fit (default {GATE})")
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
            row["gated"] = row["by_union"] if row["union_sil"] - row["single_sil"] >= args.gate else row["default"]
            rows.append(row)
            print(f"{kind} {index:3d}: " + ", ".join(f"{c} {row[c]:.3f}" for c in columns), flush=True)
            if args.records:
                with open(args.records, "a") as f:
                    f.write(json.dumps({"kind": kind, "seed": args.seed, "mu": args.mu, **row}) + "\n")
        medians = {c: float(np.median([r[c] for r in rows])) for c in columns}
        print(f"{kind} medians: " + ", ".join(f"{c} {v:.3f}" for c, v in medians.items()), flush=True)


if __name__ == "__main__":
    main()
