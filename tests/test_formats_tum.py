"""TUM trajectories as the pose source of sqfit fit --coco: intrinsics, image timestamps, time matching."""

import json
import subprocess
import sys

import numpy as np
import pytest

import sqfit
from sqfit.cli import main
from sqfit.formats import (encode_mask, match_trajectory, read_image_times, read_intrinsics, write_image_times,
                           write_intrinsics, write_pose_json, write_tum)
from sqfit.views.imported import load_import, read_poses
from sqfit.formats.coco import CocoImage
from sqfit.views.imported import track_rng
from sqfit.formats.trajectory import associate, image_timestamps
from sqfit.views.dataset import observe_views
from sqfit.testing import paper_trial


pytest.importorskip("pycocotools")

def records(path):
    return [json.loads(x) for x in path.read_text().splitlines()]


# --- conventions ----------------------------------------------------------------------------------

def test_known_tum_pose_and_opencv_principal_point(tmp_path):
    # A camera at (0, -3, 0) looking along world +y with its y axis (down) along world -z: the rotation
    # camera -> world is Rx(-90 deg), quaternion (qx, qy, qz, qw) = (-sqrt(1/2), 0, 0, sqrt(1/2)).
    (tmp_path / "traj.tum").write_text("# t tx ty tz qx qy qz qw\n"
                                       "7.25 0 -3 0 -0.7071067811865476 0 0 0.7071067811865476\n")
    images = {1: CocoImage(1, "rgb/7.250000.png", 640, 480)}
    K = read_intrinsics("400 300 319.5 239.5 640 480")  # OpenCV: top-left pixel centre at (0, 0)
    assert K == sqfit.Intrinsics(640, 480, 400.0, 300.0, 320.0, 240.0)
    cameras, unusable = match_trajectory(images, tmp_path / "traj.tum", K)
    assert unusable == {}
    cam = cameras[1]
    np.testing.assert_allclose(cam.pose, [[1, 0, 0, 0], [0, 0, 1, -3], [0, -1, 0, 0], [0, 0, 0, 1]], atol=1e-15)
    # (0.5, 0, 0.25) is at (x, y, z) = (0.5, -0.25, 3) in the camera: right of and above the optical axis.
    uv, depth = sqfit.project(cam, np.array([[0.5, 0.0, 0.25], [0.0, 5.0, 0.0]]))
    np.testing.assert_allclose(depth, [3.0, 8.0])
    np.testing.assert_allclose(uv, [[400 * 0.5 / 3 + 320, 300 * -0.25 / 3 + 240], [320, 240]])
    # OpenCV puts pixel (row 239, column 319)'s centre at (319, 239): a principal point there projects the
    # optical axis to the centre of that same pixel in sqfit's grid, (319.5, 239.5).
    on_axis = sqfit.Camera(read_intrinsics("400 300 319 239 640 480"), cam.pose)
    assert sqfit.project(on_axis, np.array([[0.0, 5.0, 0.0]]))[0].tolist() == [[319.5, 239.5]]
    assert read_intrinsics("400 300 320 240 640 480", convention="sqfit") == K


