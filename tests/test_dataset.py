import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import sqfit
from sqfit.views.dataset import iter_trials, load_trial, observations, read_mask_png, trial_dirs, write_mask_png
from sqsim.runs.generate import generate
from sqsim.world.scene import load_scene

from _datasets import files, kill_generate_midway, small_scene  # noqa: E402
from _helpers import kill_group, popen_interruptible  # noqa: E402

SCENE = small_scene(5, 4, {"erosion_px": 1, "pose_rotation_deg": 0.5})

@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def test_generate_writes_the_format_and_coco(scene_file, tmp_path):
    from pycocotools.coco import COCO

    out = tmp_path / "d"
    summary = generate(load_scene(scene_file), out, progress=False)
    assert summary["written"] == 4 and summary["skipped"] == 0
    assert [p.name for p in trial_dirs(out)] == ["000000", "000001", "000002", "000003"]
    meta = json.loads((out / "dataset.json").read_text())
    assert meta["format"] == "sqkit-dataset" and meta["seed"] == 5 and meta["trials"] == 4
    coco = COCO(str(out / "annotations.json"))
    assert len(coco.dataset["images"]) == 12
    for img in coco.dataset["images"]:
        png = read_mask_png(out / img["file_name"])
        assert png.dtype == np.uint16 and png.shape == (img["height"], img["width"])
        anns = coco.loadAnns(coco.getAnnIds(imgIds=img["id"]))
        assert {a["instance_id"] for a in anns} == set(np.unique(png)) - {0}
        for a in anns:
            np.testing.assert_array_equal(coco.annToMask(a).astype(bool), png == a["instance_id"])
            assert a["area"] == (png == a["instance_id"]).sum()
        assert img["intrinsics"]["fx"] == 100.0 and np.asarray(img["T_world_camera"]).shape == (4, 4)
    assert {c["name"] for c in coco.dataset["categories"]} >= {"superquadric", "box", "mesh"}

    trial = load_trial(out / "trials" / "000001")
    assert trial.images.shape == (3, 120, 160) and trial.object_ids == [1, 2]
    assert len(trial.objects[0]["params"]) == 11 and trial.gt["trial"] == 1
    assert not np.allclose(trial.cameras[0].pose, trial.true_cameras[0].pose)  # pose noise
    obs = observations(trial, 1, n_samples=50, rng=0)
    assert len(obs) >= 2 and obs[0].samples.shape == (50, 2)
    assert len(list(iter_trials(out))) == 4

    before = files(out)
    again = generate(load_scene(scene_file), out, progress=False)
    assert again["written"] == 0 and again["skipped"] == 4
    assert files(out) == before  # nothing new, byte for byte (annotations rebuilt identically)


def test_same_bytes_for_any_worker_count_and_resume(scene_file, tmp_path):
    scene = load_scene(scene_file)
    generate(scene, tmp_path / "a", progress=False)
    generate(scene, tmp_path / "b", trials=2, progress=False)  # a partial run...
    (tmp_path / "b" / "trials" / ".tmp-000002-999").mkdir()  # ...killed while writing trial 2
    (tmp_path / "b" / "trials" / ".tmp-000002-999" / "gt.json").write_text("{")
    generate(scene, tmp_path / "b", trials=4, workers=2, progress=False)
    assert files(tmp_path / "a") == files(tmp_path / "b")


def test_killed_run_resumes_to_identical_dataset(scene_file, tmp_path):
    scene_file.write_text(SCENE.replace("trials = 4", "trials = 40"))
    generate(load_scene(scene_file), tmp_path / "full", progress=False)
    cmd, done = kill_generate_midway(scene_file, tmp_path / "cut", 5)
    trials = tmp_path / "cut" / "trials"
    assert 5 <= done < 40
    for d in trials.glob("0*"):  # every finished trial is complete
        assert {p.name for p in d.iterdir()} == {"cameras.json", "gt.json", "masks"}
    assert subprocess.run(cmd, capture_output=True).returncode == 0
    assert files(tmp_path / "full") == files(tmp_path / "cut")


def test_refuses_a_different_scene_or_seed(scene_file, tmp_path):
    scene = load_scene(scene_file)
    generate(scene, tmp_path / "d", trials=1, progress=False)
    with pytest.raises(ValueError, match="different scene or seed"):
        generate(scene, tmp_path / "d", trials=1, seed=6, progress=False)
    with pytest.raises(ValueError, match="different scene or seed"):
        generate(scene.with_overrides({"noise.dropout": 0.1}), tmp_path / "d", trials=1, progress=False)
    (tmp_path / "d" / "dataset.json").write_text("{")
    with pytest.raises(ValueError, match="is not valid JSON"):
        generate(scene, tmp_path / "d", trials=1, progress=False)
    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        generate(scene, tmp_path / "e", workers=0, progress=False)


