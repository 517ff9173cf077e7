"""One object's mask under each segmenter-like mask model (:mod:`sqsim.imaging.mask_models`), against its clean outline.

    python scripts/mask_models_figure.py -o docs/figures/mask_models.png

The object is a mug-like silhouette (a rounded body and a thin handle) so that every model has
something to act on; each panel shows the model's mask (dark) and the clean outline (red). The
last two panels decode the mask's COCO polygons: polygons are merged as a union, so the
background enclosed by the handle comes back filled in both conventions.
"""

from __future__ import annotations

import argparse

import numpy as np

#: Image size (px) and the mug's geometry (px).
SIZE = (120, 140)
BODY = dict(top=25, bottom=100, left=25, right=90, corner=10)
HANDLE = dict(centre=(62, 90), outer=24, inner=20)
SEED = 3
#: Part of the image shown: (top, left, bottom, right), px.
VIEW = (12, 12, 112, 128)


def mug():
    """(h, w) bool: a rounded rectangle with a ring handle 4 px thick on its right."""
    from skimage.draw import disk

    m = np.zeros(SIZE, bool)
    b = BODY
    yy, xx = np.mgrid[0:SIZE[0], 0:SIZE[1]] + 0.5
    cy = np.clip(yy, b["top"] + b["corner"], b["bottom"] - b["corner"])
    cx = np.clip(xx, b["left"] + b["corner"], b["right"] - b["corner"])
    m |= (yy - cy) ** 2 + (xx - cx) ** 2 <= b["corner"] ** 2
    ring = np.zeros(SIZE, bool)
    ring[disk(HANDLE["centre"], HANDLE["outer"], shape=SIZE)] = True
    ring[disk(HANDLE["centre"], HANDLE["inner"], shape=SIZE)] = False
    ring[:, :b["right"]] = False
    return m | ring


def panels(mask):
    from sqfit.formats import decode_segmentation, mask_to_polygons
    from sqsim.imaging.mask_models import bias_boundary, punch_holes, remove_thin_parts, smooth_boundary_error

    return [
        ("clean", mask),
        ("boundary bias +1.5 px", bias_boundary(mask, 1.5)),
        ("boundary bias -1.5 px", bias_boundary(mask, -1.5)),
        ("smooth error 2 px RMS, 32 px wavelength", smooth_boundary_error(mask, 2.0, 32.0, rng=SEED)),
        ("thin parts < 5 px lost", remove_thin_parts(mask, 5.0)),
        ("holes: 4 per 1000 px, radius 2 px", punch_holes(mask, 4.0, 2.0, rng=SEED)),
        ("COCO polygons, OpenCV +0.5 (detectron2)\nrim lost, enclosed hole filled",
         decode_segmentation(mask_to_polygons(mask, "opencv"), *mask.shape)),
        ("COCO polygons, skimage at 0.5\nexact outline, enclosed hole filled",
         decode_segmentation(mask_to_polygons(mask, "skimage"), *mask.shape)),
    ]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="docs/figures/mask_models.png")
    args = parser.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from skimage import measure

    clean = mug()
    outline = measure.find_contours(np.pad(clean, 1).astype(np.uint8), 0.5)
    items = panels(clean)
    fig, axes = plt.subplots(2, 4, figsize=(12, 6.6))
    for ax, (title, mask) in zip(axes.ravel(), items):
        ax.imshow(mask, cmap="Greys", vmin=-0.6, vmax=1.3, interpolation="nearest")
        for c in outline:  # find_contours' (row, col) of the padded image -> imshow's pixel-centre axes
            ax.plot(c[:, 1] - 1, c[:, 0] - 1, color="tab:red", lw=0.8)
        changed = int((mask != clean).sum())
        ax.set_title(f"{title}\n{changed} px changed" if title != "clean" else "clean\n(red: its outline)",
                     fontsize=9)
        ax.set_xlim(VIEW[1] - 0.5, VIEW[3] - 0.5)
        ax.set_ylim(VIEW[2] - 0.5, VIEW[0] - 0.5)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
