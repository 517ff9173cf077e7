"""COCO polygons in the OpenCV (detectron2) and skimage conventions, and the generate -> fit route."""

import json

import numpy as np
import pytest
from scipy import ndimage

from sqfit.formats import decode_segmentation, encode_polygons, mask_to_polygons, read_coco
from sqfit.views.dataset import load_trial, trial_dirs

from _datasets import small_scene  # noqa: E402
from _helpers import mask_shapes  # noqa: E402


def disc(radius, centre=(60.3, 80.6), shape=(120, 160)):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    return (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= radius ** 2


def rim(mask):
    """Boundary pixels: in the mask, with a 4-neighbour outside it."""
    return mask & ~ndimage.binary_erosion(mask, border_value=0)


def shapes():
    two = disc(8.0, (20.0, 20.0), (40, 80)) | disc(10.0, (20.0, 55.0), (40, 80))
    return {"disc5": disc(5.3), "disc12": disc(12.0), "disc35": disc(35.0), **mask_shapes(), "two": two}


@pytest.mark.parametrize("name", list(shapes()))
def test_skimage_polygons_reproduce_the_mask(name):
    mask = shapes()[name]
    polygons = mask_to_polygons(mask, "skimage")
    np.testing.assert_array_equal(decode_segmentation(polygons, *mask.shape), mask)
    assert len(polygons) == ndimage.label(mask)[1]  # one polygon per component


@pytest.mark.parametrize("name", list(shapes()))
def test_opencv_polygons_lose_about_half_the_rim(name):
    mask = shapes()[name]
    back = decode_segmentation(mask_to_polygons(mask, "opencv"), *mask.shape)
    lost = mask & ~back
    assert not np.any(back & ~mask)  # through the boundary pixels' centres: never outside
    assert np.all(rim(mask)[lost])  # only boundary pixels go
    assert 0.3 < lost.sum() / rim(mask).sum() < 0.7


def test_polygon_vertices_follow_each_convention():
    square = shapes()["square"]  # rows 5..19, columns 10..29
    cv, sk = (np.array(mask_to_polygons(square, c)[0]).reshape(-1, 2) for c in ("opencv", "skimage"))
    # OpenCV: centres of the boundary pixels (+0.5); skimage: midway to the outside centres.
    assert (cv[:, 0].min(), cv[:, 0].max(), cv[:, 1].min(), cv[:, 1].max()) == (10.5, 29.5, 5.5, 19.5)
    assert (sk[:, 0].min(), sk[:, 0].max(), sk[:, 1].min(), sk[:, 1].max()) == (10.0, 30.0, 5.0, 20.0)
    lost = square & ~decode_segmentation([cv.ravel().tolist()], *square.shape)
    assert lost.sum() == 15 + 20 - 1 and lost[5, 10:30].all() and lost[5:20, 10].all()  # top row, left column


def test_holes_come_back_filled_and_tiny_objects_follow_opencv():
    ring = disc(20.0) & ~disc(8.0)
    for convention in ("opencv", "skimage"):
        polygons = mask_to_polygons(ring, convention)
        assert len(polygons) == 2  # the outline and the hole's
        back = decode_segmentation(polygons, *ring.shape)
        assert back[disc(8.0)].all()  # COCO polygons are a union: the hole is filled
    dot = np.zeros((10, 10), bool)
    dot[4, 4:6] = True
    assert mask_to_polygons(dot, "opencv") == []  # detectron2 drops contours of < 3 points
    np.testing.assert_array_equal(decode_segmentation(mask_to_polygons(dot, "skimage"), 10, 10), dot)
    assert encode_polygons(dot, "opencv") == ([], 0.0, [0.0, 0.0, 0.0, 0.0])


def test_encode_polygons_area_and_box_are_of_the_decoded_polygons():
    mask = shapes()["square"]
    for convention, area, box in [("skimage", 300.0, [10.0, 5.0, 20.0, 15.0]), ("opencv", 266.0, [11.0, 6.0, 19.0, 14.0])]:
        segmentation, got_area, got_box = encode_polygons(mask, convention)
        assert got_area == area and got_box == box
        assert json.loads(json.dumps(segmentation)) == segmentation


@pytest.mark.parametrize("call, match", [
    (lambda: mask_to_polygons(np.ones((4, 4)), "cv2"), r"polygon convention must be one of \['opencv', 'skimage'\]"),
    (lambda: encode_polygons(np.ones((4, 4)), None), "polygon convention must be one of"),
    (lambda: mask_to_polygons(np.ones(4), "opencv"), r"mask must have shape \(h, w\)"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# --- sqsim generate --coco-polygons, then sqfit fit --coco -----------------------------------------------

SCENE = small_scene(5, 2, {})


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from sqsim.cli import main as sqsim_main

    root = tmp_path_factory.mktemp("polygons")
    (root / "scene.toml").write_text(SCENE)
    for encoding in ("rle", "opencv", "skimage"):
        extra = [] if encoding == "rle" else ["--coco-polygons", encoding]
        assert sqsim_main(["generate", str(root / "scene.toml"), "-o", str(root / encoding), "--colmap",
                           "--no-progress", *extra]) == 0
    return root


def decoded(path):
    """``file_name -> {track_id -> mask}`` of a COCO file."""
    coco = read_coco(path)
    out = {}
    for track, by_image in coco.tracks.items():
        for image_id, anns in by_image.items():
            out.setdefault(coco.images[image_id].file_name, {})[track] = coco.mask(anns[0])
    return out


def test_generate_writes_polygons_in_each_convention(datasets):
    png = {}
    for path in trial_dirs(datasets / "rle"):
        trial = load_trial(path)
        for v, image in enumerate(trial.images):
            png[f"trials/{path.name}/masks/view_{v:02d}.png"] = {f"{path.name}/{k}": image == k
                                                                for k in np.unique(image) if k}
    for encoding in ("rle", "opencv", "skimage"):
        data = json.loads((datasets / encoding / "annotations.json").read_text())
        assert data["info"]["mask_encoding"] == ("rle" if encoding == "rle" else f"polygons-{encoding}")
        kinds = {type(a["segmentation"]) for a in data["annotations"]}
        assert kinds == ({dict} if encoding == "rle" else {list})
        got = decoded(datasets / encoding / "annotations.json")
        assert got.keys() == png.keys()
        for name, masks in png.items():
            for track, mask in masks.items():
                if encoding == "opencv":
                    assert not np.any(got[name][track] & ~mask) and (mask & ~got[name][track]).sum() > 0
                else:
                    np.testing.assert_array_equal(got[name][track], mask)


def test_fit_coco_reads_both_conventions_when_rasterising(datasets):
    # --polygon-convention raster: pycocotools' reading, exact for skimage outlines, not for OpenCV's.
    pytest.importorskip("pycolmap")
    from sqfit.cli import main as sqfit_main

    fits = {}
    for encoding in ("rle", "opencv", "skimage"):
        out = datasets / f"{encoding}.jsonl"
        assert sqfit_main(["fit", "--coco", str(datasets / encoding / "annotations.json"), "--poses",
                           str(datasets / encoding / "sparse" / "0"), "-o", str(out), "--no-progress",
                           "--polygon-convention", "raster"]) == 0
        fits[encoding] = {r["track_id"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert fits["rle"].keys() == fits["opencv"].keys() == fits["skimage"].keys() and len(fits["rle"]) == 4
    for track, ref in fits["rle"].items():
        assert ref["status"] == fits["opencv"][track]["status"] == fits["skimage"][track]["status"] == "ok"
        np.testing.assert_allclose(fits["skimage"][track]["params"], ref["params"], rtol=1e-9, atol=1e-9)
        assert not np.allclose(fits["opencv"][track]["params"], ref["params"], rtol=1e-9, atol=1e-9)


def test_generate_rejects_an_unknown_convention(tmp_path):
    from sqsim.runs.generate import generate
    from sqsim.world.scene import parse_scene

    with pytest.raises(ValueError, match=r"--coco-polygons must be one of \['opencv', 'skimage'\], got 'cv'"):
        generate(parse_scene({}), tmp_path / "d", trials=1, coco_polygons="cv", progress=False)
