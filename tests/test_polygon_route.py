"""The COCO polygon route: polygons read as outlines, not rasterised (sqfit.geometry.outline,
Observation.from_outline, sqfit fit --coco --polygon-convention), against the native mask route."""

import json

import numpy as np
import pytest
import shapely
from scipy import ndimage

from sqfit import Camera, Intrinsics, Observation
from sqfit.cli import main
from sqfit.formats import encode_mask, write_colmap
from sqfit.formats.coco_polygons import READING_OF, detect_polygon_convention, mask_to_polygons, polygon_reading
from sqfit.geometry.outline import (MIN_REGION_AREA_PX, densify, grow_pixel_centres, polygons_region, region_outline,
                                    region_pixels, uniform_points)
from sqfit.geometry.polygon import polygon_area
from sqfit.metrics import iou_3d
from sqfit.testing import paper_trial
from sqfit.views.imported import load_import, observe_track, track_rng
from sqfit.views.observation import clean_mask, outer_contour
from sqfit.views.visibility import BACKGROUND, BORDER, INSTANCE, outline_labels, polygon_labels

from _helpers import mask_shapes  # noqa: E402


def camera(shape):
    h, w = shape
    return Camera(Intrinsics(w, h, 100.0, 100.0, w / 2, h / 2), np.eye(4))


def rings(mask, tool, method=None):
    """The COCO polygons of a mask traced by ``tool`` ("opencv" / "skimage"), as vertex arrays."""
    if method is not None:  # OpenCV with another chain approximation than detectron2's
        import cv2

        found = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP, method)[-2]
        return [c.reshape(-1, 2) + 0.5 for c in found if len(c) >= 3]
    return [np.array(p).reshape(-1, 2) for p in mask_to_polygons(mask, tool)]


def superellipse(seed, shape=(120, 160), centre=None):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    c = rng.uniform([40, 50], [80, 110]) if centre is None else np.asarray(centre, float)
    a, b = rng.uniform(5, 35, 2)
    th, e = rng.uniform(0, np.pi), rng.uniform(0.2, 1.8)
    x = (xx - c[1]) * np.cos(th) + (yy - c[0]) * np.sin(th)
    y = -(xx - c[1]) * np.sin(th) + (yy - c[0]) * np.cos(th)
    return clean_mask((np.abs(x / a) ** (2 / e) + np.abs(y / b) ** (2 / e)) <= 1)


def shapes():
    line = np.zeros((20, 30), bool)
    line[10, 5:25] = True  # one pixel wide: the OpenCV polygon has no area
    spur = mask_shapes()["square"].copy()
    spur[12, 30:40] = True  # a one-pixel-wide spur
    cut = superellipse(3, centre=(60.0, 5.0))  # truncated by the left border
    return {**mask_shapes(), "line": line, "spur": spur, "cut": cut, **{f"sq{k}": superellipse(k) for k in range(6)}}


# --- the pixel-centre convention --------------------------------------------------------------------------

@pytest.mark.parametrize("name", list(shapes()))
@pytest.mark.parametrize("method", [None, "simple"])
def test_grown_pixel_centres_are_the_marching_squares_outline(name, method):
    import cv2

    mask = shapes()[name]
    if method and name == "line":
        pytest.skip("CHAIN_APPROX_SIMPLE traces a straight line by its two ends: no polygon")
    cv = rings(mask, "opencv", None if method is None else cv2.CHAIN_APPROX_SIMPLE)
    region = polygons_region(cv, "pixel-centres")
    outline = shapely.Polygon(outer_contour(mask))
    assert abs(region.area - outline.area) < 1e-9
    assert shapely.symmetric_difference(region, outline).area < 1e-9
    np.testing.assert_array_equal(region_pixels(region, mask.shape), mask)


def test_the_diamond_and_not_a_plain_half_pixel_offset():
    # The docstring of sqfit.geometry.outline: raw OpenCV polygons enclose ~4 % too little, a Euclidean
    # 1/2 px offset ~0.85 % too much (diagonal runs), the diamond-grown polygon exactly the outline.
    raw, euclid, grown = [], [], []
    for k in range(20):
        mask = superellipse(100 + k)
        (cv,) = rings(mask, "opencv")
        truth = abs(polygon_area(outer_contour(mask)))
        raw.append(abs(polygon_area(cv)) / truth - 1)
        offset = shapely.buffer(shapely.LinearRing(cv), 0.5, join_style="mitre", mitre_limit=2)
        euclid.append(shapely.union(shapely.Polygon(cv), offset).area / truth - 1)
        grown.append(grow_pixel_centres(cv).area / truth - 1)
    assert np.median(raw) < -0.02 and 0.004 < np.median(euclid) < 0.015 and np.abs(grown).max() < 1e-12


