import numpy as np
import pytest
from scipy.spatial import ConvexHull

from sqfit import Camera, Intrinsics, Superquadric, look_at, project
from sqfit.silhouette import ZNEAR, polygon_area, polygon_iou, silhouette
from sqfit.superquadric import to_mesh

CAM = Camera(Intrinsics(640, 480, 400.0, 300.0, 320.0, 240.0), look_at([10.0, 0, 0], [0, 0, 0]))
SHAPES = [(0.1, 0.1), (0.1, 1.9), (1.9, 0.1), (1.9, 1.9), (1.0, 1.0), (0.5, 1.4)]


def mesh_hull(sq, cam, resolution=96):
    px, depth = project(cam, to_mesh(sq, resolution).vertices)
    assert depth.min() > 0
    return px[ConvexHull(px).vertices]


@pytest.mark.parametrize("shape", SHAPES)
def test_silhouette_matches_dense_mesh_hull(shape):
    rng = np.random.default_rng(int(10 * shape[0] + 100 * shape[1]))
    sq = Superquadric(rng.uniform(0.3, 2.0, 3), shape, rng.uniform(-1, 1, 3), rng.uniform(-np.pi, np.pi, 3))
    sil = silhouette(sq, CAM, 256)
    assert sil.shape == (256, 2) and polygon_area(sil) > 0  # counter-clockwise
    assert polygon_iou(sil, mesh_hull(sq, CAM)) > 0.995
    # The default resolution is close too, and inscribed: never larger than the exact one.
    assert polygon_iou(silhouette(sq, CAM), sil) > 0.98
    assert polygon_area(silhouette(sq, CAM)) <= polygon_area(sil) * (1 + 1e-9)


def test_sphere_silhouette_is_the_analytic_ellipse():
    # A sphere of radius r at distance D centred on the axis: a circle of angular radius asin(r/D),
    # scaled by fx horizontally and fy vertically.
    r, D = 1.5, 10.0
    sil = silhouette(Superquadric((r, r, r)), CAM, 512)
    half_angle = np.arcsin(r / D)
    expected = np.pi * 400.0 * 300.0 * np.tan(half_angle) ** 2
    assert polygon_area(sil) == pytest.approx(expected, rel=1e-4)
    np.testing.assert_allclose(sil.mean(axis=0), [320.0, 240.0], atol=1e-6)


@pytest.mark.parametrize("position", [(10.0, 0.0, 0.0), (12.0, 0.0, 0.0), (9.5, 0.0, 0.0)])
def test_superquadric_at_or_behind_the_camera_has_no_silhouette(position):
    sq = Superquadric((1.0, 1.0, 1.0), position=position)
    sil = silhouette(sq, CAM)
    assert sil.shape == (0, 2)
    assert polygon_iou(sil, silhouette(Superquadric((1.0, 1.0, 1.0)), CAM)) == 0.0


def test_znear_boundary():
    # Closest point at depth exactly 2 * ZNEAR in front: still a silhouette.
    sq = Superquadric((0.5, 0.5, 0.5), position=(10.0 - 0.5 - 2 * ZNEAR - 0.5, 0.0, 0.0))
    assert len(silhouette(sq, CAM)) > 0


def square(x0, y0, s):
    return np.array([[x0, y0], [x0 + s, y0], [x0 + s, y0 + s], [x0, y0 + s]], float)


@pytest.mark.parametrize("q, expected", [
    (square(0, 0, 2), 1.0),
    (square(1, 0, 2), 2 / 6),
    (square(0.5, 0.5, 1), 0.25),
    (square(2, 2, 2), 0.0),
    (square(5, 5, 1), 0.0),
    (square(1, 1, 2)[::-1], 1 / 7),
])
def test_polygon_iou_known_values(q, expected):
    assert polygon_iou(square(0, 0, 2), q) == pytest.approx(expected, abs=1e-12)
    assert polygon_iou(q, square(0, 0, 2)) == pytest.approx(expected, abs=1e-12)


def test_polygon_iou_convex_path_agrees_with_shapely():
    import shapely

    rng = np.random.default_rng(0)
    for _ in range(20):
        p = rng.normal(size=(30, 2)) * rng.uniform(1, 5)
        q = rng.normal(size=(25, 2)) * rng.uniform(1, 5) + rng.normal(size=2)
        p, q = p[ConvexHull(p).vertices], q[ConvexHull(q).vertices]
        a, b = shapely.Polygon(p), shapely.Polygon(q)
        ref = a.intersection(b).area / a.union(b).area
        assert polygon_iou(p, q) == pytest.approx(ref, abs=1e-10)


def test_polygon_iou_non_convex_uses_shapely():
    L = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)  # area 3
    assert polygon_iou(L, square(0, 0, 2)) == pytest.approx(3 / 4)
    assert polygon_iou(L, square(1, 1, 1)) == pytest.approx(0.0)


def test_polygon_iou_degenerate_and_bad_input():
    assert polygon_iou(np.zeros((0, 2)), square(0, 0, 1)) == 0.0
    assert polygon_iou(np.array([[0, 0], [1, 1], [2, 2]], float), square(0, 0, 1)) == 0.0
    with pytest.raises(ValueError, match=r"p must have shape \(n, 2\)"):
        polygon_iou(np.zeros((3, 3)), square(0, 0, 1))
    with pytest.raises(ValueError, match="n_directions must be an integer >= 3"):
        silhouette(Superquadric((1, 1, 1)), CAM, 2)
