"""Segmenter-like mask models: each tested against its parameter on shapes with known answers."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage

from sqsim.imaging.mask_models import (HOLE_AREA_UNIT_PX, HOLE_RIM_PX, apply_mask_models, bias_boundary, draw_bias,
                               mask_models_active, outline_contours, punch_holes, remove_thin_parts,
                               signed_distance, smooth_boundary_error, smooth_outline)
from sqsim.imaging.noise import corrupt_image, corrupts_masks
from sqsim.world.scene import NoiseConfig, parse_scene


def disc(radius, centre=(60.0, 80.0), shape=(120, 160)):
    """Pixels whose centre (i + 0.5, j + 0.5) is within ``radius`` of ``centre`` (row, col)."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] + 0.5
    return (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= radius ** 2


def radius_of(mask):
    return np.sqrt(mask.sum() / np.pi)


def radial_boundary(mask, centre, n_rays=720):
    """Distance from ``centre`` (row, col) to the first background pixel along each of n rays."""
    r_max = min(centre[0], centre[1], mask.shape[0] - centre[0], mask.shape[1] - centre[1]) - 1.0
    r = np.arange(0.0, r_max, 0.02)
    out = []
    for t in np.linspace(0.0, 2 * np.pi, n_rays, endpoint=False):
        rows = np.floor(centre[0] + r * np.sin(t)).astype(int)
        cols = np.floor(centre[1] + r * np.cos(t)).astype(int)
        out.append(r[np.argmin(mask[rows, cols])])
    return np.array(out)


# --- the outline -----------------------------------------------------------------------------------

def test_outline_passes_between_pixel_centres_and_closes():
    m = np.zeros((10, 12), bool)
    m[2:5, 3:9] = True
    m[0, 0] = True  # touches the image border: the border counts as background
    contours = outline_contours(m)
    assert len(contours) == 2 and all(np.array_equal(c[0], c[-1]) for c in contours)
    box = max(contours, key=len)
    assert box[:, 0].min() == 1.5 and box[:, 0].max() == 4.5 and box[:, 1].min() == 2.5 and box[:, 1].max() == 8.5


def test_smooth_outline_of_a_disc_is_the_circle():
    # The staircase's length overestimates a circle's by ~5 %; the smoothed outline by < 1 %.
    for centre in [(60.0, 80.0), (60.3, 80.7)]:
        m = disc(30.0, centre)
        region = smooth_outline(m)
        assert region.length == pytest.approx(2 * np.pi * 30.0, rel=0.01)
        assert region.area == pytest.approx(m.sum(), rel=0.01)


def test_signed_distance_sign_is_the_masks_and_magnitude_the_distance():
    m = disc(30.0)
    sd = signed_distance(m)
    assert np.all(sd[m] >= 0) and np.all(sd[~m] <= 0)
    yy, xx = np.mgrid[0:120, 0:160] + 0.5
    true = 30.0 - np.hypot(yy - 60.0, xx - 80.0)
    near = np.abs(true) < 3
    assert np.median(np.abs(sd - true)[near]) < 0.1
    assert np.all(np.isinf(signed_distance(np.zeros((5, 5), bool))))


# --- boundary bias ---------------------------------------------------------------------------------

@pytest.mark.parametrize("delta", [0.2, 0.5, 1.0, 2.5, -0.3, -1.0, -2.5])
@pytest.mark.parametrize("centre", [(60.0, 80.0), (60.37, 80.81)])
def test_bias_changes_a_discs_radius_by_delta(delta, centre):
    m = disc(35.0, centre)
    out = bias_boundary(m, delta)
    assert radius_of(out) - radius_of(m) == pytest.approx(delta, abs=0.1)
    assert np.all(out[m]) if delta > 0 else not np.any(out & ~m)
    # Evenly all round: the boundary is a circle of radius 35 + delta (to the pixel).
    r = radial_boundary(out, centre)
    assert np.abs(r - (35.0 + delta)).max() < 1.0 and np.std(r) < 0.4


def test_bias_moves_straight_edges_by_whole_pixels_at_integer_amounts():
    m = np.zeros((60, 80), bool)
    m[10:50, 10:60] = True
    grown, shrunk = bias_boundary(m, 2.0), bias_boundary(m, -1.0)
    assert grown[12:48].sum(axis=1).tolist() == [54] * 36 and grown[:, 12:58].sum(axis=0).tolist() == [44] * 46
    assert shrunk[12:48].sum(axis=1).tolist() == [48] * 36 and shrunk[:, 12:58].sum(axis=0).tolist() == [38] * 46


def test_bias_zero_and_tiny_amounts_change_nothing_and_draws_are_seeded():
    m = disc(20.0)
    for delta in (0.0, 1e-3, -1e-3):
        np.testing.assert_array_equal(bias_boundary(m, delta), m)
    assert draw_bias(0.7, 0.0, rng=1) == 0.7  # no draw without spread
    draws = [draw_bias(0.5, 2.0, rng) for rng in [np.random.default_rng(0)] * 4000]
    assert np.mean(draws) == pytest.approx(0.5, abs=0.1) and np.std(draws) == pytest.approx(2.0, rel=0.05)


def test_bias_removes_a_thin_line_only_when_it_exceeds_its_half_width():
    m = np.zeros((40, 60), bool)
    m[20, 5:55] = True
    assert bias_boundary(m, -0.6).sum() == 0
    assert bias_boundary(m, -0.3).sum() > 0


# --- smooth boundary error -------------------------------------------------------------------------

@pytest.mark.parametrize("amplitude", [1.0, 2.0, 4.0])
def test_smooth_error_has_the_requested_rms(amplitude):
    m = disc(40.0, (70.0, 80.0), (140, 160))
    displacement = np.concatenate([radial_boundary(smooth_boundary_error(m, amplitude, 32.0, rng=seed),
                                                   (70.0, 80.0)) - 40.0 for seed in range(4)])
    assert np.sqrt(np.mean(displacement ** 2)) == pytest.approx(amplitude, rel=0.25)


@pytest.mark.parametrize("wavelength", [32.0, 64.0])
def test_smooth_error_varies_along_the_outline_no_faster_than_its_wavelength(wavelength):
    # A straight edge displaced by the field: along the edge, the displacement's spectrum holds
    # (almost) no power at wavelengths shorter than `wavelength`; the rest is pixel quantisation.
    m = np.zeros((100, 1024), bool)
    m[50:, :] = True
    window = np.hanning(1024)
    spectra, shifts = [], []
    for seed in range(6):
        shift = 50.0 - np.argmax(smooth_boundary_error(m, 2.0, wavelength, rng=seed), axis=0)
        shifts.append(shift)
        spectra.append(np.abs(np.fft.rfft((shift - shift.mean()) * window)) ** 2)
    spectrum = np.mean(spectra, axis=0)
    freq = np.fft.rfftfreq(1024)
    assert spectrum[freq > 1.5 / wavelength].sum() < 0.05 * spectrum.sum()
    assert np.sqrt(np.mean(np.square(shifts))) == pytest.approx(2.0, rel=0.3)


def test_smooth_error_zero_amplitude_and_seeding():
    m = disc(25.0)
    np.testing.assert_array_equal(smooth_boundary_error(m, 0.0, 32.0, rng=3), m)
    np.testing.assert_array_equal(smooth_boundary_error(m, 2.0, 32.0, rng=3), smooth_boundary_error(m, 2.0, 32.0, rng=3))
    assert not np.array_equal(smooth_boundary_error(m, 2.0, 32.0, rng=3), m)


# --- thin parts -------------------------------------------------------------------------------------

def disc_with_bar(bar_width):
    m = disc(20.0, (50.0, 50.0), (100, 160))
    m[50 - bar_width // 2:50 - bar_width // 2 + bar_width, 50:140] = True
    return m


@pytest.mark.parametrize("bar, width, kept", [(1, 0.8, True), (1, 1.2, False), (2, 3.0, False), (4, 3.0, True),
                                               (4, 4.5, False), (5, 4.5, True), (6, 7.0, False), (8, 7.0, True)])
def test_opening_removes_parts_thinner_than_the_width(bar, width, kept):
    m = disc_with_bar(bar)
    out = remove_thin_parts(m, width)
    assert not np.any(out & ~m)
    far_bar = (slice(None), slice(80, 135))  # the bar away from the disc and from its rounded end
    assert out[far_bar].sum() == (m[far_bar].sum() if kept else 0)
    np.testing.assert_array_equal(out[:, :60], m[:, :60])  # the disc itself stays


def test_opening_keeps_straight_edges_and_rounds_corners():
    m = np.zeros((60, 80), bool)
    m[10:50, 10:60] = True
    out = remove_thin_parts(m, 6.0)
    np.testing.assert_array_equal(out[13:47], m[13:47])
    np.testing.assert_array_equal(out[:, 13:57], m[:, 13:57])
    lost = (m & ~out).sum()
    assert 4 * (1 - np.pi / 4) * 3.0 ** 2 * 0.5 < lost < 4 * 3.0 ** 2  # four corners of radius 3
    np.testing.assert_array_equal(remove_thin_parts(m, 0.0), m)


# --- holes ------------------------------------------------------------------------------------------

def test_holes_come_at_the_rate_inside_the_mask():
    m = disc(50.0, (60.0, 80.0), (120, 160))
    rate, radius = 1.0, 2.0
    counts = []
    for seed in range(60):
        out = punch_holes(m, rate, radius, rng=seed)
        assert not np.any(out & ~m)
        holes, n = ndimage.label(m & ~out)
        counts.append(n)
        # Interior: every hole keeps a rim of mask to the outline.
        assert np.all(ndimage.distance_transform_edt(np.pad(m, 1))[1:-1, 1:-1][holes > 0] > radius + HOLE_RIM_PX - 0.5)
        sizes = np.bincount(holes.ravel())[1:]
        assert np.all(sizes >= 9)  # a disc of radius 2 covers 9 to 16 pixel centres (merged ones more)
    expected = rate * m.sum() / HOLE_AREA_UNIT_PX
    assert np.mean(counts) == pytest.approx(expected, rel=0.1)  # a few merge where they overlap
    np.testing.assert_array_equal(punch_holes(m, 0.0, radius, rng=0), m)


def test_holes_need_room():
    m = np.zeros((30, 30), bool)
    m[10:14, 5:25] = True  # 4 px thick: no place 3 px deep
    np.testing.assert_array_equal(punch_holes(m, 50.0, 2.0, rng=0), m)


# --- scenes and id images ---------------------------------------------------------------------------

def test_scene_keys_drive_the_models_per_instance():
    image = np.zeros((120, 160), np.uint16)
    image[disc(25.0, (60.0, 50.0))] = 1
    image[disc(25.0, (60.0, 110.0))] = 2
    clean = NoiseConfig()
    assert not corrupts_masks(clean) and not mask_models_active(clean)
    np.testing.assert_array_equal(corrupt_image(image, clean, rng=0), image)
    grown = corrupt_image(image, NoiseConfig(boundary_bias_px=2.0), rng=0)
    for oid, centre in [(1, (60.0, 50.0)), (2, (60.0, 110.0))]:
        assert radius_of(grown == oid) - radius_of(image == oid) == pytest.approx(2.0, abs=0.25)
        assert np.all(grown[image == oid] == oid)  # original pixels keep their ids
    # Per object and view: two objects get different draws from N(mean, std).
    noisy = corrupt_image(image, NoiseConfig(boundary_bias_px=0.0, boundary_bias_std_px=3.0), rng=1)
    changes = [radius_of(noisy == k) - radius_of(image == k) for k in (1, 2)]
    assert abs(changes[0] - changes[1]) > 0.2
    every = NoiseConfig(thin_part_width_px=3.0, smooth_error_px=1.0, boundary_bias_px=-0.5, hole_rate=2.0)
    assert corrupts_masks(every) and mask_models_active(every)
    out = corrupt_image(image, every, rng=0)
    np.testing.assert_array_equal(out, corrupt_image(image, every, rng=0))
    assert set(np.unique(out)) == {0, 1, 2} and (out == 1).sum() < (image == 1).sum()


def test_models_off_leave_the_random_stream_alone():
    # A scene without the new models draws the same numbers as before they existed.
    m = disc(25.0)
    rng = np.random.default_rng(5)
    apply_mask_models(m, NoiseConfig(), rng)
    assert rng.random() == np.random.default_rng(5).random()


def test_scene_validates_the_keys():
    s = parse_scene({"noise": {"boundary_bias_px": -1.5, "boundary_bias_std_px": 0.5, "smooth_error_px": 2.0,
                               "smooth_error_wavelength_px": 20, "thin_part_width_px": 3, "hole_rate": 0.5,
                               "hole_radius_px": 1.5}})
    assert s.noise.boundary_bias_px == -1.5 and s.noise.smooth_error_wavelength_px == 20.0 and not s.noise_free
    assert parse_scene({"noise": {"smooth_error_wavelength_px": 10.0, "hole_radius_px": 4.0}}).noise_free
    assert replace(s.noise, boundary_bias_px=0.0).boundary_bias_std_px == 0.5


@pytest.mark.parametrize("key, value, match", [
    ("boundary_bias_px", float("nan"), "noise.boundary_bias_px must be a finite number"),
    ("boundary_bias_std_px", -0.1, "noise.boundary_bias_std_px must be >= 0"),
    ("smooth_error_px", -1.0, "noise.smooth_error_px must be >= 0"),
    ("smooth_error_wavelength_px", 0.0, "noise.smooth_error_wavelength_px must be > 0"),
    ("thin_part_width_px", -2.0, "noise.thin_part_width_px must be >= 0"),
    ("hole_rate", -0.5, "noise.hole_rate must be >= 0"),
    ("hole_radius_px", 0.0, "noise.hole_radius_px must be > 0"),
    ("hole_rate", "many", "noise.hole_rate must be a finite number"),
])
def test_scene_rejects_bad_values(key, value, match):
    with pytest.raises(ValueError, match=match):
        parse_scene({"noise": {key: value}})


@pytest.mark.parametrize("call, match", [
    (lambda: bias_boundary(np.zeros(5), 1.0), r"mask must have shape \(h, w\)"),
    (lambda: bias_boundary(disc(5.0), float("inf")), "boundary bias must be a finite number"),
    (lambda: bias_boundary(disc(5.0), "x"), "boundary bias must be a finite number"),
    (lambda: draw_bias(0.0, -1.0), "boundary bias std must be a finite number >= 0"),
    (lambda: draw_bias(float("nan"), 1.0), "boundary bias mean must be a finite number"),
    (lambda: smooth_boundary_error(disc(5.0), -1.0, 32.0), "smooth boundary error must be a finite number >= 0"),
    (lambda: smooth_boundary_error(disc(5.0), 1.0, 0.0), "smooth boundary error wavelength must be a finite number > 0"),
    (lambda: remove_thin_parts(disc(5.0), -1.0), "thin-part width must be a finite number >= 0"),
    (lambda: punch_holes(disc(5.0), -1.0, 2.0), "hole rate must be a finite number >= 0"),
    (lambda: punch_holes(disc(5.0), 1.0, 0.0), "hole radius must be a finite number > 0"),
    (lambda: signed_distance(np.zeros((2, 2, 2))), r"mask must have shape \(h, w\)"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("model", [lambda m: bias_boundary(m, -1.5), lambda m: bias_boundary(m, 1.5),
                                   lambda m: smooth_boundary_error(m, 1.0, 32.0, rng=0),
                                   lambda m: remove_thin_parts(m, 6.0)])
def test_an_object_cut_by_the_image_border_goes_on_beyond_it(model):
    m = np.zeros((60, 80), bool)
    m[20:40, :30] = True  # cut by the left border
    out = model(m)
    np.testing.assert_array_equal(out[25:35, 0], m[25:35, 0])  # its cut edge stays on the border
    assert out[:, 0].sum() == pytest.approx(m[:, 0].sum(), abs=4)  # the border-side column stays whole, give or take its ends
