"""Sequence datasets: sqsim generate -> files (TUM, COCO with track ids) -> sqfit.views.load_sequence."""

import json
import subprocess

import numpy as np
import pytest

from sqfit.formats.tum import read_tum
from sqfit.views.dataset import load_trial
from sqfit.views.sequence import LazyImages, load_sequence
from sqsim.runs.generate import generate
from sqsim.world.scene import load_scene
from sqsim.imaging.sequence import simulate_sequence

from _datasets import SMALL_CAMERA, files, kill_generate_midway  # noqa: E402

SCENE = """
[experiment]
name = "seq-test"
seed = 3
trials = 1
""" + SMALL_CAMERA + """[trajectory]
kind = "orbit"
frames = 16
radius = 5.0
radius_amplitude = 1.0
height = 1.5
height_amplitude = 0.3
look_at = [0.0, 0.0, 0.3]
look_at_wander = 1.0
[objects]
count = 4
layout = "ground"
upright = true
size = [0.2, 0.5]
position = [-1.8, 1.8]
[masks]
min_area_px = 15
[noise]
erosion_px = 1
odometry_rotation_deg = 0.5
odometry_translation_m = 0.02
"""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq")
    (root / "scene.toml").write_text(SCENE)
    scene = load_scene(root / "scene.toml")
    summary = generate(scene, root / "d", progress=False)
    return scene, root / "d", summary


def test_generate_writes_a_sequence_that_loads_back_as_simulated(dataset):
    scene, out, summary = dataset
    assert summary["written"] == 1
    assert {p.name for p in out.iterdir()} == {"dataset.json", "annotations.json", "trials", "true.tum", "odometry.tum"}
    seq_dir = out / "trials" / "000000"
    assert {p.name for p in seq_dir.iterdir()} == {"cameras.json", "gt.json", "masks", "true.tum", "odometry.tum"}
    assert (out / "true.tum").read_bytes() == (seq_dir / "true.tum").read_bytes()
    loaded = load_sequence(out)
    memory = simulate_sequence(scene, seed=3, index=0)
    assert isinstance(loaded.images, LazyImages) and len(loaded.images) == 16
    np.testing.assert_array_equal(loaded.timestamps, memory.timestamps)
    np.testing.assert_allclose(loaded.true_poses, memory.true_poses, atol=1e-14)
    np.testing.assert_allclose(loaded.odometry_poses, memory.odometry_poses, atol=1e-14)
    for k in range(16):
        np.testing.assert_array_equal(loaded.images[k], memory.images[k])
    np.testing.assert_array_equal(loaded.observed, memory.observed)
    np.testing.assert_array_equal(loaded.object_ids, memory.object_ids)
    assert loaded.intrinsics == memory.intrinsics
    for oid, sq in memory.objects.items():
        np.testing.assert_allclose(loaded.objects[oid].to_vector(), sq.to_vector())
    assert load_sequence(seq_dir).name == loaded.name
    # the multi-view reader sees the odometry poses as the fitter's and the true ones as truth
    trial = load_trial(seq_dir)
    np.testing.assert_allclose(trial.cameras[5].pose, memory.odometry_poses[5], atol=1e-14)
    np.testing.assert_allclose(trial.true_cameras[5].pose, memory.true_poses[5], atol=1e-14)


def test_coco_has_track_ids_and_only_observed_pairs(dataset):
    from pycocotools.coco import COCO

    _, out, _ = dataset
    coco = COCO(str(out / "annotations.json"))
    seq = load_sequence(out)
    assert len(coco.dataset["images"]) == 16
    pairs = set()
    for img in coco.dataset["images"]:
        k = img["frame"]
        assert img["timestamp"] == seq.timestamps[k]
        np.testing.assert_allclose(img["T_world_camera"], seq.odometry_poses[k], atol=1e-14)
        for a in coco.loadAnns(coco.getAnnIds(imgIds=img["id"])):
            assert a["track_id"] == a["instance_id"] and isinstance(a["track_id"], int)
            np.testing.assert_array_equal(coco.annToMask(a).astype(bool), seq.images[k] == a["track_id"])
            pairs.add((k, a["track_id"]))
    expected = {(k, int(oid)) for k, i in zip(*np.nonzero(seq.observed)) for oid in [seq.object_ids[i]]}
    assert pairs == expected


def test_rerun_is_a_no_op(dataset, tmp_path):
    scene, out, _ = dataset
    before = files(out)
    summary = generate(scene, out, progress=False)
    assert summary["written"] == 0 and summary["skipped"] == 1
    assert files(out) == before


