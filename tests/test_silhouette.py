import numpy as np
import pytest
from scipy.spatial import ConvexHull

from sqfit import Camera, Intrinsics, Superquadric, look_at, project
from sqfit.geometry.polygon import convex_iou, convex_iou_jacobian, polygon_area, polygon_iou
from sqfit.geometry.silhouette import (ZNEAR, batch_silhouettes, camera_arrays, silhouette, silhouette_gradient,
                              vertex_velocities)
from sqfit.geometry.superquadric import to_mesh

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


@pytest.mark.parametrize("q", [
    [[0.5, 0.0], [2.0, 0.0], [2.0, 1.0], [0.5, 1.0]],  # shares parts of two edges with the square
    [[1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [1.0, 1.0]],  # touches along a whole edge: IoU 0
    [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],  # identical
    [[0.25, 0.25], [0.75, 0.25], [0.75, 0.75], [0.25, 0.75]],  # inside
])
def test_convex_iou_shared_edges_and_repeated_vertices(q):
    """Edges on the other polygon's boundary are counted once, and repeated vertices (silhouette
    corners, padding) constrain nothing, in either role."""
    import shapely

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    q = np.array(q)
    ref = shapely.Polygon(square).intersection(shapely.Polygon(q)).area / shapely.Polygon(square).union(
        shapely.Polygon(q)).area
    padded = np.vstack([q, q[-1:], q[-1:]])
    assert convex_iou(square, padded) == pytest.approx(ref, abs=1e-12)
    assert convex_iou(padded, square) == pytest.approx(ref, abs=1e-12)


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


# --- the fitter's fast paths: warm starts, vertex weights, the pulled-back gradient ----------------

CAMS = [CAM, Camera(CAM.intrinsics, look_at([0.0, 9.0, 3.0], [0, 0, 0])),
        Camera(CAM.intrinsics, look_at([-6.0, -6.0, -2.0], [0, 0, 0]))]


def random_xi(rng, shape=None):
    xi = np.r_[rng.uniform(0.4, 1.5, 3), shape if shape is not None else rng.uniform(0.2, 1.8, 2),
               rng.uniform(-0.5, 0.5, 3), rng.uniform(-np.pi, np.pi, 3)]
    return xi


def solve(xi, start=None, k=48, **kw):
    return batch_silhouettes(np.atleast_2d(xi), *camera_arrays(CAMS), k, start, **kw)


def test_warm_start_keeps_its_directions_and_finds_the_same_silhouette():
    rng = np.random.default_rng(0)
    xi = random_xi(rng)
    polys, valid, start = solve(xi)
    assert valid.all()
    moved = xi + rng.normal(size=11) * 0.02
    warm_polys, _, warm = solve(moved, start)
    np.testing.assert_array_equal(warm.directions, start.directions)
    # The same directions from a cold support value (the projected centre) give the same polygon.
    cold_polys, _, _ = solve(moved, start._replace(h=np.full_like(start.h, np.nan), normals=None))
    np.testing.assert_allclose(warm_polys, cold_polys, atol=1e-6)
    # Inscribed in the exact silhouette: close to a fine one (as the default resolution is, above).
    for v, cam in enumerate(CAMS):
        assert polygon_iou(warm_polys[0, v], silhouette(Superquadric.from_vector(moved), cam, 512)) > 0.98


def test_silhouette_tolerance_bounds_the_vertex_error():
    xi = random_xi(np.random.default_rng(1))
    exact, _, _ = solve(xi)
    loose, _, _ = solve(xi, tol=1e-3)
    assert np.abs(loose - exact).max() < 1e-2


def test_refreshed_records_then_readapts_drifted_directions():
    rng = np.random.default_rng(2)
    xi = random_xi(rng, shape=(1.0, 1.0))
    _, _, start = solve(xi)
    assert np.isnan(start.metric).all()
    recorded = start.refreshed()  # first call: records the shape, keeps the directions
    np.testing.assert_array_equal(recorded.directions, start.directions)
    assert np.isfinite(recorded.metric).all()
    # A small move keeps everything: the cost stays one function of xi.
    _, _, near = solve(xi + 1e-4, recorded)
    assert near.refreshed() is near
    # Stretching the superquadric 3x along one axis changes every silhouette's aspect ratio.
    stretched = xi.copy()
    stretched[0] *= 3.0
    polys, _, far = solve(stretched, recorded)
    fresh = far.refreshed()
    changed = np.any(fresh.directions != far.directions, axis=(2, 3))
    assert changed.all() and fresh.normals is None and np.isnan(fresh.metric).all()
    # New support values start below the exact ones (Newton needs a lower bound) and converge.
    _, _, exact = solve(stretched, fresh._replace(h=np.full_like(fresh.h, np.nan)))
    assert np.all(fresh.h <= exact.h + 1e-9)
    again, _, _ = solve(stretched, fresh)
    np.testing.assert_allclose(again, solve(stretched, exact)[0], atol=1e-6)
    # The re-adapted vertices are spread around the silhouette: a larger inscribed area.
    assert polygon_area(again[0, 0]) >= polygon_area(polys[0, 0]) - 1e-9


def test_convex_iou_vertex_weights_match_central_differences():
    rng = np.random.default_rng(3)
    xi = random_xi(rng)
    S, _, _ = solve(xi)
    Q, _, _ = solve(xi + rng.normal(size=11) * 0.05)  # an overlapping convex target
    iou, weights = convex_iou_jacobian(S[0], Q[0])
    W = weights()
    dS = rng.normal(size=S[0].shape)
    eps = 1e-6
    numeric = (convex_iou(S[0] + eps * dS, Q[0]) - convex_iou(S[0] - eps * dS, Q[0])) / (2 * eps)
    np.testing.assert_allclose(np.sum(W * dS, axis=(-2, -1)), numeric, rtol=1e-4, atol=1e-8)
    np.testing.assert_allclose(iou, convex_iou(S[0], Q[0]))
    # Disjoint polygons: IoU 0, no gradient.
    _, weights = convex_iou_jacobian(S[0], Q[0] + 1e4)
    assert not weights().any()


@pytest.mark.parametrize("shape", [None, (0.01, 1.0), (1.0, 1.99), (2.5, 0.5)])
def test_silhouette_gradient_is_weights_times_vertex_velocities(shape):
    rng = np.random.default_rng(4)
    xi = np.stack([random_xi(rng, shape), random_xi(rng, shape)])
    xi[1, 0] *= -1.0  # the sign of a is ignored by the silhouette, not by its derivative
    rotations, centers, intr = camera_arrays(CAMS)
    _, valid, _, unit_points, points = batch_silhouettes(xi, rotations, centers, intr, 48, touching=True)
    assert valid.all()
    W = rng.normal(size=points.shape[:3] + (2,))
    expected = np.einsum("bvkc,bvkcp->bvp", W, vertex_velocities(xi, unit_points, points, rotations, intr))
    got = silhouette_gradient(xi, W, unit_points, points, rotations, intr)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    if shape == (2.5, 0.5):  # e1 clamped by the silhouette: no derivative
        assert not got[..., 3].any()