def test_cli_generate_and_errors(scene_file, tmp_path):
    run = lambda *a: subprocess.run([sys.executable, "-m", "sqsim.cli", "generate", *a],  # noqa: E731
                                    capture_output=True, text=True)
    ok = run(str(scene_file), "-o", str(tmp_path / "d"), "--trials", "1", "--no-progress")
    assert ok.returncode == 0 and "1 trial(s) written" in ok.stdout
    missing = run(str(tmp_path / "nope.toml"), "-o", str(tmp_path / "x"))
    assert missing.returncode == 2 and "scene file not found" in missing.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("[noise]\nblur = 1\n")
    out = run(str(bad), "-o", str(tmp_path / "x"))
    assert out.returncode == 2 and "unknown key 'blur' in [noise]" in out.stderr and "bad.toml" in out.stderr
    assert not (tmp_path / "x").exists()


def user_trial(tmp_path, poses=None, mask_shape=(48, 64)):
    """A real user's trial: cameras.json without true poses, masks, no gt.json."""
    intr = sqfit.Intrinsics(64, 48, 40.0, 30.0, 32.0, 24.0)
    d = tmp_path / "mine"
    (d / "masks").mkdir(parents=True)
    poses = poses or [sqfit.look_at([10.0 * np.cos(a), 10.0 * np.sin(a), 0], [0, 0, 0]) for a in (0, 2)]
    views = []
    for k, T in enumerate(poses):
        image = np.zeros(mask_shape, np.uint16)
        image[20:30, 25:40] = 3
        write_mask_png(d / "masks" / f"view_{k:02d}.png", image)
        views.append({"intrinsics": intr.to_dict(), "T_world_camera": np.asarray(T).tolist()})
    (d / "cameras.json").write_text(json.dumps({"views": views}))
    return d


def test_user_data_without_ground_truth(tmp_path):
    d = user_trial(tmp_path)
    trial = load_trial(d)
    assert trial.true_cameras is None and trial.objects == [] and trial.object_ids == [3]
    assert [t.name for t in iter_trials(d)] == ["mine"]
    obs = observations(trial, 3, n_samples=20, sampling="contour", rng=1)
    assert len(obs) == 2 and obs[0].area_px == 150
    assert observations(trial, 4) == []


def test_png_round_trip_is_exact_and_deterministic(tmp_path):
    image = np.random.default_rng(0).integers(0, 65536, (30, 40)).astype(np.uint16)
    write_mask_png(tmp_path / "a.png", image)
    write_mask_png(tmp_path / "b.png", image)
    np.testing.assert_array_equal(read_mask_png(tmp_path / "a.png"), image)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_png_is_8_bit_for_small_ids_and_16_bit_otherwise(tmp_path):
    from PIL import Image

    small = np.zeros((6, 7), np.uint16)
    small[2:4, 1:5] = 255
    write_mask_png(tmp_path / "s.png", small)
    write_mask_png(tmp_path / "w.png", small.astype(np.int64) + 256 * (small > 0))
    with Image.open(tmp_path / "s.png") as a, Image.open(tmp_path / "w.png") as b:
        assert a.mode == "L" and b.mode.startswith("I")
    got = read_mask_png(tmp_path / "s.png")
    assert got.dtype == np.uint16 and np.array_equal(got, small)
    assert np.array_equal(read_mask_png(tmp_path / "w.png"), small.astype(np.int64) + 256 * (small > 0))
    with pytest.raises(ValueError, match=r"instance ids in \[0, 65535\]"):
        write_mask_png(tmp_path / "x.png", np.full((2, 2), 70000))
    with pytest.raises(ValueError, match=r"instance ids in \[0, 65535\]"):
        write_mask_png(tmp_path / "x.png", np.full((2, 2), -1))
    with pytest.raises(ValueError, match="must hold integer instance ids, got dtype float64"):
        write_mask_png(tmp_path / "x.png", np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"must have shape \(h, w\)"):
        write_mask_png(tmp_path / "x.png", np.zeros((2, 2, 2), np.uint16))


@pytest.mark.parametrize("dtype, top", [(np.uint8, 255), (">u2", 65535)])
def test_encoded_png_decodes_the_same_in_pillow_and_opencv(tmp_path, dtype, top):
    import io

    import cv2
    from PIL import Image

    from sqfit.views.dataset import encode_png

    image = np.random.default_rng(1).integers(0, top + 1, (37, 53)).astype(dtype)
    image[5:30] = 0  # long runs, as in masks
    png = encode_png(image)
    with Image.open(io.BytesIO(png)) as im:
        im.load()
        assert np.array_equal(np.array(im).astype(np.int64), image.astype(np.int64))
    decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(decoded.astype(np.int64), image.astype(np.int64))
    with pytest.raises(ValueError, match="must be .h, w. uint8 or big-endian uint16, got <u2"):
        encode_png(image.astype("<u2"))