# --- observations from outlines against observations from masks ------------------------------------------

@pytest.mark.parametrize("name", list(shapes()))
@pytest.mark.parametrize("tool", ["opencv", "skimage"])
def test_an_outline_gives_the_observation_of_its_mask(name, tool):
    mask = shapes()[name]
    cam = camera(mask.shape)
    occluder = np.zeros_like(mask)
    occluder[:, mask.shape[1] // 2:mask.shape[1] // 2 + 2] = True  # another object across the middle
    occluder &= ~mask
    native = Observation.from_mask(cam, mask, rng=0, occluder=occluder)
    got = Observation.from_outline(cam, rings(mask, tool), READING_OF[tool], rng=0, occluder=occluder)
    np.testing.assert_array_equal(got.contour, native.contour)  # same vertices, same start
    np.testing.assert_array_equal(got.contour_labels, native.contour_labels)
    np.testing.assert_allclose(got.centroid, native.centroid, atol=1e-12)
    assert got.area_px == native.area_px and got.touches_border == native.touches_border
    np.testing.assert_array_equal(got.hidden, native.hidden)
    # area samples: uniform in the outline itself, so other points than the mask's pixel squares give
    outline = shapely.Polygon(native.contour)
    assert shapely.contains_xy(outline, *got.samples.T).all()


@pytest.mark.parametrize("tool", ["opencv", "skimage"])
def test_outline_samples_follow_the_mask_rules_and_draws(tool):
    mask = superellipse(7)
    cam = camera(mask.shape)
    for sampling in ("contour", "mixed"):
        native = Observation.from_mask(cam, mask, 40, sampling, rng=3)
        got = Observation.from_outline(cam, rings(mask, tool), READING_OF[tool], 40, sampling, rng=3)
        if sampling == "contour":  # the same contour and the same generator: the same points
            np.testing.assert_array_equal(got.samples, native.samples)
        np.testing.assert_array_equal(got.sample_labels, native.sample_labels)
        assert len(got.samples) == 40


def test_area_samples_are_uniform_in_the_polygon():
    # an L drawn by hand (outline convention, off the pixel grid): a bar on top of a leg
    ell = np.array([[10.2, 10.1], [30.7, 10.1], [30.7, 20.4], [20.45, 20.4], [20.45, 40.3], [10.2, 40.3]])
    n = 30000
    obs = Observation.from_outline(camera((60, 60)), [ell], n_samples=n, rng=1)
    poly = shapely.Polygon(ell)
    assert shapely.contains_xy(poly, *obs.samples.T).all()
    share = (30.7 - 10.2) * (20.4 - 10.1) / poly.area  # the bar's
    assert abs(np.mean(obs.samples[:, 1] < 20.4) - share) < 4 * np.sqrt(share * (1 - share) / n)
    np.testing.assert_allclose(obs.samples.mean(axis=0), np.array(poly.centroid.coords[0]), atol=0.15)
    again = uniform_points(poly, 5, np.random.default_rng(4))
    np.testing.assert_array_equal(again, uniform_points(poly, 5, np.random.default_rng(4)))


def test_outer_contour_starts_where_the_polygon_route_starts_it():
    # skimage closes an outer contour at the last square it scans: the contour starts at the midpoint of
    # the bottom edge of the last pixel (raster order) inside it (Observation.from_outline relies on it).
    rng = np.random.default_rng(5)
    for _ in range(200):
        h, w = rng.integers(10, 60, 2)
        mask = clean_mask(ndimage.gaussian_filter(rng.random((h, w)), rng.uniform(0.5, 3)) > rng.uniform(0.45, 0.55))
        if not mask.any() or mask.all():
            continue
        contour = outer_contour(mask)
        rows, cols = np.nonzero(region_pixels(shapely.Polygon(contour), mask.shape))
        last = np.argmax(rows * w + cols)
        np.testing.assert_array_equal(contour[0], [cols[last] + 0.5, rows[last] + 1.0])


def test_polygon_labels_agree_with_mask_labels_on_a_traced_outline():
    rng = np.random.default_rng(0)
    for k in range(30):
        mask = superellipse(200 + k, (60, 80), rng.uniform([0, 0], [60, 80]))
        if mask.sum() < 20:
            continue
        occluder = np.zeros_like(mask)
        occluder[:, rng.integers(0, 78):][:, :3] = True
        occluder &= ~mask
        contour = outer_contour(mask)
        np.testing.assert_array_equal(polygon_labels(contour, mask.shape, occluder),
                                      outline_labels(contour, mask, occluder))


# --- several polygons, holes, the image border ------------------------------------------------------------

def test_several_parts_and_holes():
    yy, xx = np.mgrid[0:60, 0:100] + 0.5
    big, small = (yy - 30) ** 2 + (xx - 30) ** 2 <= 15 ** 2, (yy - 30) ** 2 + (xx - 75) ** 2 <= 8 ** 2
    cam = camera(big.shape)
    two = rings(big | small, "opencv")
    assert len(two) == 2
    got = Observation.from_outline(cam, two, "pixel-centres", rng=0)  # clean-up: the largest part
    native = Observation.from_mask(cam, big | small, rng=0)
    np.testing.assert_array_equal(got.contour, native.contour)
    assert got.area_px == native.area_px == big.sum()
    both = Observation.from_outline(cam, two, "pixel-centres", 400, rng=0, cleanup=False)
    np.testing.assert_array_equal(both.contour, native.contour)  # the contour is the largest part's
    assert both.area_px == (big | small).sum() and (both.samples[:, 0] > 60).sum() > 20  # samples in both
    # a hole: its outline is one more polygon, and COCO polygons are a union (no holes)
    ring = big & ~((yy - 30) ** 2 + (xx - 30) ** 2 <= 6 ** 2)
    for tool in ("opencv", "skimage"):
        holed = rings(ring, tool)
        assert len(holed) == 2
        got = Observation.from_outline(cam, holed, READING_OF[tool], rng=0, cleanup=False)
        assert got.area_px == big.sum()


def test_a_polygon_past_the_image_border_is_clipped_and_labelled_border():
    box = np.array([[-7.3, 5.2], [20.6, 5.2], [20.6, 30.8], [-7.3, 30.8]])  # hand-drawn, runs off the left
    obs = Observation.from_outline(camera((48, 64)), [box], rng=0)
    assert obs.touches_border and obs.contour[:, 0].min() == 0.0
    on_edge = obs.contour[:, 0] == 0.0
    assert np.all(obs.contour_labels[on_edge] == BORDER)
    assert np.all(obs.contour_labels[obs.contour[:, 0] > 0.5] == BACKGROUND)
    assert np.abs(np.diff(np.vstack([obs.contour, obs.contour[:1]]), axis=0)).max() <= 1.0 + 1e-9  # densified
    np.testing.assert_allclose(abs(polygon_area(obs.contour)), 20.6 * 25.6)


def test_instance_labels_from_the_occluder():
    mask = shapes()["square"]  # rows 5..19, columns 10..29
    other = np.zeros_like(mask)
    other[5:20, 30:40] = True  # touching on the right
    obs = Observation.from_outline(camera(mask.shape), rings(mask, "opencv"), "pixel-centres", occluder=other)
    right = obs.contour[:, 0] == 30.0
    assert right.any() and np.all(obs.contour_labels[right] == INSTANCE)
    assert np.all(obs.contour_labels[obs.contour[:, 0] < 25] == BACKGROUND) and len(obs.hidden) == other.sum()


def test_pixels_touching_at_a_corner_are_joined():
    # The one way a traced OpenCV polygon's grown outline differs from the mask's marching-squares
    # outline: OpenCV traces 8-connected borders through both pixels of a diagonal pair, and the grown
    # polygon joins them by a strip 0.71 px wide; skimage's outline (background 8-connected) separates
    # them, and the mask route keeps the larger part's outline (its pixels keep both: clean_mask).
    mask = np.zeros((20, 20), bool)
    mask[3:9, 3:9] = True
    mask[9:12, 9:12] = True
    cam = camera(mask.shape)
    got = Observation.from_outline(cam, rings(mask, "opencv"), "pixel-centres", rng=0)
    native = Observation.from_mask(cam, mask, rng=0)
    assert abs(polygon_area(native.contour)) == 36 - 0.5
    assert abs(polygon_area(got.contour)) == 35.5 + 8.5 + 0.5  # both blocks' outlines and the bridge
    assert got.area_px == native.area_px == 45 and np.allclose(got.centroid, native.centroid)


def test_tiny_polygons():
    cam = camera((20, 20))
    dot = np.zeros((20, 20), bool)
    dot[5:7, 5:8] = True  # six pixels: OpenCV traces four centres
    got = Observation.from_outline(cam, rings(dot, "opencv"), "pixel-centres", rng=0)
    native = Observation.from_mask(cam, dot, rng=0)
    np.testing.assert_array_equal(got.contour, native.contour)
    assert got.area_px == 6
    # a triangle holding no pixel centre: its own area and centroid
    tri = np.array([[3.6, 3.6], [4.9, 3.6], [3.6, 4.5]])
    obs = Observation.from_outline(cam, [tri], rng=0)
    assert obs.area_px == 1 and np.allclose(obs.centroid, tri.mean(axis=0))


@pytest.mark.parametrize("polygons, convention, match", [
    ([np.array([[1.0, 1.0], [5.0, 1.0]])], "outline", r"polygons\[0\] has 2 vertices; a polygon needs >= 3"),
    ([np.array([[1.0, 1.0], [5.0, np.nan], [3.0, 4.0]])], "outline", r"polygons\[0\] contains NaN"),
    ([np.array([[1.0, 1.0], [5.0, 1.0], [9.0, 1.0]])], "outline", r"enclose no area \(their vertices are collinear or repeated\)"),
    ([np.array([[1.0, 1.0], [1.5, 1.0], [1.0, 1.5]])], "outline", r"enclose 0.125 px\^2, less than a single pixel"),
    ([np.array([[70.0, 1.0], [80.0, 1.0], [75.0, 9.0]])], "outline", "lie outside the 64x48 image"),
    ([np.array([[-1.0, -1.0], [65.0, -1.0], [65.0, 49.0], [-1.0, 49.0]])], "outline", "cover the whole image"),
    ([np.array([[1.0, 1.0], [9.0, 1.0], [5.0, 9.0]])], "opencv", r"polygon convention must be one of \['outline'"),
    ("10 10 20 10 15 20", "outline", "polygons must be a non-empty list of"),
    ([], "outline", "polygons must be a non-empty list of"),
])
def test_bad_polygons(polygons, convention, match):
    with pytest.raises(ValueError, match=match):
        Observation.from_outline(camera((48, 64)), polygons, convention)
    assert MIN_REGION_AREA_PX == 0.5


def test_densify_splits_at_the_pixel_centre_lines():
    ring = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 0.5]])
    np.testing.assert_allclose(densify(ring), [[0, 0], [0.5, 0], [1.5, 0], [2.5, 0], [2.5, 0.5], [1.5, 0.3], [0.5, 0.1]])
    # a traced outline stripped of the vertices inside its straight runs gets them back
    contour = outer_contour(superellipse(9))
    got = region_outline(shapely.Polygon(contour))
    assert len(got) == len(contour) and set(map(tuple, got)) == set(map(tuple, contour))


