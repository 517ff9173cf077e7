"""Export -> import -> fit against the native fit, on a generated dataset; prints a Markdown table.

    python scripts/formats_roundtrip.py scenes/paper.toml -o runs/roundtrip --trials 30 \
        --chains 1-2-3D 1-2-3D-3A default

Generates the dataset with ``--colmap`` (resuming if it exists), writes its cameras also as a TUM
trajectory (``DIR/tum/cameras.tum``, 30 Hz from t = 1.7e9 s in image order), the images' times 3 ms
after their poses as a TUM RGB-D ``rgb.txt`` list and the intrinsics (OpenCV principal point) as
``DIR/tum/camera.txt``; fits it natively (``sqfit fit DIR``) and through the import path with COLMAP
poses (``sqfit fit --coco DIR/annotations.json --poses DIR/sparse/0``) and with TUM poses
(``--poses DIR/tum/cameras.tum --intrinsics DIR/tum/camera.txt --image-times DIR/tum/rgb.txt``), all
with the same seed, and compares each import with the native records object by object: largest
parameter difference, objects differing by more than 1e-9, and the 3D IoU of the two fitted
superquadrics.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main(argv=None):
    from sqfit import DEFAULT_CHAIN
    from sqfit.cli import main as sqfit_main
    from sqfit.formats import read_pose_json, write_image_times, write_intrinsics, write_tum
    from sqfit.metrics import iou_3d
    from sqfit.geometry.superquadric import Superquadric
    from sqsim.cli import main as sqsim_main

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--chains", nargs="+", default=["1-2-3D", "1-2-3D-3A", "default"])
    p.add_argument("--seed", type=int, default=0, help="sampling seed of both fits")
    args = p.parse_args(argv)
    root = Path(args.output)
    sqsim_main(["generate", args.scene, "-o", str(root), "--trials", str(args.trials), "--colmap", "--no-progress"])
    cameras = read_pose_json(root / "annotations.json")  # each image's camera, as the native fit reads it
    intrinsics = {c.intrinsics for c in cameras.values()}
    if len(intrinsics) != 1:
        raise SystemExit(f"the TUM export needs one camera for all images; the scene has {len(intrinsics)}")
    tum = root / "tum"
    tum.mkdir(exist_ok=True)
    times = 1.7e9 + np.arange(len(cameras)) / 30.0
    write_tum(tum / "cameras.tum", times, np.stack([c.pose for c in cameras.values()]))
    write_image_times(tum / "rgb.txt", dict(zip(cameras, times + 0.003)))
    write_intrinsics(tum / "camera.txt", intrinsics.pop())
    sources = {"COLMAP": ["--poses", str(root / "sparse" / "0")],
               "TUM": ["--poses", str(tum / "cameras.tum"), "--intrinsics", str(tum / "camera.txt"),
                       "--image-times", str(tum / "rgb.txt")]}
    print("| chain | poses | objects | max abs param difference | objects differing > 1e-9 | 3D IoU native vs "
          "imported (min / median) | status equal |")
    print("|---|---|---|---|---|---|---|")
    for chain in args.chains:
        chain = DEFAULT_CHAIN if chain == "default" else chain
        common = ["--chain", chain, "--seed", str(args.seed), "--no-progress"]
        native = root / f"native-{chain}.jsonl"
        sqfit_main(["fit", str(root), "-o", str(native), *common])
        ref = {f"{r['trial']}/{r['object_id']}": r for r in map(json.loads, native.read_text().splitlines())}
        for source, poses in sources.items():
            imported = root / f"imported-{source.lower()}-{chain}.jsonl"
            sqfit_main(["fit", "--coco", str(root / "annotations.json"), *poses, "-o", str(imported), *common])
            got = {r["track_id"]: r for r in map(json.loads, imported.read_text().splitlines())}
            assert sorted(ref) == sorted(got), "the two fits cover different objects"
            both = [k for k in ref if ref[k]["params"] is not None and got[k]["params"] is not None]
            diffs = [float(np.abs(np.subtract(got[k]["params"], ref[k]["params"])).max()) for k in both]
            ious = [iou_3d(Superquadric.from_vector(got[k]["params"]), Superquadric.from_vector(ref[k]["params"]))
                    for k in both]
            same_status = all(got[k]["status"] == ref[k]["status"] for k in ref)
            print(f"| {chain} | {source} | {len(ref)} | {max(diffs):.1e} | {sum(d > 1e-9 for d in diffs)} | "
                  f"{min(ious):.3f} / {np.median(ious):.3f} | {same_status} |")


if __name__ == "__main__":
    main()
