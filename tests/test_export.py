"""Round trip: sqsim generate --colmap, then sqfit fit --coco/--poses == sqfit fit on the native dataset."""

import json

import numpy as np
import pytest

from sqfit.cli import main as sqfit_main
from sqfit.formats import (read_coco, read_colmap, read_pose_json, write_image_times, write_intrinsics,
                           write_tum)
from sqfit.views.dataset import load_trial, trial_dirs
from sqsim.cli import main as sqsim_main

pytest.importorskip("pycolmap")

from _datasets import small_scene  # noqa: E402

SCENE = small_scene(11, 3, {"boundary_jitter_px": 0.5, "pose_rotation_deg": 0.5, "pose_translation_m": 0.05})

@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    (root / "scene.toml").write_text(SCENE)
    assert sqsim_main(["generate", str(root / "scene.toml"), "-o", str(root / "d"), "--colmap",
                       "--no-progress"]) == 0
    return root / "d"


def records(path):
    return [json.loads(x) for x in path.read_text().splitlines()]


def assert_same_fits(native, imported):
    """Records of a native fit and of an import of the same dataset: same objects, views and parameters."""
    ref = {f"{r['trial']}/{r['object_id']}": r for r in records(native)}
    got = {r["track_id"]: r for r in records(imported)}
    assert sorted(got) == sorted(ref) and len(got) == 6
    for key, r in got.items():
        assert r["status"] == ref[key]["status"] == "ok", key
        assert r["views"] == ref[key]["views"] and r["dropped_views"] == ref[key]["dropped_views"]
        np.testing.assert_allclose(r["params"], ref[key]["params"], rtol=1e-9, atol=1e-9, err_msg=key)
        for a, b in zip(r["stages"], ref[key]["stages"]):
            np.testing.assert_allclose(a["superquadric"], b["superquadric"], rtol=1e-9, atol=1e-9)


def test_exported_model_and_coco_hold_every_view(dataset):
    model = read_colmap(dataset / "sparse" / "0")
    assert sorted(p.name for p in (dataset / "sparse" / "0").iterdir()) == \
        ["cameras.txt", "frames.txt", "images.txt", "points3D.txt", "rigs.txt"]
    coco = read_coco(dataset / "annotations.json")
    assert sorted(model) == sorted(im.file_name for im in coco.images.values())
    for path in trial_dirs(dataset):
        trial = load_trial(path)
        for v, cam in enumerate(trial.cameras):  # the fitter's (noisy) pose, not the true one
            got = model[f"trials/{path.name}/masks/view_{v:02d}.png"]
            np.testing.assert_allclose(got.pose, cam.pose, atol=1e-12)
            assert got.intrinsics == cam.intrinsics
    assert list(coco.tracks) == [f"{t:06d}/{k}" for t in range(3) for k in (1, 2)]


def test_export_import_fit_equals_native_fit(dataset, tmp_path):
    native, imported = tmp_path / "native.jsonl", tmp_path / "imported.jsonl"
    args = ["--chain", "1-2-3D", "--seed", "3", "--samples", "50", "--no-progress"]
    assert sqfit_main(["fit", str(dataset), "-o", str(native), *args]) == 0
    assert sqfit_main(["fit", "--coco", str(dataset / "annotations.json"), "--poses", str(dataset / "sparse" / "0"),
                       "-o", str(imported), *args]) == 0
    assert_same_fits(native, imported)


def test_model_is_rebuilt_deterministically_on_resume(dataset, tmp_path):
    before = {p.name: p.read_bytes() for p in (dataset / "sparse" / "0").iterdir()}
    assert sqsim_main(["generate", str(dataset.parent / "scene.toml"), "-o", str(dataset), "--colmap",
                       "--no-progress"]) == 0
    after = {p.name: p.read_bytes() for p in (dataset / "sparse" / "0").iterdir()}
    assert after == before
    assert not [p for p in (dataset / "sparse").iterdir() if p.name.startswith(".")]