def test_intrinsics_forms_round_trip(tmp_path):
    K = sqfit.Intrinsics(640, 480, 517.3, 516.5, 318.6, 255.3)
    for convention in ("opencv", "sqfit"):
        write_intrinsics(tmp_path / f"{convention}.txt", K, convention)
        assert read_intrinsics(tmp_path / f"{convention}.txt", convention) == K
        assert read_intrinsics(str(tmp_path / f"{convention}.txt"), convention) == K
    assert (tmp_path / "opencv.txt").read_text().splitlines()[1].split()[2] == "318.1"
    (tmp_path / "k.json").write_text(json.dumps({"fx": 517.3, "fy": 516.5, "cx": 318.1, "cy": 254.8,
                                                 "width": 640, "height": 480}))
    assert read_intrinsics(tmp_path / "k.json") == K
    assert read_intrinsics({"fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3, "width": 640, "height": 480},
                           "sqfit") == K
    assert read_intrinsics("517.3, 516.5, 318.1, 254.8, 640, 480") == K
    assert read_intrinsics([517.3, 516.5, 318.1, 254.8, 640, 480]) == K
    assert read_intrinsics(np.array([517.3, 516.5, 318.6, 255.3, 640, 480]), "sqfit") == K
    assert read_intrinsics(K, "opencv") is K  # an Intrinsics is sqfit's already


@pytest.mark.parametrize("source, match", [
    ("517.3 516.5 318.6 255.3", r"expected 6 numbers 'fx fy cx cy width height', got 4: add the image size"),
    ("517.3 516.5 318.6 255.3 0.26 -0.95 -0.005 0.003 1.16", r"got 9: distortion coefficients cannot be used"),
    ("500 500 320 240 640.5 480", "width must be a positive integer"),
    ("-500 500 320 240 640 480", "fx must be a finite number > 0"),
    ({"fx": 1, "fy": 1, "cx": 0, "cy": 0, "width": 4}, r"needs exactly the keys .*; missing \['height'\]"),
    ({"fx": 1, "fy": 1, "cx": 0, "cy": 0, "width": 4, "height": 4, "k1": 0.1}, r"unknown \['k1'\]"),
    ({"fx": 1, "fy": 1, "cx": "0", "cy": 0, "width": 4, "height": 4}, "cx must be a number, got '0'"),
    ({"fx": None, "fy": 1, "cx": 0, "cy": 0, "width": 4, "height": 4}, "fx must be a number, got None"),
    ({"fx": 1, "fy": 1, "cx": 0, "cy": 0, "width": "4", "height": 4}, "width must be a number, got '4'"),
    ("1 2 3 4 5", r"expected 6 numbers 'fx fy cx cy width height', got 5$"),
    ((500, 500, 320, 240), "got 4: add the image size"),
    (["500", "x", 1, 1, 1, 1], r"expected the numbers 'fx fy cx cy width height', got '500 x 1 1 1 1'"),
    (525.0, "intrinsics must be a sqfit.Intrinsics, a dict, six numbers .* or a file, got float"),
])
def test_bad_intrinsics(source, match):
    with pytest.raises(ValueError, match=match):
        read_intrinsics(source)


def test_bad_intrinsics_files(tmp_path):
    with pytest.raises(OSError, match=r"intrinsics file not found: .*nope.txt \(give a file, or the numbers"):
        read_intrinsics(tmp_path / "nope.txt")
    with pytest.raises(OSError, match="intrinsics file not found: cam.yaml"):
        read_intrinsics("cam.yaml")
    (tmp_path / "k.txt").write_text("# my camera\nfx=500 500 320 240 640 480\n")
    with pytest.raises(ValueError, match=r"intrinsics file .*k.txt: expected the numbers 'fx fy cx cy width "
                                         r"height', got 'fx=500"):
        read_intrinsics(tmp_path / "k.txt")
    (tmp_path / "k.json").write_text("{oops")
    with pytest.raises(ValueError, match=r"intrinsics file .*k.json is not valid JSON"):
        read_intrinsics(tmp_path / "k.json")
    (tmp_path / "l.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="must be an object with keys fx, fy, cx, cy, width, height"):
        read_intrinsics(tmp_path / "l.json")
    with pytest.raises(ValueError, match=r"intrinsics convention must be one of \['opencv', 'sqfit'\], got 'ros'"):
        read_intrinsics("1 1 0 0 4 4", convention="ros")
    with pytest.raises(ValueError, match="intrinsics convention must be one of"):
        write_intrinsics(tmp_path / "x.txt", sqfit.Intrinsics(4, 4, 1, 1, 2, 2), "ros")


# --- image timestamps and association -------------------------------------------------------------

def test_image_times_list_like_tum_rgb_txt(tmp_path):
    (tmp_path / "rgb.txt").write_text("# color images\n# timestamp filename\n"
                                      "1305031102.175304 rgb/1305031102.175304.png\n"
                                      "1305031102.211214\trgb/1305031102.211214.png 1305031102.2 depth/x.png\n\n")
    assert read_image_times(tmp_path / "rgb.txt") == {"rgb/1305031102.175304.png": 1305031102.175304,
                                                      "rgb/1305031102.211214.png": 1305031102.211214}
    write_image_times(tmp_path / "out.txt", {"a/b.png": 0.1, "c.png": 1e9 + 1 / 3})
    assert read_image_times(tmp_path / "out.txt") == {"a/b.png": 0.1, "c.png": 1e9 + 1 / 3}


def test_image_time_list_errors(tmp_path):
    with pytest.raises(OSError, match="image timestamp list not found"):
        read_image_times(tmp_path / "rgb.txt")
    with pytest.raises(ValueError, match="image name 'a b.png' cannot be written"):
        write_image_times(tmp_path / "x.txt", {"a b.png": 1.0})
    with pytest.raises(ValueError, match="timestamp of 'a.png' must be finite"):
        write_image_times(tmp_path / "x.txt", {"a.png": float("nan")})


def test_image_timestamps_from_names_or_list():
    images = {1: CocoImage(1, "rgb/1305031102.175304.png", 4, 4), 2: CocoImage(2, "frame_0001.png", 4, 4),
              3: CocoImage(3, "nan.png", 4, 4)}
    times, unusable = image_timestamps(images)
    assert times == {1: 1305031102.175304}
    assert unusable[2] == ("image 'frame_0001.png': its file name stem 'frame_0001' is not a timestamp in seconds; "
                           "name the images by time (rgb/1305031102.175304.png) or give a list 'timestamp "
                           "filename' (--image-times rgb.txt)")
    assert "stem 'nan' is not a timestamp" in unusable[3]
    times, unusable = image_timestamps(images, {"frames/frame_0001.png": 5.0, "x/nan.png": 6.0, "y/nan.png": 7.0},
                                       source="list.txt")
    assert times == {2: 5.0}
    assert unusable[1] == ("image 'rgb/1305031102.175304.png' is not in list.txt: no entry with this file name or "
                           "base name")
    assert "base name matches 2 entries (x/nan.png, y/nan.png)" in unusable[3]


def test_associate_nearest_in_time():
    traj = np.array([1.0, 2.0, 3.0])
    index, diff = associate([0.5, 1.4, 1.5, 1.6, 2.0, 9.0], traj)
    assert index.tolist() == [0, 0, 0, 1, 1, 2]  # a tie takes the earlier pose
    np.testing.assert_allclose(diff, [0.5, 0.4, 0.5, 0.4, 0.0, 6.0])
    assert associate([], traj)[0].tolist() == []
    with pytest.raises(ValueError, match="trajectory_times is empty"):
        associate([1.0], [])
    with pytest.raises(ValueError, match="trajectory_times must be strictly increasing"):
        associate([1.0], [2.0, 1.0])
    with pytest.raises(ValueError, match=r"times must have shape \(n,\)"):
        associate([[1.0]], traj)


def test_match_trajectory_flags_far_and_mis_sized_images():
    K = sqfit.Intrinsics(640, 480, 400, 300, 320, 240)
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = [1, 2, 3]
    images = {1: CocoImage(1, "10.019.png", 640, 480), 2: CocoImage(2, "10.5.png", 640, 480),
              3: CocoImage(3, "11.png", 320, 240), 4: CocoImage(4, "x.png", 640, 480)}
    cameras, unusable = match_trajectory(images, (np.array([10.0, 11.0]), poses), K, source="t.tum")
    assert list(cameras) == [1] and np.array_equal(cameras[1].pose, np.eye(4))
    assert list(unusable) == [2, 3, 4]
    assert unusable[2] == ("image '10.5.png' (t = 10.500000 s) has no pose in t.tum within 0.02 s: the nearest is "
                           "0.5 s away (t = 10.000000 s; --max-time-diff)")
    assert unusable[3] == "image '11.png' is 320x240 in COCO but the intrinsics are 640x480"
    cameras, _ = match_trajectory(images, (np.array([10.0, 11.0]), poses), K, max_time_diff=0.5)
    assert list(cameras) == [1, 2]
    with pytest.raises(ValueError, match="max_time_diff must be a finite number of seconds >= 0, got -1"):
        match_trajectory(images, (np.array([10.0]), poses[:1]), K, max_time_diff=-1)
    with pytest.raises(ValueError, match="max_time_diff must be a finite number of seconds >= 0, got nan"):
        match_trajectory(images, (np.array([10.0]), poses[:1]), K, max_time_diff="soon")
    with pytest.raises(ValueError, match="intrinsics must be a sqfit.Intrinsics"):
        match_trajectory(images, (np.array([10.0]), poses[:1]), "400 300 320 240 640 480")
    with pytest.raises(ValueError, match=r"trajectory poses must have shape \(2, 4, 4\)"):
        match_trajectory(images, (np.array([10.0, 11.0]), poses[:1]), K)


# --- a user's scene: COCO + TUM trajectory --------------------------------------------------------

TIMES = [1305031102.175304, 1305031102.211214, 1305031102.243188]


@pytest.fixture(scope="module")
def trial():
    return paper_trial(3)


def write_tum_scene(root, trial, offset=0.004, others=()):
    """COCO masks named by timestamp, a TUM trajectory with decoy poses between, OpenCV intrinsics."""
    names = [f"rgb/{t:.6f}.png" for t in TIMES]
    images = [{"id": k + 1, "file_name": n, "width": 640, "height": 480} for k, n in enumerate(names)]
    annotations = [{"id": k + 1, "image_id": k + 1, "track_id": 7, "segmentation": encode_mask(m)[0]}
                   for k, m in enumerate(trial.masks)]
    (root / "annotations.json").write_text(json.dumps({"images": images, "annotations": [*annotations, *others]}))
    # The images are `offset` s after their pose; a wrong pose 0.015 s after each (nearer in time to nothing).
    stamps = np.sort(np.concatenate([np.array(TIMES) - offset, np.array(TIMES) - offset + 0.015]))
    poses = np.stack([p for cam in trial.cameras for p in (cam.pose, trial.cameras[0].pose)])
    write_tum(root / "traj.tum", stamps, poses)
    write_intrinsics(root / "camera.txt", trial.cameras[0].intrinsics)
    return root / "annotations.json", root / "traj.tum", root / "camera.txt"


def test_fit_user_scene_with_tum_poses_matches_native_fit(tmp_path, trial):
    coco, traj, camera = write_tum_scene(tmp_path, trial)
    out = tmp_path / "fits.jsonl"
    assert main(["fit", "--coco", str(coco), "--poses", str(traj), "--intrinsics", str(camera), "-o", str(out),
                 "--chain", "1-2-3D", "--seed", "4", "--no-progress"]) == 0
    (rec,) = records(out)
    assert rec["status"] == "ok" and rec["track_id"] == 7 and rec["views"] == [0, 1, 2] and rec["dropped_views"] == []
    native = observe_views(trial.cameras, [m.astype(np.uint16) for m in trial.masks], 1, rng=track_rng(4, 7))
    ref = sqfit.fit(native.observations, "1-2-3D")
    np.testing.assert_allclose(rec["params"], ref.superquadric.to_vector(), rtol=1e-9, atol=1e-9)
    scene = load_import(coco, traj, intrinsics=camera)
    for k, cam in enumerate(trial.cameras):
        np.testing.assert_allclose(scene.cameras[k + 1].pose, cam.pose, atol=1e-14)
        assert scene.cameras[k + 1].intrinsics == cam.intrinsics


def test_tum_images_without_a_pose_are_dropped_with_the_reason(tmp_path, trial):
    coco, traj, camera = write_tum_scene(tmp_path, trial, offset=0.004)
    out = tmp_path / "fits.jsonl"
    # 0.003 s: no image has its pose that near; 0.01 s: all do (the decoys are 0.011 s away).
    assert main(["fit", "--coco", str(coco), "--poses", str(traj), "--intrinsics", str(camera), "-o", str(out),
                 "--chain", "1-2", "--no-progress", "--max-time-diff", "0.01"]) == 0
    assert records(out)[0]["status"] == "ok"
    with pytest.raises(ValueError, match=r"no image of .* can be used with the poses of .*traj.tum \(matched by "
                                         r"timestamp\): image 'rgb/1305031102.175304.png' \(t = 1305031102.175304 s\) "
                                         r"has no pose in .*within 0.003 s.*"
                                         r"the trajectory spans t = 1305031102.171304"):
        load_import(coco, traj, intrinsics=camera, max_time_diff=0.003)
    # One image 0.1 s off its pose: the object keeps two views and the record says which was dropped and why.
    (tmp_path / "rgb.txt").write_text(f"{TIMES[0]} rgb/{TIMES[0]:.6f}.png\n{TIMES[1] + 0.1} rgb/{TIMES[1]:.6f}.png\n"
                                      f"{TIMES[2]} rgb/{TIMES[2]:.6f}.png\n")
    assert main(["fit", "--coco", str(coco), "--poses", str(traj), "--intrinsics", str(camera), "-o", str(out),
                 "--image-times", str(tmp_path / "rgb.txt"), "--chain", "1-2", "--no-progress"]) == 0
    (rec,) = records(out)
    assert rec["status"] == "ok" and rec["views"] == [0, 2]
    assert rec["dropped_views"] == [{"view": 1, "reason": f"image 'rgb/1305031102.211214.png' (t = "
                                     f"{TIMES[1] + 0.1:.6f} s) has no pose in {traj} within 0.02 s: the nearest is "
                                     f"0.057 s away (t = {TIMES[2] - 0.004 + 0.015:.6f} s; --max-time-diff)"}]
    assert rec["warnings"][0].startswith("view 1 (rgb/1305031102.211214.png) dropped: image 'rgb/")


def test_tum_option_errors(tmp_path, trial, capsys):
    coco, traj, camera = write_tum_scene(tmp_path, trial)
    with pytest.raises(ValueError, match=r"traj.tum is a TUM trajectory, which has no camera intrinsics: give them "
                                         r"\(--intrinsics 'fx fy cx cy width height'"):
        load_import(coco, traj)
    write_pose_json_path = tmp_path / "poses.json"
    write_pose_json(write_pose_json_path, {f"rgb/{t:.6f}.png": c for t, c in zip(TIMES, trial.cameras)})
    with pytest.raises(ValueError, match=r"intrinsics, max_time_diff only apply to a TUM trajectory; .*poses.json "
                                         "is a json pose source"):
        load_import(coco, write_pose_json_path, intrinsics=camera, max_time_diff=0.1)
    with pytest.raises(ValueError, match="intrinsics_convention only apply to a TUM trajectory"):
        load_import(coco, write_pose_json_path, intrinsics_convention="sqfit")
    with pytest.raises(ValueError, match=r"traj.tum is a TUM trajectory: it has no image names"):
        read_poses(traj)
    with pytest.raises(ValueError, match=r"pose format must be one of \['auto', 'colmap', 'json', 'tum'\]"):
        read_poses(traj, "kitti")
    assert load_import(coco, traj, "tum", intrinsics=camera).cameras.keys() == {1, 2, 3}
    assert main(["fit", "--coco", str(coco), "--poses", str(traj), "-o", str(tmp_path / "f.jsonl")]) == 2
    assert "has no camera intrinsics" in capsys.readouterr().err


def test_malformed_tum_file_is_a_one_line_error(tmp_path, trial):
    coco, traj, camera = write_tum_scene(tmp_path, trial)
    lines = traj.read_text().splitlines()
    lines[3] = lines[3].rsplit(" ", 1)[0]  # 7 numbers
    traj.write_text("\n".join(lines) + "\n")
    cmd = [sys.executable, "-m", "sqfit.cli", "fit", "--coco", str(coco), "--poses", str(traj), "--intrinsics",
           "400 300 319.5 239.5 640 480", "-o", str(tmp_path / "f.jsonl"), "--no-progress"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert f"{traj}:4: expected 8 finite numbers 't tx ty tz qx qy qz qw'" in res.stderr


def test_readme_tum_commands_run(tmp_path, trial, monkeypatch):
    import re
    import shlex
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = next(b for b in re.findall(r"```bash\n(.*?)```", text, flags=re.S) if "--poses traj.tum" in b)
    lines = [line for line in block.strip().splitlines() if not line.startswith("#")]
    assert len(lines) == 2 and all(shlex.split(x)[:2] == [".venv/bin/sqfit", "fit"] for x in lines)
    monkeypatch.chdir(tmp_path)
    write_tum_scene(tmp_path, trial)
    (tmp_path / "groundtruth.txt").write_text((tmp_path / "traj.tum").read_text())
    write_image_times(tmp_path / "rgb.txt", {f"rgb/{t:.6f}.png": t for t in TIMES})
    for line in lines:
        assert main([*shlex.split(line)[1:], "--chain", "1-2", "--no-progress"]) == 0
        (rec,) = records(tmp_path / "fits.jsonl")
        assert rec["views"] == [0, 1, 2], line
