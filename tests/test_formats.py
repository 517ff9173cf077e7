"""COCO, COLMAP and JSON pose readers/writers, and fitting a user's COCO + COLMAP scene."""

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

import sqfit
from sqfit.cli import main
from sqfit.formats import decode_segmentation, encode_mask, read_coco, read_colmap, read_pose_json, write_colmap, write_pose_json
from sqfit.views.imported import load_import, read_poses
from sqfit.views.imported import detect_pose_format, track_rng
from sqfit.views.dataset import observe_views
from sqfit.geometry.raster import fill_convex_polygon
from sqfit.testing import paper_trial

pycolmap = pytest.importorskip("pycolmap")
pytest.importorskip("pycocotools")

NAMES = ["view_00.png", "view_01.png", "view_02.png"]


def text_model(directory, cameras, images):
    """A COLMAP text model directory with these ``cameras.txt`` and ``images.txt`` lines, no points."""
    directory.mkdir()
    (directory / "cameras.txt").write_text(cameras)
    (directory / "images.txt").write_text(images)
    (directory / "points3D.txt").write_text("")
    return directory


@pytest.fixture(scope="module")
def trial():
    return paper_trial(3)


def contour_polygon(mask):
    """A COCO polygon (flat list) of a mask's outer contour, image coordinates."""
    obs = sqfit.Observation.from_mask(sqfit.Camera(sqfit.Intrinsics(mask.shape[1], mask.shape[0], 1, 1, 0, 0),
                                                   np.eye(4)), mask, rng=0)
    return obs.contour.ravel().tolist()


def write_user_scene(root, trial, polygons=False, prefix="images/", track=7, other=None):
    """A user's scene: COCO file (file names without folder) + COLMAP text model (names with ``prefix``)."""
    images, annotations = [], []
    for k, (name, mask) in enumerate(zip(NAMES, trial.masks)):
        images.append({"id": k + 10, "file_name": name, "width": 640, "height": 480})
        segm = [contour_polygon(mask)] if polygons else encode_mask(mask)[0]
        annotations.append({"id": k + 1, "image_id": k + 10, "category_id": 1, "track_id": track,
                            "segmentation": segm, "iscrowd": 0})
    if other is not None:
        annotations.extend(other)
    coco = root / "annotations.json"
    coco.write_text(json.dumps({"images": images, "annotations": annotations, "categories": []}))
    write_colmap(root / "sparse" / "0", {prefix + n: cam for n, cam in zip(NAMES, trial.cameras)})
    return coco, root / "sparse" / "0"


def records(path):
    return [json.loads(x) for x in path.read_text().splitlines()]


# --- conventions ----------------------------------------------------------------------------------

def test_coco_polygon_pixels_follow_the_sqfit_pixel_grid():
    # A polygon in image coordinates covers the pixels whose centres (j + 0.5, i + 0.5) are inside.
    poly = [3.0, 2.0, 8.0, 2.0, 8.0, 5.0, 3.0, 5.0]
    mask = decode_segmentation([poly], 10, 12)
    expected = np.zeros((10, 12), bool)
    expected[2:5, 3:8] = True
    np.testing.assert_array_equal(mask, expected)
    # pycocotools rasterises on a 5x finer grid: only pixels whose centres lie within a fraction of
    # a pixel of an edge may differ (a half-pixel shift of the convention would differ everywhere).
    tri = np.array([[10.2, 5.7], [90.3, 22.9], [34.1, 70.6]])
    diff = decode_segmentation([tri.ravel().tolist()], 80, 100) != fill_convex_polygon(tri, (80, 100))
    centres = np.argwhere(diff)[:, ::-1] + 0.5
    a, b = tri, np.roll(tri, -1, axis=0)
    t = np.clip(np.einsum("pkd,kd->pk", centres[:, None] - a, b - a) / ((b - a) ** 2).sum(1), 0, 1)
    dist = np.linalg.norm(centres[:, None] - (a + t[..., None] * (b - a)), axis=2).min(axis=1)
    assert diff.sum() < 15 and dist.max(initial=0) < 0.25