def test_resuming_a_dataset_of_another_format_version_is_refused(scene_file, tmp_path):
    generate(load_scene(scene_file), tmp_path / "d", trials=1, progress=False)
    meta = json.loads((tmp_path / "d" / "dataset.json").read_text())
    (tmp_path / "d" / "dataset.json").write_text(json.dumps({**meta, "version": 1}))
    with pytest.raises(ValueError, match=r"holds a dataset of another format/version \('sqkit-dataset' v1\)"):
        generate(load_scene(scene_file), tmp_path / "d", trials=2, progress=False)


def test_reader_errors(tmp_path):
    with pytest.raises(OSError, match="trial directory not found"):
        load_trial(tmp_path / "none")
    with pytest.raises(OSError, match="dataset directory not found"):
        list(iter_trials(tmp_path / "none"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(OSError, match="is not a dataset"):
        list(iter_trials(tmp_path / "empty"))
    with pytest.raises(OSError, match="file not found: .*cameras.json"):
        load_trial(tmp_path / "empty")
    d = user_trial(tmp_path)
    (d / "cameras.json").write_text("{\"views\": [")
    with pytest.raises(ValueError, match="cameras.json is not valid JSON"):
        load_trial(d)
    (d / "cameras.json").write_text("{\"views\": []}")
    with pytest.raises(ValueError, match="non-empty list 'views'"):
        load_trial(d)
    shutil.rmtree(d)
    d = user_trial(tmp_path, poses=[np.full((4, 4), np.nan), np.eye(4)])
    with pytest.raises(ValueError, match="view 0: .*NaN"):
        load_trial(d)
    shutil.rmtree(d)
    d = user_trial(tmp_path, mask_shape=(40, 64))
    with pytest.raises(ValueError, match=r"mask has shape \(40, 64\), intrinsics say"):
        load_trial(d)
    (d / "masks" / "view_01.png").unlink()
    (d / "masks" / "view_00.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="cannot read mask image"):
        load_trial(d)
    with pytest.raises(OSError, match="mask file not found"):
        read_mask_png(d / "masks" / "view_01.png")


def test_ctrl_c_with_workers_stops_cleanly(scene_file, tmp_path):
    # Ctrl-C reaches the whole process group: the run must stop promptly (no hang, however many
    # trials are left), exit 130, and leave only complete trials that a re-run accepts. A million
    # trials cannot finish before the signal, so the test cannot pass by the run ending on its own.
    scene_file.write_text(SCENE.replace("trials = 4", "trials = 1000000"))
    out = tmp_path / "d"
    cmd = [sys.executable, "-m", "sqsim.cli", "generate", str(scene_file), "-o", str(out), "--workers", "2",
           "--no-progress"]
    # The run must start with SIGINT at its default, as from a terminal (popen_interruptible): a
    # run started with SIGINT ignored rightly goes on, which made this test hang whenever the suite
    # itself ran in the background.
    proc = popen_interruptible(cmd, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and proc.poll() is None and not list((out / "trials").glob("0*")):
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before it was interrupted"
        assert list((out / "trials").glob("0*")), "no trial written in 120 s"
        os.killpg(proc.pid, signal.SIGINT)
        sent = time.time()
        _, err = proc.communicate(timeout=60)
        stopped = time.time() - sent
    finally:
        # whatever failed above, leave no worker of the group running (a failed run once left two
        # workers rendering a million trials for the rest of the session)
        kill_group(proc)
    assert stopped < 20, f"took {stopped:.1f} s to stop"
    assert proc.returncode == 130 and "interrupted" in err
    names = [p.name for p in (out / "trials").iterdir()]
    assert 1 <= len(names) < 1000 and not [n for n in names if n.startswith(".")]
    for name in names:
        load_trial(out / "trials" / name)


def test_dask_local_cluster_writes_the_same_bytes(scene_file, tmp_path):
    distributed = pytest.importorskip("distributed")
    scene = load_scene(scene_file)
    generate(scene, tmp_path / "one", workers=1, progress=False)
    # One worker process with two threads: the threads share (and take turns on) its renderer.
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True,
                                  dashboard_address=None) as cluster:
        summary = generate(scene, tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False)
    assert summary["written"] == 4
    assert files(tmp_path / "one") == files(tmp_path / "dask")


def test_generate_unreachable_scheduler(scene_file, tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    import sqsim.runs.parallel

    monkeypatch.setattr(sqsim.runs.parallel, "CONNECT_TIMEOUT_S", 2)
    with pytest.raises(OSError, match="cannot connect to the Dask scheduler 'tcp://127.0.0.1:9'"):
        generate(load_scene(scene_file), tmp_path / "d", scheduler="tcp://127.0.0.1:9", progress=False)