def test_evo_reads_the_trajectories_and_drift_grows_with_the_frames(dataset):
    pytest.importorskip("evo")
    from evo.core import metrics
    from evo.tools import file_interface

    _, out, _ = dataset
    ref = file_interface.read_tum_trajectory_file(str(out / "true.tum"))
    est = file_interface.read_tum_trajectory_file(str(out / "odometry.tum"))
    assert ref.num_poses == est.num_poses == 16
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    errors = ape.error
    assert errors[0] == pytest.approx(0.0, abs=1e-12)
    # the drift of a random walk grows: the last quarter is worse than the first quarter
    assert errors[12:].mean() > errors[1:5].mean() > 0


def test_evo_drift_grows_with_frame_count_over_seeds(tmp_path):
    """Average APE at the end of 8-, 16- and 32-step odometry over many seeds (no rendering)."""
    pytest.importorskip("evo")
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    from sqsim.world.odometry import integrate_odometry
    from sqsim.world.scene import parse_scene
    from sqsim.world.trajectory import sequence_poses

    s = parse_scene({"trajectory": {"kind": "orbit", "frames": 33, "radius": 5.0}})
    t, true = sequence_poses(s.trajectory)
    final = {8: [], 16: [], 32: []}
    for seed in range(60):
        odo = integrate_odometry(true, 0.5, 0.02, seed)
        for n in final:
            ape = metrics.APE(metrics.PoseRelation.translation_part)
            ape.process_data((PoseTrajectory3D(poses_se3=list(true[:n + 1]), timestamps=t[:n + 1]),
                              PoseTrajectory3D(poses_se3=list(odo[:n + 1]), timestamps=t[:n + 1])))
            final[n].append(ape.get_statistic(metrics.StatisticsType.rmse))
    means = [np.mean(final[n]) for n in (8, 16, 32)]
    assert means[0] < means[1] < means[2]


def test_killed_run_resumes_to_identical_bytes(tmp_path):
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text(SCENE.replace("trials = 1", "trials = 8").replace("frames = 16", "frames = 10"))
    generate(load_scene(scene_file), tmp_path / "full", progress=False)
    assert not (tmp_path / "full" / "true.tum").exists()  # several sequences: TUM files per sequence only
    cmd, done = kill_generate_midway(scene_file, tmp_path / "cut", 2, timeout_s=120)
    trials = tmp_path / "cut" / "trials"
    assert 2 <= done < 8
    for d in trials.glob("0*"):  # every finished sequence is complete
        assert {p.name for p in d.iterdir()} == {"cameras.json", "gt.json", "masks", "true.tum", "odometry.tum"}
        assert len(list((d / "masks").iterdir())) == 10
    assert subprocess.run(cmd, capture_output=True).returncode == 0
    assert files(tmp_path / "full") == files(tmp_path / "cut")


def test_reader_errors(dataset, tmp_path):
    _, out, _ = dataset
    with pytest.raises(OSError, match="sequence directory not found"):
        load_sequence(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="is not a sequence: no cameras.json"):
        load_sequence(tmp_path / "empty")
    two = tmp_path / "two" / "trials"
    (two / "000000").mkdir(parents=True)
    (two / "000001").mkdir()
    with pytest.raises(ValueError, match=r"holds 2 sequences under trials/; pass one of them"):
        load_sequence(tmp_path / "two")
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(out / "trials" / "000000", bad)
    (bad / "true.tum").write_text("\n".join((bad / "true.tum").read_text().splitlines()[:-1]) + "\n")
    with pytest.raises(ValueError, match=r"true\.tum has 15 poses whose timestamps do not match the 16 frames"):
        load_sequence(bad)
    meta = json.loads((bad / "cameras.json").read_text())
    del meta["sequence"]
    (bad / "cameras.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"is not a sequence .* sqfit.views.dataset.load_trial"):
        load_sequence(bad)
    (bad / "odometry.tum").unlink()
    meta["sequence"] = {"frames": 16}
    (bad / "cameras.json").write_text(json.dumps(meta))
    with pytest.raises(OSError, match=r"TUM trajectory file not found: .*odometry\.tum"):
        load_sequence(bad)


def test_user_sequence_without_ground_truth(dataset, tmp_path):
    """A sequence without gt.json or true.tum: observations are the non-empty masks."""
    import shutil

    _, out, _ = dataset
    user = tmp_path / "user"
    shutil.copytree(out / "trials" / "000000", user)
    (user / "gt.json").unlink()
    (user / "true.tum").unlink()
    seq = load_sequence(user)
    assert seq.true_poses is None and seq.objects == {}
    present = [set(np.unique(seq.images[k])) - {0} for k in range(seq.n_frames)]
    assert seq.object_ids.tolist() == sorted(set().union(*present))
    with pytest.raises(ValueError, match="has no true poses"):
        seq.cameras("true")
    assert read_tum(user / "odometry.tum")[1].shape == (16, 4, 4)