# --- auto-detection ---------------------------------------------------------------------------------------

def test_the_convention_is_detected_from_the_vertices():
    import cv2

    mask = superellipse(1)
    assert detect_polygon_convention(rings(mask, "opencv"))[0] == "pixel-centres"
    assert detect_polygon_convention(rings(mask, "opencv", cv2.CHAIN_APPROX_SIMPLE))[0] == "pixel-centres"
    assert detect_polygon_convention(rings(mask, "skimage"))[0] == "outline"
    hand = [np.array([[10.0, 10.0], [30.0, 10.0], [20.0, 25.0]]), np.array([[40.5, 40.5], [45.5, 40.5], [41.2, 47.0]])]
    found, reason = detect_polygon_convention(hand)
    assert found == "outline" and reason == "4 of 6 polygon vertices lie off pixel centres"
    assert detect_polygon_convention([]) == (None, "no polygon")
    assert polygon_reading(rings(mask, "opencv"))[0] == "pixel-centres"
    assert polygon_reading(rings(mask, "opencv"), "raster") == ("raster", "1 COCO polygon(s) rasterised by "
                                                                 "pycocotools (--polygon-convention raster)")
    assert polygon_reading([], "outline") == (None, "")
    with pytest.raises(ValueError, match=r"polygon convention must be one of \['auto', 'pixel-centres', 'outline', "
                                         r"'raster'\], got 'opencv'"):
        polygon_reading([], "opencv")