def test_colmap_pose_and_pixel_conventions(tmp_path, trial):
    # COLMAP cam_from_world is the inverse of sqfit's T_world_camera; a world point projects to the
    # same pixel with pycolmap and with sqfit.project.
    cam = trial.cameras[1]
    write_colmap(tmp_path, {"a.png": cam})
    model = pycolmap.Reconstruction(str(tmp_path))
    image = model.images[1]
    cam_from_world = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
    np.testing.assert_allclose(cam_from_world @ cam.pose, np.eye(4), atol=1e-12)
    X = np.array([[0.3, -1.2, 0.8], [2.0, 1.0, -1.0]])
    expected, _ = sqfit.project(cam, X)
    got = [model.cameras[image.camera_id].img_from_cam(image.cam_from_world() * x) for x in X]
    np.testing.assert_allclose(np.array(got), expected, atol=1e-9)
    back = read_colmap(tmp_path)["a.png"]
    np.testing.assert_allclose(back.pose, cam.pose, atol=1e-12)
    assert back.intrinsics == cam.intrinsics


def test_colmap_binary_and_legacy_text_models(tmp_path, trial):
    write_colmap(tmp_path / "bin", {"a.png": trial.cameras[0], "b.png": trial.cameras[2]}, binary=True)
    assert sorted(p.suffix for p in (tmp_path / "bin").iterdir()) == [".bin"] * 5
    got = read_colmap(tmp_path / "bin")
    assert list(got) == ["a.png", "b.png"]
    np.testing.assert_allclose(got["b.png"].pose, trial.cameras[2].pose, atol=1e-12)
    # Older COLMAP writes cameras/images/points3D only; SIMPLE_PINHOLE has one focal length.
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "cameras.txt").write_text("# id model w h params\n3 SIMPLE_PINHOLE 64 48 50 32 24\n")
    (legacy / "images.txt").write_text("# two lines per image\n5 1 0 0 0 1 2 3 3 frames/x.png\n\n")
    (legacy / "points3D.txt").write_text("")
    cam = read_colmap(legacy)["frames/x.png"]
    assert cam.intrinsics == sqfit.Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    np.testing.assert_allclose(cam.pose[:3, 3], [-1.0, -2.0, -3.0])  # identity rotation: centre = -t


