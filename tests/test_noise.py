import numpy as np
import pytest
from scipy import ndimage

import sqfit
from sqsim.imaging.noise import (add_false_blobs, corrupt_image, dilate, drop_out, erode, jitter_boundary,
                         perturb_cameras, perturb_pose)
from sqsim.world.scene import NoiseConfig


def square(h=120, w=160, r0=30, r1=90, c0=40, c1=120):
    m = np.zeros((h, w), bool)
    m[r0:r1, c0:c1] = True
    return m


def disc(radius=35.0, h=120, w=160):
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    return (yy - h / 2) ** 2 + (xx - w / 2) ** 2 <= radius ** 2


@pytest.mark.parametrize("k", [1, 2, 5])
def test_erosion_removes_a_k_pixel_band(k):
    out = erode(square(), k)
    np.testing.assert_array_equal(out, square(r0=30 + k, r1=90 - k, c0=40 + k, c1=120 - k))


@pytest.mark.parametrize("k", [1, 3])
def test_dilation_adds_a_k_pixel_band(k):
    out = dilate(square(), k)
    grown = square(r0=30 - k, r1=90 + k, c0=40 - k, c1=120 + k)
    # Straight edges move by exactly k; the corners are rounded (Euclidean distance).
    np.testing.assert_array_equal(out[30:90], grown[30:90])
    np.testing.assert_array_equal(out[:, 40:120], grown[:, 40:120])
    assert not out[30 - k, 40 - k] and out.sum() < grown.sum()


def test_erosion_and_dilation_of_a_disc_change_its_radius():
    area = disc().sum()
    for k in (2, 4):
        r_er = np.sqrt(erode(disc(), k).sum() / np.pi)
        r_di = np.sqrt(dilate(disc(), k).sum() / np.pi)
        r0 = np.sqrt(area / np.pi)
        assert r0 - r_er == pytest.approx(k, abs=0.5)
        assert r_di - r0 == pytest.approx(k, abs=0.5)


@pytest.mark.parametrize("sigma", [1.0, 3.0])
def test_boundary_jitter_has_the_requested_std(sigma):
    # Radius of the jittered disc along 360 rays, minus the clean radius: std ~= sigma.
    base = disc()
    diffs = []
    for seed in range(4):
        out = jitter_boundary(base, sigma, rng=seed)
        dist = ndimage.distance_transform_edt(~out)  # distance of outside pixels to the mask
        sd_new = np.where(out, ndimage.distance_transform_edt(out) - 0.5, 0.5 - dist)
        sd_old = np.where(base, ndimage.distance_transform_edt(base) - 0.5,
                          0.5 - ndimage.distance_transform_edt(~base))
        edge = np.abs(sd_old) < 0.75  # pixels along the clean boundary
        diffs.append((sd_new - sd_old)[edge])
    measured = np.std(np.concatenate(diffs))
    assert measured == pytest.approx(sigma, rel=0.3)
    assert not np.array_equal(jitter_boundary(base, sigma, rng=0), base)


def test_jitter_zero_and_seeding():
    np.testing.assert_array_equal(jitter_boundary(disc(), 0.0, rng=1), disc())
    np.testing.assert_array_equal(jitter_boundary(disc(), 2.0, rng=1), jitter_boundary(disc(), 2.0, rng=1))


@pytest.mark.parametrize("fraction", [0.05, 0.2, 0.5])
def test_dropout_removes_the_requested_fraction_in_blobs(fraction):
    base = disc()
    out = drop_out(base, fraction, rng=0)
    assert not np.any(out & ~base)
    removed = base & ~out
    assert removed.sum() == round(fraction * base.sum())
    n_blobs = ndimage.label(removed)[1]
    assert 1 <= n_blobs < removed.sum() / 10  # blobs, not salt-and-pepper


def test_false_blobs_add_separate_components():
    base = disc(20.0)
    out = add_false_blobs(base, 3, rng=0)
    assert np.all(out[base])
    labels, n = ndimage.label(out)
    assert n == 4
    sizes = sorted(np.bincount(labels.ravel())[1:])[:3]
    r = 0.15 * np.sqrt(base.sum())
    for s in sizes:
        assert s == pytest.approx(np.pi * r ** 2, rel=0.35)


def test_corrupt_image_keeps_ids_and_order():
    image = np.zeros((120, 160), np.uint16)
    image[square()] = 1
    image[20:40, 10:30] = 2
    noise = NoiseConfig(erosion_px=1, dropout=0.1, false_blobs=1)
    out = corrupt_image(image, noise, rng=0)
    assert out.dtype == np.uint16 and set(np.unique(out)) <= {0, 1, 2}
    np.testing.assert_array_equal(out, corrupt_image(image, noise, rng=0))
    assert (out == 1).sum() < (image == 1).sum()
    dil = corrupt_image(image, NoiseConfig(dilation_px=3), rng=0)
    assert np.all(dil[image == 1] == 1) and np.all(dil[image == 2] == 2)  # original pixels keep ids


def test_pose_noise_statistics():
    rng = np.random.default_rng(0)
    pose = sqfit.look_at([10.0, 0, 0], [0, 0, 0])
    angles, shifts = [], []
    for _ in range(2000):
        noisy = perturb_pose(pose, 2.0, 0.1, rng)
        dR = pose[:3, :3].T @ noisy[:3, :3]
        angles.append(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))
        shifts.append(noisy[:3, 3] - pose[:3, 3])
    # Per-axis std sigma: the rotation angle has RMS sqrt(3) sigma; the shift std is sigma per axis.
    assert np.sqrt(np.mean(np.square(angles))) / np.sqrt(3) == pytest.approx(2.0, rel=0.05)
    np.testing.assert_allclose(np.std(shifts, axis=0), 0.1, rtol=0.1)
    cams = [sqfit.Camera(sqfit.Intrinsics(10, 10, 5, 5, 5, 5), pose)]
    assert perturb_cameras(cams, 0.0, 0.0, 0)[0] is cams[0]
    moved = perturb_cameras(cams, 1.0, 0.0, 0)[0]
    np.testing.assert_array_equal(moved.center, cams[0].center)


@pytest.mark.parametrize("call, match", [
    (lambda: erode(square(), -1), "erosion must be an integer"),
    (lambda: dilate(square(), 1.5), "dilation must be an integer"),
    (lambda: erode(np.zeros(5), 1), r"mask must have shape \(h, w\)"),
    (lambda: jitter_boundary(square(), -1.0), "boundary jitter must be a finite number >= 0"),
    (lambda: drop_out(square(), 1.0), r"dropout fraction must be in \[0, 1\)"),
    (lambda: add_false_blobs(square(), -2), "false_blobs must be an integer"),
    (lambda: perturb_pose(np.eye(3), 1.0, 1.0), r"pose must have shape \(4, 4\)"),
    (lambda: perturb_pose(np.full((4, 4), np.nan), 1.0, 1.0), "pose contains NaN"),
    (lambda: perturb_pose(np.eye(4), float("nan"), 1.0), "pose rotation noise must be"),
    (lambda: corrupt_image(np.zeros(4), NoiseConfig()), r"image must have shape \(h, w\)"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()