def test_imported_observations_are_the_native_ones(dataset):
    from sqfit.views.imported import load_import, observe_track, track_rng
    from sqfit.views.dataset import object_rng, observe_views

    scene = load_import(dataset / "annotations.json", dataset / "sparse" / "0")
    trial = load_trial(dataset / "trials" / "000001")
    for oid in (1, 2):
        imported = observe_track(scene, f"000001/{oid}", 30, rng=track_rng(7, f"000001/{oid}"))
        native = observe_views(trial.cameras, trial.images, oid, 30, rng=object_rng(7, "000001", oid))
        assert imported.views == native.views and imported.names[0] == "trials/000001/masks/view_00.png"
        for a, b in zip(imported.observations, native.observations):
            np.testing.assert_array_equal(a.samples, b.samples)  # same masks, same seed: same samples
            np.testing.assert_array_equal(a.contour, b.contour)
            np.testing.assert_allclose(a.camera.pose, b.camera.pose, atol=1e-12)  # via COLMAP quaternions


def test_readme_round_trip_commands_run(tmp_path):
    """The README's documented commands, on 2 paper trials in a temporary directory."""
    import re
    import shlex
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    text = (root / "README.md").read_text()
    block = next(b for b in re.findall(r"```bash\n(.*?)```", text, flags=re.S) if "sqfit fit --coco runs/" in b)
    lines = [line.split("#")[0] for line in block.strip().splitlines()]
    assert [shlex.split(x)[:2] for x in lines] == [[".venv/bin/sqsim", "generate"], [".venv/bin/sqfit", "fit"],
                                                    [".venv/bin/sqfit", "fit"]]
    for line in lines:
        args = shlex.split(line.replace("runs/coco-demo", str(tmp_path / "demo")).replace("--trials 30", "--trials 2"))
        cmd = [sys.executable, "-m", f"{Path(args[0]).name}.cli", *args[1:], "--no-progress"]
        res = subprocess.run(cmd, cwd=root, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
    imported = records(tmp_path / "demo" / "fits.jsonl")
    native = {f"{r['trial']}/{r['object_id']}": r for r in records(tmp_path / "demo" / "native.jsonl")}
    assert len(imported) == 2 and all(r["status"] == "ok" for r in imported)
    assert all(native[r["track_id"]]["status"] == "ok" for r in imported)


def test_json_poses_of_the_coco_file_reproduce_native_fits_exactly(dataset, tmp_path):
    # annotations.json carries file_name, intrinsics and T_world_camera per image: a JSON pose file.
    # Without COLMAP's quaternion rounding the import is bit-identical to the native fit, any chain.
    native, imported = tmp_path / "native.jsonl", tmp_path / "imported.jsonl"
    args = ["--seed", "3", "--samples", "50", "--no-progress"]  # default chain
    assert sqfit_main(["fit", str(dataset), "-o", str(native), *args]) == 0
    coco = str(dataset / "annotations.json")
    assert sqfit_main(["fit", "--coco", coco, "--poses", coco, "-o", str(imported), *args]) == 0
    ref = {f"{r['trial']}/{r['object_id']}": r["params"] for r in records(native)}
    assert {r["track_id"]: r["params"] for r in records(imported)} == ref


def test_tum_trajectory_import_fits_as_native(dataset, tmp_path):
    # Each image's camera (from annotations.json: the fitter's noisy pose, as the native fit reads it)
    # as a 30 Hz TUM trajectory, the image times 3 ms after their poses as a TUM RGB-D rgb.txt, and the
    # intrinsics with OpenCV's principal point: the import gives the native fit.
    cameras = read_pose_json(dataset / "annotations.json")
    times = 1.7e9 + np.arange(len(cameras)) / 30.0
    write_tum(tmp_path / "cameras.tum", times, np.stack([c.pose for c in cameras.values()]))
    write_image_times(tmp_path / "rgb.txt", dict(zip(cameras, times + 0.003)))
    (intrinsics,) = {c.intrinsics for c in cameras.values()}
    write_intrinsics(tmp_path / "camera.txt", intrinsics)
    native, imported = tmp_path / "native.jsonl", tmp_path / "imported.jsonl"
    args = ["--chain", "1-2-3D", "--seed", "3", "--samples", "50", "--no-progress"]
    assert sqfit_main(["fit", str(dataset), "-o", str(native), *args]) == 0
    assert sqfit_main(["fit", "--coco", str(dataset / "annotations.json"), "--poses", str(tmp_path / "cameras.tum"),
                       "--intrinsics", str(tmp_path / "camera.txt"), "--image-times", str(tmp_path / "rgb.txt"),
                       "-o", str(imported), *args]) == 0
    assert_same_fits(native, imported)
