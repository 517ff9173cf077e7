import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.draw import polygon as skimage_polygon

from sqfit.views.observation import convex_hull
from sqfit.geometry.raster import fill_convex_polygon


def test_pixel_centre_convention():
    mask = fill_convex_polygon(np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 2.0], [1.0, 2.0]]), (4, 5))
    expected = np.zeros((4, 5), bool)
    expected[1, 1:3] = True  # centres (1.5, 1.5) and (2.5, 1.5)
    np.testing.assert_array_equal(mask, expected)


def test_shared_edges_claim_each_pixel_once():
    left = np.array([[0.5, 0.5], [4.0, 0.5], [4.0, 9.5], [0.5, 9.5]])
    right = left + [3.5, 0.0]
    a, b = fill_convex_polygon(left, (10, 10)), fill_convex_polygon(right, (10, 10))
    # Rows 0..8 (centres 0.5..8.5 < 9.5), columns 0..3 left and 4..6 right (6.5 < 7.5 <= 7.5).
    assert not (a & b).any()
    assert a[:9, :4].all() and b[:9, 4:7].all() and (a | b).sum() == 9 * 7


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(3, 40))
def test_matches_scikit_image_on_random_convex_polygons(seed, n):
    rng = np.random.default_rng(seed)
    hull = convex_hull(rng.uniform([-20, -20], [90, 70], (n, 2)))
    if len(hull) < 3:
        return
    expected = np.zeros((50, 70), bool)
    rr, cc = skimage_polygon(hull[:, 1] - 0.5, hull[:, 0] - 0.5, shape=expected.shape)
    expected[rr, cc] = True
    got = fill_convex_polygon(hull, expected.shape)
    got_reversed = fill_convex_polygon(hull[::-1], expected.shape)
    np.testing.assert_array_equal(got, got_reversed)
    # Random real vertices never put a pixel centre exactly on an edge: the masks must be equal.
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("poly", [np.zeros((2, 2)), np.array([[-5.0, -5], [-1, -5], [-1, -1]])])
def test_degenerate_or_outside_polygons_give_empty_masks(poly):
    assert not fill_convex_polygon(poly, (8, 8)).any()


def test_rejects_bad_polygons():
    with pytest.raises(ValueError, match=r"polygon must have shape \(n, 2\)"):
        fill_convex_polygon(np.zeros((3, 3)), (8, 8))
    with pytest.raises(ValueError, match="polygon contains NaN"):
        fill_convex_polygon(np.full((3, 2), np.nan), (8, 8))