# --- a user's COCO file -----------------------------------------------------------------------------------

NAMES = ["view_00.png", "view_01.png", "view_02.png"]


def user_scene(root, trial, encoding):
    """A COCO file (track 7 = the trial's object, track 8 = a box beside it) and a COLMAP model."""
    images, annotations = [], []
    for k, (name, mask) in enumerate(zip(NAMES, trial.masks)):
        rows, cols = np.nonzero(mask)
        right = int(np.median(rows[cols == cols.max()]))
        other = np.zeros_like(mask)
        other[right - 8:right + 8, cols.max() + 1:cols.max() + 20] = True  # touching it on the right
        images.append({"id": k + 1, "file_name": name, "width": 640, "height": 480})
        for track, m in ((7, mask), (8, other)):
            segm = encode_mask(m)[0] if encoding == "rle" else mask_to_polygons(m, encoding)
            annotations.append({"id": len(annotations) + 1, "image_id": k + 1, "category_id": 1, "track_id": track,
                                "segmentation": segm, "iscrowd": 0})
    coco = root / f"{encoding}.json"
    coco.write_text(json.dumps({"images": images, "annotations": annotations, "categories": []}))
    if not (root / "sparse" / "0").exists():
        write_colmap(root / "sparse" / "0", dict(zip(NAMES, trial.cameras)))
    return coco, root / "sparse" / "0"


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    pytest.importorskip("pycolmap")
    root = tmp_path_factory.mktemp("polyroute")
    trial = paper_trial(3)
    return {enc: user_scene(root, trial, enc) for enc in ("rle", "opencv", "skimage")}, root