def test_colmap_rejects_distortion_naming_model_and_camera(tmp_path):
    (tmp_path / "cameras.txt").write_text("2 OPENCV 64 48 50 50 32 24 0.1 0 0 0\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 2 img.png\n\n")
    (tmp_path / "points3D.txt").write_text("")
    with pytest.raises(ValueError, match=r"camera 2 \(used by image 'img.png'\) has model OPENCV; only PINHOLE "
                                         r"and SIMPLE_PINHOLE"):
        read_colmap(tmp_path)
    with pytest.raises(OSError, match="COLMAP model directory not found"):
        read_colmap(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(OSError, match="no images.bin or images.txt"):
        read_colmap(tmp_path / "empty")
    with pytest.raises(ValueError, match="pycolmap cannot read this COLMAP model"):
        read_colmap(text_model(tmp_path / "bad", "1 PINHOLE 64 48 oops\n", ""))


def test_json_poses_both_conventions(tmp_path, trial):
    cam = trial.cameras[1]
    write_pose_json(tmp_path / "p.json", {"a.png": cam})
    np.testing.assert_array_equal(read_pose_json(tmp_path / "p.json")["a.png"].pose, cam.pose)
    inv = np.linalg.inv(cam.pose)
    rec = {"file_name": "b.png", "intrinsics": cam.intrinsics.to_dict(), "T_camera_world": inv.tolist()}
    (tmp_path / "q.json").write_text(json.dumps({"images": [rec]}))
    np.testing.assert_allclose(read_pose_json(tmp_path / "q.json")["b.png"].pose, cam.pose, atol=1e-12)


@pytest.mark.parametrize("images, match", [
    ("nope", r"needs a list 'images'"),
    ([{"intrinsics": {}}], r"images\[0\] needs a string 'file_name'"),
    ([{"file_name": "a"}], r"\(a\) needs exactly one of T_world_camera or T_camera_world, got neither"),
    ([{"file_name": "a", "T_world_camera": np.eye(4).tolist()}], r"\(a\) needs 'intrinsics'"),
    ([{"file_name": "a", "T_world_camera": np.eye(4).tolist(), "T_camera_world": np.eye(4).tolist(),
       "intrinsics": {}}], "got \\['T_world_camera', 'T_camera_world'\\]"),
    ([{"file_name": "a", "T_world_camera": np.eye(3).tolist(), "intrinsics": {"width": 4, "height": 4, "fx": 1,
                                                                               "fy": 1, "cx": 0, "cy": 0}}],
     r"T_world_camera must have shape \(4, 4\)"),
    ([{"file_name": "a", "T_camera_world": (2 * np.eye(4)).tolist(),
       "intrinsics": {"width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 0, "cy": 0}}],
     "T_camera_world must have last row"),
    ([{"file_name": "a", "T_world_camera": np.eye(4).tolist(), "intrinsics": {"width": 4}}],
     "intrinsics must be"),
])
def test_json_pose_errors(tmp_path, images, match):
    (tmp_path / "p.json").write_text(json.dumps({"images": images}))
    with pytest.raises(ValueError, match=match):
        read_pose_json(tmp_path / "p.json")


def test_pose_format_detection(tmp_path):
    assert detect_pose_format(tmp_path) == "colmap"
    assert detect_pose_format(tmp_path / "p.json") == "json"
    assert detect_pose_format(tmp_path / "groundtruth.txt") == detect_pose_format(tmp_path / "a.TUM") == "tum"
    with pytest.raises(ValueError, match="cannot tell the pose format of .*poses.yaml.*--pose-format "
                                         r"\(colmap, json, tum\)"):
        detect_pose_format(tmp_path / "poses.yaml")
    with pytest.raises(OSError, match="pose source not found"):
        read_poses(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="pose format must be one of"):
        read_poses(tmp_path, "tum2")


# --- COCO -----------------------------------------------------------------------------------------

def test_rle_round_trip_and_uncompressed_rle():
    rng = np.random.default_rng(0)
    mask = rng.random((7, 9)) > 0.5
    segm, area, bbox = encode_mask(mask)
    assert area == mask.sum() and isinstance(segm["counts"], str)
    np.testing.assert_array_equal(decode_segmentation(segm, 7, 9), mask)
    runs, flat, value, n = [], mask.ravel(order="F"), False, 0
    for v in flat:  # uncompressed RLE: alternating run lengths starting with background
        if v != value:
            runs.append(n)
            value, n = v, 0
        n += 1
    runs.append(n)
    np.testing.assert_array_equal(decode_segmentation({"size": [7, 9], "counts": runs}, 7, 9), mask)


@pytest.mark.parametrize("segm, match", [
    ({"size": [5, 9], "counts": "abc"}, r"RLE size \[5, 9\] does not match the image \(height, width\) = \(7, 9\)"),
    ({"size": [7, 9], "counts": "zz"}, "malformed compressed RLE"),
    ({"size": [7, 9], "counts": "P1370000000V1x"}, "cannot decode RLE: Invalid RLE mask representation"),
    ({"size": [7, 9], "counts": [3, 4]}, "uncompressed RLE counts sum to 7, not height \\* width = 63"),
    ({"size": [7, 9], "counts": 5}, "'counts' must be a string or a list"),
    ({"size": [7, 9], "counts": [70, -7]}, "uncompressed RLE counts must be >= 0"),
    ({"size": [7, 9], "counts": [60, 3.0]}, "uncompressed RLE counts must be integers"),
    ([[1, 2, 3]], r"polygons must be lists of >= 3 finite \(x, y\) pairs"),
    ([[1, 2, 3, 4, 5, float("nan")]], "polygons must be lists"),
    ("P1370", "segmentation must be RLE .* or polygons"),
])
def test_bad_segmentations(segm, match):
    with pytest.raises(ValueError, match=match):
        decode_segmentation(segm, 7, 9, "ann 3")


def _coco(tmp_path, images, annotations):
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"images": images, "annotations": annotations}))
    return path


IMG = {"id": 1, "file_name": "a.png", "width": 4, "height": 3}


@pytest.mark.parametrize("images, annotations, match", [
    ([{"id": 1}], [], r"images\[0\] needs 'id', 'file_name', 'width' and 'height'"),
    ([dict(IMG, width=0)], [], r"images\[0\] \(a.png\): width must be a positive integer"),
    ([IMG, IMG], [], "duplicate image id 1"),
    ([IMG, dict(IMG, id=2)], [], "duplicate file_name 'a.png'"),
    ([IMG], [{"id": 4, "image_id": 9, "track_id": 1}], r"annotation 4: image_id 9 is not in 'images'"),
    ([IMG], [{"id": 4, "image_id": 1}], r"annotation 4 \(a.png\) has no 'track_id'"),
    ([IMG], [{"id": 4, "image_id": 1, "track_id": 1.5}], r"annotation 4 \(a.png\) has no 'track_id'"),
    ([IMG], ["x"], r"annotation #0 must be an object"),
])
def test_bad_coco_files(tmp_path, images, annotations, match):
    with pytest.raises(ValueError, match=match):
        read_coco(_coco(tmp_path, images, annotations))


def test_coco_file_errors_and_grouping(tmp_path):
    with pytest.raises(OSError, match="COCO file not found"):
        read_coco(tmp_path / "none.json")
    (tmp_path / "x.json").write_text("{oops")
    with pytest.raises(ValueError, match="x.json is not valid JSON"):
        read_coco(tmp_path / "x.json")
    (tmp_path / "y.json").write_text("[]")
    with pytest.raises(ValueError, match="needs lists 'images' and 'annotations'"):
        read_coco(tmp_path / "y.json")
    images = [IMG, dict(IMG, id=2, file_name="b.png")]
    anns = [{"id": 1, "image_id": 2, "track_id": 5}, {"id": 2, "image_id": 1, "track_id": 5},
            {"id": 3, "image_id": 1, "track_id": "car"}, {"id": 4, "image_id": 1, "iscrowd": 1},
            {"id": 5, "image_id": 1, "track_id": 2}]
    coco = read_coco(_coco(tmp_path, images, anns))
    assert list(coco.tracks) == [2, 5, "car"]  # ints in order, then strings; crowd skipped
    assert list(coco.tracks[5]) == [1, 2]  # images in file order


def test_duplicate_annotation_ids_are_named_in_a_warning(tmp_path):
    anns = [{"id": 7, "image_id": 1, "track_id": 1}, {"id": 7, "image_id": 1, "track_id": 2},
            {"id": "a", "image_id": 1, "track_id": 3}, {"id": "a", "image_id": 1, "track_id": 4},
            {"id": 8, "image_id": 1, "track_id": 5}]
    with pytest.warns(UserWarning, match=r"c.json: 2 annotation id\(s\) occur more than once: 7, 'a' \("):
        coco = read_coco(_coco(tmp_path, [IMG], anns))
    assert list(coco.tracks) == [1, 2, 3, 4, 5]  # read as it is
    many = [{"id": k // 2, "image_id": 1, "track_id": k} for k in range(30)]
    with pytest.warns(UserWarning, match=r"15 annotation id\(s\) .*: 0, 1, 2, 3, 4, 5, 6, 7, 8, 9 and 5 more"):
        read_coco(_coco(tmp_path, [IMG], many))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_coco(_coco(tmp_path, [IMG], anns[:1] + anns[2:3]))  # unique ids: no warning


# --- import and fit -------------------------------------------------------------------------------

@pytest.mark.parametrize("polygons", [False, True])
def test_fit_user_scene_matches_native_fit(tmp_path, trial, polygons):
    coco, model = write_user_scene(tmp_path, trial, polygons=polygons)
    out = tmp_path / "fits.jsonl"
    # raster: pycocotools' reading of the polygons, as the native route reads masks (the polygon
    # route draws its samples inside the outline instead: tests/test_polygon_route.py)
    assert main(["fit", "--coco", str(coco), "--poses", str(model), "-o", str(out), "--chain", "1-2-3D",
                 "--no-progress", "--seed", "4", "--polygon-convention", "raster"]) == 0
    (rec,) = records(out)
    assert rec["status"] == "ok" and rec["object_id"] == 7 and rec["track_id"] == 7 and rec["trial"] is None
    assert rec["images"] == NAMES and rec["views"] == [0, 1, 2] and rec["dropped_views"] == []
    # The same masks and cameras fitted natively, with the importer's seed, give the same parameters.
    masks = [decode_segmentation(a["segmentation"], 480, 640) for a in json.loads(coco.read_text())["annotations"]]
    native = observe_views(trial.cameras, [m.astype(np.uint16) for m in masks], 1, rng=track_rng(4, 7))
    ref = sqfit.fit(native.observations, "1-2-3D")
    np.testing.assert_allclose(rec["params"], ref.superquadric.to_vector(), rtol=1e-9, atol=1e-9)
    if polygons:  # polygon masks of the contour reproduce the rendered mask up to boundary pixels
        iou = [np.logical_and(m, t).sum() / np.logical_or(m, t).sum() for m, t in zip(masks, trial.masks)]
        assert min(iou) > 0.97


def test_fit_coco_warns_about_duplicate_annotation_ids(tmp_path, trial):
    coco, model = write_user_scene(tmp_path, trial)
    data = json.loads(coco.read_text())
    data["annotations"][2]["id"] = data["annotations"][0]["id"]
    coco.write_text(json.dumps(data))
    with warnings.catch_warnings(), pytest.warns(UserWarning, match=r"annotations.json: 1 annotation id\(s\) "
                                                                 r"occur more than once: 1 \("):
        warnings.simplefilter("ignore", DeprecationWarning)  # pycocotools' own, under numpy 2
        assert main(["fit", "--coco", str(coco), "--poses", str(model), "-o", str(tmp_path / "fits.jsonl"),
                     "--chain", "1-2-3D", "--no-progress"]) == 0
    assert records(tmp_path / "fits.jsonl")[0]["status"] == "ok"


def test_json_pose_source(tmp_path, trial):
    coco, _ = write_user_scene(tmp_path, trial)
    write_pose_json(tmp_path / "poses.json", dict(zip(NAMES, trial.cameras)))
    out = tmp_path / "fits.jsonl"
    assert main(["fit", "--coco", str(coco), "--poses", str(tmp_path / "poses.json"), "-o", str(out),
                 "--chain", "1-2", "--no-progress"]) == 0
    assert records(out)[0]["status"] == "ok"


def test_bad_user_scenes_are_flagged(tmp_path, trial):
    one = encode_mask(trial.masks[0])[0]
    empty = encode_mask(np.zeros((480, 640), bool))[0]
    others = [{"id": 20, "image_id": 10, "track_id": "lonely", "segmentation": one},          # one view only
              {"id": 21, "image_id": 10, "track_id": "ghost", "segmentation": empty},         # empty in view 0
              {"id": 22, "image_id": 11, "track_id": "ghost", "segmentation": one},
              {"id": 23, "image_id": 12, "track_id": "ghost", "segmentation": one},
              {"id": 24, "image_id": 11, "track_id": "broken", "segmentation": {"size": [10, 10], "counts": "x"}}]
    coco, model = write_user_scene(tmp_path, trial, other=others)
    data = json.loads(coco.read_text())
    data["images"].append({"id": 99, "file_name": "unposed.png", "width": 640, "height": 480})
    data["images"].append({"id": 98, "file_name": "small.png", "width": 320, "height": 240})
    data["annotations"] += [{"id": 30, "image_id": 99, "track_id": 7, "segmentation": one},
                            {"id": 31, "image_id": 98, "track_id": 7, "segmentation": {"size": [240, 320],
                                                                                       "counts": [76800]}}]
    coco.write_text(json.dumps(data))
    write_pose_json(tmp_path / "poses.json", {**dict(zip(NAMES, trial.cameras)),
                                              "small.png": trial.cameras[0]})
    out = tmp_path / "fits.jsonl"
    assert main(["fit", "--coco", str(coco), "--poses", str(tmp_path / "poses.json"), "-o", str(out),
                 "--chain", "1-2", "--no-progress"]) == 0
    by_track = {r["track_id"]: r for r in records(out)}
    seven = by_track[7]
    assert seven["status"] == "ok" and seven["images"] == NAMES
    assert seven["dropped_views"] == [
        {"view": 3, "reason": f"image 'unposed.png' is not in {tmp_path / 'poses.json'}: no pose with this file "
                              "name or base name"},
        {"view": 4, "reason": f"image 'small.png' is 320x240 in COCO but its camera in {tmp_path / 'poses.json'} "
                              "is 640x480"}]
    assert seven["warnings"][0].startswith("view 3 (unposed.png) dropped: image 'unposed.png' is not in")
    lonely = by_track["lonely"]
    assert lonely["status"] == "too_few_views"
    assert lonely["message"] == "track 'lonely' has 1 usable view(s) ['view_00.png']; fitting needs >= 2"
    broken = by_track["broken"]  # its bad RLE drops its own view only, not track 7's view of that image
    assert broken["status"] == "too_few_views" and broken["dropped_views"][0]["view"] == 0
    assert "annotation 24 (view_01.png): RLE size [10, 10] does not match" in broken["dropped_views"][0]["reason"]
    ghost = by_track["ghost"]
    assert ghost["status"] == "ok" and ghost["views"] == [1, 2]
    assert ghost["warnings"][0] == "view 0 (view_00.png) dropped: the object's mask is empty in this view"


def test_import_errors_are_one_line(tmp_path, trial, capsys):
    coco, model = write_user_scene(tmp_path, trial, prefix="")
    (model / "cameras.txt").write_text((model / "cameras.txt").read_text().replace("PINHOLE 640 480 400 300 320 240",
                                                                                   "RADIAL 640 480 400 320 240 0 0"))
    cmd = [sys.executable, "-m", "sqfit.cli", "fit", "--coco", str(coco), "--poses", str(model), "-o",
           str(tmp_path / "f.jsonl"), "--no-progress"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "camera 1 (used by image 'view_00.png') has model RADIAL; only PINHOLE and SIMPLE_PINHOLE" in res.stderr
    write_colmap(model, {"other/x.png": trial.cameras[0]})
    with pytest.raises(ValueError, match=r"no image of .*annotations.json can be used with the poses of .*image "
                                         r"'view_00.png' is not in .*pose image names look like \['other/x.png'\]"):
        load_import(coco, model)
    assert main(["fit", "--coco", str(coco), "-o", str(tmp_path / "f.jsonl")]) == 2
    assert "either a DATASET directory or --coco FILE with --poses PATH" in capsys.readouterr().err
    assert main(["fit", "-o", str(tmp_path / "f.jsonl")]) == 2
    assert "give a DATASET directory, or --coco FILE with --poses PATH" in capsys.readouterr().err


def test_ambiguous_base_names_are_flagged(tmp_path, trial):
    coco, _ = write_user_scene(tmp_path, trial)
    poses = {f"{d}/{n}": cam for d in ("left", "right") for n, cam in zip(NAMES, trial.cameras)}
    poses["view_00.png"] = trial.cameras[0]  # exact names win over base names
    poses["view_02.png"] = trial.cameras[2]
    write_pose_json(tmp_path / "p.json", poses)
    scene = load_import(coco, tmp_path / "p.json")
    assert list(scene.cameras) == [10, 12]
    assert "base name matches 2 poses (left/view_01.png, right/view_01.png); use full names" in scene.unusable[11]


def test_more_reader_errors(tmp_path, trial):
    with pytest.raises(OSError, match="pose file not found"):
        read_pose_json(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="bad.json is not valid JSON"):
        read_pose_json(tmp_path / "bad.json")
    rec = {"file_name": "a", "intrinsics": trial.cameras[0].intrinsics.to_dict(),
           "T_world_camera": trial.cameras[0].pose.tolist()}
    (tmp_path / "dup.json").write_text(json.dumps({"images": [rec, rec]}))
    with pytest.raises(ValueError, match=r"images\[1\] \(a\): duplicate file_name"):
        read_pose_json(tmp_path / "dup.json")
    with pytest.raises(ValueError, match=r"cameras\['x'\] must be a sqfit.Camera"):
        write_colmap(tmp_path / "m", {"x": "not a camera"})
    with pytest.raises(ValueError, match="camera 4: fx must be a finite number > 0"):
        read_colmap(text_model(tmp_path / "zero", "4 PINHOLE 64 48 0 50 32 24\n", "1 1 0 0 0 0 0 0 4 img.png\n\n"))
    write_pose_json(tmp_path / "one.json", {NAMES[1]: trial.cameras[1]})
    with pytest.raises(ValueError, match="only 1 image of .* can be used .*; fitting needs >= 2 views"):
        load_import(write_user_scene(tmp_path, trial)[0], tmp_path / "one.json")
    (tmp_path / "empty.json").write_text(json.dumps({"images": []}))
    coco, _ = write_user_scene(tmp_path, trial)
    with pytest.raises(ValueError, match="empty.json holds no image with a pose"):
        load_import(coco, tmp_path / "empty.json")
