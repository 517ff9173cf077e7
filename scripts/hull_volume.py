"""The best superquadric of the visual hull's volume, against the best of the mesh (household kinds).

Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/hull_volume.py [--scene scenes/household.toml] \
        [--kinds table chair ...] [--trials 10] [--seed 0] [--no-search] [--limits DIR]

An experiment that did not pay off, kept so that it can be repeated. The representation limit
(:func:`sqfit.limit.best_superquadric`) is the superquadric of highest 3D IoU with the object's
mesh; the idea was to run the same search (:func:`sqfit.limit.search_volume`) against the visual
hull carved from the masks (:func:`sqfit.fitting.hull.object_hull`, as stage ``HULL`` carves it),
on one uniform point in each of up to :data:`HULL_POINTS` occupied voxels, hoping that the hull
carves the space under a table's top and between its legs. For each kind (the scene with
``objects.catalogue = [KIND]``) and each of the first ``--trials`` trials of ``--seed``, it prints
the medians over the trials of:

- the hull's volume over the mesh's, the share of the mesh inside the hull (1 up to the carving's
  half-voxel rounding) and the 3D IoU of hull and mesh, on a uniform interior sample of the mesh
  (:func:`sqfit.limit.interior_points`);
- unless ``--no-search``: the mesh-boolean 3D IoU (:func:`sqfit.metrics.iou_3d_mesh`) of the
  superquadric that fits the hull best, and the object's limit (cached in ``--limits`` when given:
  an experiment's ``DIR/limits`` serves).

From the four elevated views of ``scenes/household.toml`` the hull of a table, chair or laptop is
3-6 times the object's volume, and its best superquadric fills that phantom volume: far below the
limit there (README "Real objects").
"""

from __future__ import annotations

import argparse
import os
import tomllib

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sqfit.fitting.costs import ObservationSet  # noqa: E402
from sqfit.fitting.hull import object_hull  # noqa: E402
from sqfit.limit import interior_points, search_volume  # noqa: E402
from sqfit.metrics import iou_3d_mesh  # noqa: E402
from sqsim.imaging.render import get_renderer  # noqa: E402
from sqsim.imaging.trial import observations, simulate_trial  # noqa: E402
from sqsim.world.household import CATALOGUE  # noqa: E402
from sqsim.world.limit import LimitCache, object_limit  # noqa: E402
from sqsim.world.scene import parse_scene  # noqa: E402

#: Interior sample of each mesh (the hull's share of it).
MESH_POINTS = 2**14
#: Points of the hull's sample searched (at most one per occupied voxel).
HULL_POINTS = 2**13
#: Seed of the hull's sample and of the search.
SEED = 0


def in_hull(hull, points):
    """``(n,) bool``: whether each point lies in an occupied voxel of ``hull``."""
    cell = np.floor((points - hull.origin) / hull.voxel + 0.5).astype(np.int64)
    valid = np.all((cell >= 0) & (cell < np.array(hull.occupied.shape)), axis=1)
    out = np.zeros(len(points), dtype=bool)
    out[valid] = hull.occupied[tuple(cell[valid].T)]
    return out


def hull_sample(hull, n, rng):
    """``(min(n, voxels), 3) float``: one uniform point in each of up to ``n`` occupied voxels (without replacement)."""
    centres = hull.centers()
    if len(centres) > n:
        centres = centres[rng.choice(len(centres), int(n), replace=False)]
    return centres + hull.voxel * rng.uniform(-0.5, 0.5, centres.shape)


def hull_fit(hull):
    """The superquadric of highest estimated 3D IoU with the hull's volume."""
    rng = np.random.default_rng(SEED)
    candidates, _ = search_volume(hull_sample(hull, HULL_POINTS, rng), hull.volume, rng, final=1)
    return candidates[0][1]


def kind_rows(scene_dict, kind, trials, seed, search, cache):
    """``(trials, 5) float``: hull / mesh volume, share of the mesh in the hull, IoU of hull and mesh,
    IoU of the hull's best superquadric with the mesh and the limit (both NaN without ``search``)."""
    scene_dict = {**scene_dict, "objects": {**scene_dict["objects"], "catalogue": [kind]},
                  "experiment": {**scene_dict["experiment"], "seed": seed}}
    scene = parse_scene(scene_dict, source=kind)
    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    rows = []
    for index in range(trials):
        sim = simulate_trial(scene, index, renderer)
        obj = sim.objects[0]
        hull = object_hull(ObservationSet(observations(sim, obj.id, scene)))
        share = in_hull(hull, interior_points(obj.mesh, MESH_POINTS, 0)).mean()
        inter = share * obj.mesh.volume
        fit_iou = iou_3d_mesh(hull_fit(hull), obj.mesh) if search else np.nan
        limit = object_limit(obj, cache).iou if search else np.nan
        rows.append((hull.volume / obj.mesh.volume, share, inter / (hull.volume + obj.mesh.volume - inter),
                     fit_iou, limit))
    return np.array(rows)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="scenes/household.toml")
    parser.add_argument("--kinds", nargs="+", default=list(CATALOGUE))
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-search", dest="search", action="store_false", help="the hull's statistics only")
    parser.add_argument("--limits", default=None, help="directory of cached limits (an experiment's DIR/limits)")
    args = parser.parse_args(argv)
    with open(args.scene, "rb") as f:
        scene_dict = tomllib.load(f)
    cache = LimitCache(args.limits) if args.limits else None
    print("kind        hull/mesh volume   mesh in hull   IoU(hull, mesh)   best SQ of hull   limit   (medians)")
    for kind in args.kinds:
        rows = kind_rows(scene_dict, kind, args.trials, args.seed, args.search, cache)
        ratio, share, iou, fit_iou, limit = np.median(rows, axis=0)
        print(f"{kind:<11} {ratio:16.2f} {share:14.3f} {iou:17.3f} {fit_iou:17.3f} {limit:7.3f}", flush=True)


if __name__ == "__main__":
    main()
