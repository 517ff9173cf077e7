"""Per household kind: the mesh, its best superquadric (the representation limit) and the fits.

Usage::

    python scripts/household_fits_figure.py RUN_DIR [RUN_DIR ...] --output docs/figures/household_fits.png \
        [--chains default,tolerant]

Each ``RUN_DIR`` is an ``sqsim experiment`` output of a household scene (``trials.jsonl`` with the
``limit`` of every object, so ``experiment.limit = true``), e.g. one per kind; their objects are
pooled (an object is a trial and object of one directory). For each kind, the object whose default
IoU / limit is the median of its kind is drawn in one row: the mesh alone, then the mesh (grey) with
the limit superquadric and with each chain's fit (translucent, coloured), all from the same
off-screen pyrender (OSMesa) camera, with the 3D IoU against the mesh in the panel title.
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyrender  # noqa: E402

import sqfit  # noqa: E402
from sqfit.fitting import CHAIN_ALIASES  # noqa: E402
from sqfit.geometry.superquadric import to_mesh  # noqa: E402
from sqsim.data.files import read_records  # noqa: E402
from sqsim.world.objects import make_object  # noqa: E402

PIXELS = 300
#: Camera direction from the object (world frame: front-left and above), vertical field of view.
VIEW_DIRECTION = np.array([-0.6, -1.0, 0.7])
FOV = np.radians(32.0)
MESH_COLOUR = (0.55, 0.55, 0.55, 1.0)
#: Colours of the overlaid superquadrics: limit, then the chains in order.
SQ_COLOURS = [(0.15, 0.65, 0.25, 0.45), (0.90, 0.45, 0.10, 0.45), (0.75, 0.10, 0.45, 0.45), (0.1, 0.3, 0.8, 0.45)]


def _records(run_dirs):
    """``{(directory index, trial, object): {chain: record}}`` of the household objects with a limit."""
    by_object = defaultdict(dict)
    for index, run_dir in enumerate(run_dirs):
        path = Path(run_dir) / "trials.jsonl"
        if not path.is_file():
            raise SystemExit(f"{path} not found: each RUN_DIR must be an sqsim experiment output")
        try:
            records = read_records(path)  # as a resumed run reads them: a line cut short by a kill is dropped
        except ValueError as exc:
            raise SystemExit(str(exc)) from None
        for r in records:
            if "item" in r.get("gt", {}) and r.get("limit"):
                by_object[(index, r["trial"], r["object"])][r["chain"]] = r
    if not by_object:
        raise SystemExit(f"{', '.join(map(str, run_dirs))}: no household objects with a representation limit")
    return by_object


def _pick(by_object, chains):
    """Per kind, the object whose first chain's IoU / limit is the median of its kind."""
    kinds = defaultdict(list)
    for recs in by_object.values():
        if all(c in recs for c in chains):
            first = recs[chains[0]]
            kinds[first["gt"]["item"]].append((first["metrics"]["iou"] / first["metrics"]["iou_limit"], recs))
    out = {}
    for kind, rows in sorted(kinds.items()):
        rows.sort(key=lambda row: row[0])
        out[kind] = rows[(len(rows) - 1) // 2][1]
    return out


def _render(renderer, meshes, centre, radius):
    scene = pyrender.Scene(bg_color=(1.0, 1.0, 1.0, 1.0), ambient_light=(0.25, 0.25, 0.25))
    for mesh, colour in meshes:
        material = pyrender.MetallicRoughnessMaterial(baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=0.8,
                                                      alphaMode="BLEND" if colour[3] < 1 else "OPAQUE")
        scene.add(pyrender.Mesh.from_trimesh(mesh, material=material, smooth=False))
    eye = centre + VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION) * radius / np.sin(FOV / 2) * 1.1
    pose = sqfit.look_at(eye, centre) @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV -> OpenGL camera
    scene.add(pyrender.PerspectiveCamera(yfov=FOV), pose=pose)
    scene.add(pyrender.DirectionalLight(intensity=2.5), pose=pose)
    colour, _ = renderer.render(scene)
    return colour


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    parser.add_argument("--output", required=True)
    parser.add_argument("--chains", default="default,tolerant",
                        help="chains to draw, as recorded (aliases are expanded: default = sqfit.DEFAULT_CHAIN)")
    args = parser.parse_args(argv)
    chains = [CHAIN_ALIASES.get(c, c) for c in args.chains.split(",")]
    picked = _pick(_records(args.run_dirs), chains)
    if not picked:
        raise SystemExit(f"no object of {', '.join(args.run_dirs)} was fitted with all of {chains}")
    cols = 2 + len(chains)
    fig, axes = plt.subplots(len(picked), cols, figsize=(2.3 * cols, 2.4 * len(picked)), squeeze=False)
    renderer = pyrender.OffscreenRenderer(PIXELS, PIXELS)
    for row, (kind, recs) in zip(axes, picked.items()):
        first = recs[chains[0]]
        gt = first["gt"]
        # the record's size is the object's half-extents; "keep" scales the longest to size[0]
        obj = make_object(1, "household", [max(gt["size"])] * 3, None, gt["position"], gt["rotation"],
                          item=(gt["item"], gt["item_seed"]), proportions="keep")
        centre = obj.mesh.bounds.mean(axis=0)
        radius = 0.5 * np.linalg.norm(obj.mesh.extents)
        limit = sqfit.Superquadric.from_vector(first["limit"]["params"])
        panels = [("mesh", None, None), ("limit", limit, first["metrics"]["iou_limit"])]
        panels += [(c, sqfit.Superquadric.from_vector(recs[c]["params"]) if recs[c].get("params") else None,
                    recs[c]["metrics"]["iou"]) for c in chains]
        for k, (ax, (name, sq, iou)) in enumerate(zip(row, panels)):
            meshes = [(obj.mesh, MESH_COLOUR)]
            if sq is not None:
                meshes.append((to_mesh(sq, 48), SQ_COLOURS[(k - 1) % len(SQ_COLOURS)]))
            ax.imshow(_render(renderer, meshes, centre, radius))
            ax.set_title(kind if name == "mesh" else f"{name}: IoU {iou:.2f}", fontsize=8)
            ax.set_axis_off()
    renderer.delete()
    source = Path(args.run_dirs[0]).name if len(args.run_dirs) == 1 else f"{len(args.run_dirs)} runs"
    fig.suptitle(f"{source}: mesh, best superquadric (limit), fits (median object of each kind)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.4 / fig.get_figheight()))
    fig.savefig(args.output, dpi=100)
    print(f"wrote {args.output} ({len(picked)} kinds)")


if __name__ == "__main__":
    main()
