"""Draw the household catalogue (``sqsim.world.household``): one rendered panel per kind.

Usage::

    python scripts/household_figure.py --output docs/figures/household_catalogue.png [--seed 0]

Each panel is an off-screen pyrender (OSMesa) colour image of the kind built with ``--seed`` in
its canonical frame (metres, +z up, front to -y), seen from the front-left and above, with its
extents in the title.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pyrender  # noqa: E402
import trimesh  # noqa: E402

import sqfit  # noqa: E402
from sqsim.world.household import CATALOGUE, build_household  # noqa: E402

#: Panel size, pixels.
PIXELS = 360
#: Camera direction from the object (world frame; front-left and above), and its vertical field
#: of view, radians.
VIEW_DIRECTION = np.array([-0.55, -1.0, 0.6])
FOV = np.radians(30.0)
#: Base colour of the objects (RGB in [0, 1]).
COLOUR = (0.25, 0.42, 0.68)


def render(mesh, renderer):
    """``(PIXELS, PIXELS, 3) uint8``: ``mesh`` lit by a key light from the camera and a fill light."""
    scene = pyrender.Scene(bg_color=(1.0, 1.0, 1.0, 1.0), ambient_light=(0.12, 0.12, 0.12))
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=(*COLOUR, 1.0), metallicFactor=0.0,
                                                  roughnessFactor=0.8)
    scene.add(pyrender.Mesh.from_trimesh(mesh, material=material, smooth=False))
    radius = np.linalg.norm(mesh.extents) / 2
    eye = VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION) * radius / np.sin(FOV / 2) * 1.05
    # sqfit.look_at gives an OpenCV camera (y down, z forward); pyrender's is OpenGL (y up, z back).
    pose = sqfit.look_at(eye, np.zeros(3)) @ np.diag([1.0, -1.0, -1.0, 1.0])
    scene.add(pyrender.PerspectiveCamera(yfov=FOV), pose=pose)
    scene.add(pyrender.DirectionalLight(intensity=2.2), pose=pose)
    fill = trimesh.transformations.rotation_matrix(np.pi / 2, (0, 0, 1)) @ pose
    scene.add(pyrender.DirectionalLight(intensity=0.8), pose=fill)
    colour, _ = renderer.render(scene)
    return colour


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    names = list(CATALOGUE)
    cols = 4
    rows = -(-len(names) // cols)
    renderer = pyrender.OffscreenRenderer(PIXELS, PIXELS)
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.9 * rows))
    for ax, name in zip(axes.flat, names):
        mesh = build_household(name, args.seed)
        ax.imshow(render(mesh, renderer))
        w, d, h = (100 * mesh.extents).round().astype(int)
        ax.set_title(f"{name}  {w} x {d} x {h} cm", fontsize=9)
    for ax in axes.flat:
        ax.set_axis_off()
    renderer.delete()
    fig.suptitle(f"sqsim.world.household: the {len(names)} kinds (seed {args.seed}; +z up, front to -y)", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)


if __name__ == "__main__":
    main()
