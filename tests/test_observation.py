import numpy as np
import pytest

from sqfit import Observation
from sqfit.views.observation import convex_hull, outer_contour

from _helpers import CAM, rect_mask  # noqa: E402


def test_contour_runs_along_pixel_edges():
    contour = outer_contour(rect_mask())
    # Pixel columns 5..29 span u in [5, 30]; rows 10..19 span v in [10, 20] (corners are cut).
    np.testing.assert_allclose([contour[:, 0].min(), contour[:, 0].max()], [5.0, 30.0])
    np.testing.assert_allclose([contour[:, 1].min(), contour[:, 1].max()], [10.0, 20.0])


@pytest.mark.parametrize("sampling", ["uniform", "contour", "mixed"])
def test_samples_lie_in_the_mask(sampling):
    obs = Observation.from_mask(CAM, rect_mask(), n_samples=200, sampling=sampling, rng=3)
    assert obs.samples.shape == (200, 2)
    assert np.all((obs.samples[:, 0] >= 5) & (obs.samples[:, 0] <= 30))
    assert np.all((obs.samples[:, 1] >= 10) & (obs.samples[:, 1] <= 20))
    on_edge = np.isclose(obs.samples, [[5, 10]]).any(1) | np.isclose(obs.samples, [[30, 20]]).any(1)
    expected_on_edge = {"uniform": 0.0, "contour": 1.0, "mixed": 0.5}[sampling]
    assert on_edge.mean() == pytest.approx(expected_on_edge, abs=0.05)


def test_samples_are_seeded():
    a = Observation.from_mask(CAM, rect_mask(), rng=7).samples
    b = Observation.from_mask(CAM, rect_mask(), rng=7).samples
    np.testing.assert_array_equal(a, b)


def test_centroid_area_and_polygons():
    obs = Observation.from_mask(CAM, rect_mask(), rng=0)
    np.testing.assert_allclose(obs.centroid, [17.5, 15.0])
    assert obs.area_px == 250 and not obs.touches_border
    assert obs.polygon("contour") is obs.contour
    hull = obs.polygon("hull")
    assert len(hull) >= 3 and np.all(hull >= [5, 10]) and np.all(hull <= [30, 20])
    with pytest.raises(ValueError, match="polygon kind must be one of"):
        obs.polygon("box")


def test_convex_hull_of_square_with_interior_points():
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [0.2, 0.7]])
    hull = convex_hull(pts)
    assert len(hull) == 4
    x, y = hull[:, 0], hull[:, 1]
    assert 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) == pytest.approx(1.0)


def test_border_flag():
    assert Observation.from_mask(CAM, rect_mask(r0=0), rng=0).touches_border
    assert Observation.from_mask(CAM, rect_mask(c1=64), rng=0).touches_border


@pytest.mark.parametrize(
    "mask, match",
    [
        (np.zeros((48, 64), bool), "mask is empty"),
        (np.ones((48, 64), bool), "covers the whole image"),
        (np.zeros((64, 48), bool), r"mask must have shape \(height, width\) = \(48, 64\)"),
        (np.zeros((48, 64), dtype="U1"), "mask must be boolean or numeric"),
    ],
)
def test_bad_masks_are_reported(mask, match):
    with pytest.raises(ValueError, match=match):
        Observation.from_mask(CAM, mask)


def test_bad_arguments_are_reported():
    with pytest.raises(ValueError, match="sampling must be one of"):
        Observation.from_mask(CAM, rect_mask(), sampling="grid")
    with pytest.raises(ValueError, match="n_samples must be an integer >= 3"):
        Observation.from_mask(CAM, rect_mask(), n_samples=2)
    with pytest.raises(ValueError, match="camera must be a sqfit.Camera"):
        Observation.from_mask(None, rect_mask())


def test_cleanup_keeps_the_largest_component_and_fills_holes():
    from sqfit.views.observation import clean_mask

    mask = rect_mask()
    mask[14:16, 15:18] = False  # a hole (a missed part)
    mask[40:43, 50:53] = True  # a false-positive blob
    cleaned = clean_mask(mask)
    np.testing.assert_array_equal(cleaned, rect_mask())
    assert not clean_mask(np.zeros((4, 4), bool)).any()
    raw = Observation.from_mask(CAM, mask, rng=1, cleanup=False)
    tidy = Observation.from_mask(CAM, mask, rng=1)  # clean-up is the default
    assert raw.area_px == 250 - 6 + 9 and tidy.area_px == 250
    assert np.all(tidy.samples[:, 1] <= 20)  # no sample lands on the blob
    assert np.any(raw.samples[:, 1] > 40)


def test_dataset_reader_passes_cleanup_through():
    from sqfit.views.dataset import observations_from_images

    image = rect_mask().astype(np.uint16)
    image[40:43, 50:53] = 1  # a false-positive blob with the object's id
    images = np.stack([image, image])
    raw = observations_from_images([CAM, CAM], images, 1, rng=0, cleanup=False)
    tidy = observations_from_images([CAM, CAM], images, 1, rng=0)
    assert [o.area_px for o in raw] == [259, 259] and [o.area_px for o in tidy] == [250, 250]


def test_with_camera_moves_the_camera_and_keeps_what_the_pixels_gave():
    # the factor graph moves every observation to its current pose estimate many times: what depends
    # on the pixels alone is carried over, and the rays are those of a fresh observation, bit for bit
    from dataclasses import replace

    from sqfit import Camera, look_at
    from sqfit.views.rays import contour_rays

    obs = Observation.from_mask(CAM, rect_mask(), rng=0)
    rays = contour_rays([obs], 16, smooth_px=1.0)
    arc, hull = obs.contour_arc, obs.hull
    other = Camera(CAM.intrinsics, look_at([9.0, 2.0, 1.0], [0, 0, 0.5]))
    moved = obs.with_camera(other)
    assert moved.camera is other and obs.camera is CAM
    assert moved.contour is obs.contour and moved.samples is obs.samples
    assert moved.contour_arc is arc and moved.hull is hull
    fresh = replace(obs, camera=other)  # nothing carried over
    got, want = contour_rays([moved], 16, smooth_px=1.0), contour_rays([fresh], 16, smooth_px=1.0)
    for name in ("origins", "directions", "modes", "weights", "view", "two_sided", "offsets", "radii"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name
    assert not np.array_equal(got.directions, rays.directions)  # the camera did move
    with pytest.raises(ValueError, match="camera must be a Camera"):
        obs.with_camera(other.pose)


def test_derived_values_are_computed_once_and_read_only():
    obs = Observation.from_mask(CAM, rect_mask(), rng=0)
    calls = []

    def compute():
        calls.append(1)
        return np.arange(3.0), np.ones(2)

    first = obs.derived("k", compute)
    assert obs.derived("k", compute) is first and len(calls) == 1
    assert obs.with_camera(CAM).derived("k", compute) is first and len(calls) == 1  # shared by copies
    with pytest.raises(ValueError):
        first[0][0] = 1.0
    from dataclasses import replace

    assert replace(obs, camera=CAM).derived("k", compute) is not first and len(calls) == 2  # not carried