def test_observe_track_reads_polygons_as_the_masks_they_outline(scene_files):
    files, _ = scene_files
    views = {}
    for encoding in ("rle", "opencv", "skimage"):
        scene = load_import(*files[encoding])
        assert scene.polygons == {"rle": None, "opencv": "pixel-centres", "skimage": "outline"}[encoding]
        views[encoding] = observe_track(scene, 7, rng=track_rng(0, 7)).observations
    for encoding in ("opencv", "skimage"):
        for ref, got in zip(views["rle"], views[encoding]):
            np.testing.assert_array_equal(got.contour, ref.contour)
            np.testing.assert_array_equal(got.contour_labels, ref.contour_labels)
            np.testing.assert_array_equal(got.hidden, ref.hidden)
            assert got.area_px == ref.area_px and np.allclose(got.centroid, ref.centroid, atol=1e-12)
            assert (got.contour_labels == INSTANCE).any()  # the box beside it
    # read in the wrong convention, outlines grow by half a pixel step; rasterised, OpenCV's lose pixels
    grown = observe_track(load_import(*files["skimage"], polygon_convention="pixel-centres"), 7).observations
    raster = observe_track(load_import(*files["opencv"], polygon_convention="raster"), 7).observations
    for ref, big, small in zip(views["rle"], grown, raster):
        assert polygon_area(big.contour) > polygon_area(ref.contour) > polygon_area(small.contour)
        assert ref.area_px > small.area_px


def test_fit_coco_polygon_convention_option(scene_files, capsys):
    files, root = scene_files
    fits = {}
    for encoding, extra in (("rle", []), ("opencv", []), ("skimage", []), ("opencv", ["--polygon-convention", "outline"])):
        out = root / f"fits-{encoding}-{len(extra)}.jsonl"
        coco, model = files[encoding]
        assert main(["fit", "--coco", str(coco), "--poses", str(model), "-o", str(out), "--no-progress", *extra]) == 0
        printed = capsys.readouterr().out
        if encoding == "rle":
            assert "COCO polygon" not in printed
        elif extra:
            assert "6 COCO polygon(s) read as outlines, taken as they are (--polygon-convention outline)" in printed
        else:
            assert {"opencv": "through boundary pixels' centres, grown half a pixel step (auto: all",
                    "skimage": "read as outlines, taken as they are (auto: "}[encoding] in printed
        records = {r["track_id"]: r for r in map(json.loads, out.read_text().splitlines())}
        assert [r["status"] for r in records.values()] == ["ok", "ok"]
        fits[encoding, bool(extra)] = records[7]["params"]
    from sqfit import Superquadric

    ref = Superquadric.from_vector(fits["rle", False])
    for key in (("opencv", False), ("skimage", False)):  # one answer, whatever the encoding
        assert iou_3d(Superquadric.from_vector(fits[key]), ref) > 0.99
    assert fits["opencv", True] != fits["opencv", False]


def test_polygon_convention_needs_a_coco_file(tmp_path):
    from _helpers import run_command

    res = run_command("sqfit", "fit", tmp_path, "-o", tmp_path / "f.jsonl", "--polygon-convention", "outline")
    assert res.returncode == 2 and "--polygon-convention reads the polygons of a --coco file" in res.stderr
    res = run_command("sqfit", "fit", "--coco", tmp_path / "a.json", "--poses", tmp_path, "-o", tmp_path / "f.jsonl",
                      "--polygon-convention", "opencv")
    assert res.returncode == 2 and "invalid choice: 'opencv'" in res.stderr
