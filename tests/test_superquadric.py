import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sqfit import Superquadric
from sqfit import constants as C
from sqfit.geometry import superquadric as sqm

EDGE_SHAPES = [(0.1, 0.1), (0.1, 1.9), (1.9, 0.1), (1.9, 1.9), (1.0, 1.0), (0.5, 1.5)]
#: The sharpest edges the fitter makes (3G's bound) and accepts at all (the domain's end).
SHARP_SHAPES = [(C.SILHOUETTE_SHAPE_BOUNDS[0],) * 2, (C.SILHOUETTE_SHAPE_BOUNDS[0], 1.0), (C.SHAPE_DOMAIN[0],) * 2]

shape_st = st.floats(0.1, 1.9)
size_st = st.floats(0.1, 5.0)
angle_st = st.floats(-np.pi, np.pi)


def make(shape=(1.0, 1.0), size=(1.0, 2.0, 0.5), position=(0.3, -0.2, 1.0), rotation=(0.4, -0.3, 1.2)):
    return Superquadric(size, shape, position, rotation)


@st.composite
def superquadrics(draw):
    return Superquadric([draw(size_st) for _ in range(3)], [draw(shape_st), draw(shape_st)],
                        [draw(st.floats(-5, 5)) for _ in range(3)], [draw(angle_st) for _ in range(3)])


def test_vector_round_trip_and_order():
    sq = make()
    xi = sq.to_vector()
    assert xi.shape == (11,)
    np.testing.assert_array_equal(xi, [1.0, 2.0, 0.5, 1.0, 1.0, 0.3, -0.2, 1.0, 0.4, -0.3, 1.2])
    assert Superquadric.from_vector(xi) == sq


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(size=(1, -1, 1)), "size ay must be > 0"),
        (dict(size=(0, 1, 1)), "size ax must be > 0"),
        (dict(shape=(0.001, 1)), r"shape e1 must be in \[0.01, 2.0\]"),
        (dict(shape=(1, 2.5)), r"shape e2 must be in"),
        (dict(position=(0, np.nan, 0)), "position contains NaN"),
        (dict(rotation=(0, 0)), r"rotation must have shape \(3,\)"),
        (dict(size="abc"), "size must be numeric"),
    ],
)
def test_invalid_parameters_name_the_parameter(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make(**kwargs)


def test_from_vector_rejects_wrong_length():
    with pytest.raises(ValueError, match=r"xi must have shape \(11,\)"):
        Superquadric.from_vector(np.ones(10))


@settings(max_examples=60, deadline=None)
@given(superquadrics(), st.integers(0, 2**31))
def test_surface_samples_satisfy_implicit_and_radial(sq, seed):
    for sampler in (sqm.sample_surface_parametric, sqm.sample_surface_uniform):
        pts = sampler(sq, 200, np.random.default_rng(seed))
        np.testing.assert_allclose(sqm.implicit(sq, pts), 1.0, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(sqm.radial_distance(sq, pts), 0.0, atol=1e-9 * max(sq.size) + 1e-12)


@settings(max_examples=60, deadline=None)
@given(superquadrics(), st.floats(0.05, 0.95), st.floats(1.05, 3.0), st.integers(0, 2**31))
def test_radial_distance_sign_inside_outside(sq, shrink, grow, seed):
    surface = sqm.sample_surface_uniform(sq, 50, np.random.default_rng(seed))
    centre = np.asarray(sq.position)
    inner = centre + shrink * (surface - centre)
    outer = centre + grow * (surface - centre)
    assert np.all(sqm.radial_distance(sq, inner) > 0)
    assert np.all(sqm.radial_distance(sq, outer) < 0)
    assert np.all(sqm.contains(sq, inner)) and not np.any(sqm.contains(sq, outer))
    # The radial distance is exactly the distance along the ray from the centre.
    expected = (1 - shrink) * np.linalg.norm(surface - centre, axis=1)
    np.testing.assert_allclose(sqm.radial_distance(sq, inner), expected, rtol=1e-6)


def test_implicit_is_finite_at_extremes():
    sq = make(shape=(0.1, 0.1))
    pts = np.array([[0, 0, 0], [1e6, 1e6, 1e6], [1e-300, 0, 0], [0.3, 0.0, 0.0]])
    F = sqm.implicit(sq, pts + np.asarray(sq.position) @ np.eye(3))
    assert np.all(np.isfinite(F)) and np.all(F >= 0)
    g3 = sqm.radial_distance(sq, np.asarray([sq.position]))
    np.testing.assert_allclose(g3, [sq.size[0]])


@pytest.mark.parametrize("shape", EDGE_SHAPES + SHARP_SHAPES)
def test_mesh_is_watertight_and_matches_closed_form_volume(shape):
    sq = make(shape=shape)
    mesh = sqm.to_mesh(sq, resolution=40)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals
    assert abs(mesh.volume - sqm.volume(sq)) / sqm.volume(sq) < 0.01
    np.testing.assert_allclose(sqm.implicit(sq, mesh.vertices), 1.0, rtol=1e-6)


@pytest.mark.parametrize("shape, expected", [((1.0, 1.0), 4 / 3 * np.pi), ((1e-2, 1e-2), 8.0)])
def test_closed_form_volume_limits(shape, expected):
    # A unit sphere, and a unit-half-axis box in the limit e -> 0.
    vol = sqm.volume(Superquadric((1, 1, 1), shape))
    assert vol == pytest.approx(expected, rel=0.05 if shape[0] < 0.1 else 1e-12)


def test_mesh_rejects_tiny_resolution():
    with pytest.raises(ValueError, match="resolution must be an integer >= 2"):
        sqm.to_mesh(make(), resolution=1)


def _face_fractions(sq, points, weights=None):
    face = np.argmax(np.abs(sqm.to_local(sq, points) / np.asarray(sq.size)), axis=1)
    return np.bincount(face, weights=weights, minlength=3) / (len(points) if weights is None else weights.sum())


def test_uniform_sampler_is_area_uniform_on_a_thin_box():
    # Each face of a thin box-like SQ must get samples in proportion to its area (reference: a
    # very fine mesh); the explicit-form sampler crowds the edges and fails the same check.
    sq = Superquadric((2.0, 1.0, 0.1), (0.1, 0.1), (1.0, 2.0, 3.0), (0.3, 0.2, 0.1))
    fine = sqm.to_mesh(sq, resolution=200)
    expected = _face_fractions(sq, fine.triangles_center, fine.area_faces)
    rng = np.random.default_rng(0)
    uniform = _face_fractions(sq, sqm.sample_surface_uniform(sq, 40000, rng))
    np.testing.assert_allclose(uniform, expected, atol=0.005)
    parametric = _face_fractions(sq, sqm.sample_surface_parametric(sq, 40000, rng))
    assert np.abs(parametric - expected).max() > 0.05


def test_parametric_sampler_uses_the_explicit_form():
    sq = Superquadric((1.0, 2.0, 3.0), (0.5, 1.5))
    pts = sqm.sample_surface_parametric(sq, 100, np.random.default_rng(1))
    assert pts.shape == (100, 3)
    assert np.all(np.abs(pts) <= np.array([1.0, 2.0, 3.0]) + 1e-12)


def test_spow_signs_and_zero():
    np.testing.assert_allclose(sqm.spow([-8.0, 0.0, 8.0], 1 / 3), [-2.0, 0.0, 2.0])


@settings(max_examples=100, deadline=None)
@given(angle_st, st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3), angle_st)
def test_euler_convention_matches_scipy_and_round_trips(rx, ry, rz):
    r = np.array([rx, ry, rz])
    R = sqm.euler_to_matrix(r)
    np.testing.assert_allclose(R, Rotation.from_euler("xyz", r).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(sqm.euler_to_matrix(sqm.matrix_to_euler(R)), R, atol=1e-9)
    wrapped = np.angle(np.exp(1j * (sqm.matrix_to_euler(R) - r)))  # equal modulo 2 pi
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-6)


def test_euler_convention_is_extrinsic_xyz():
    # R = Rz @ Ry @ Rx: a pure rz turns the x axis towards y.
    np.testing.assert_allclose(sqm.euler_to_matrix([0, 0, np.pi / 2]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    r = np.array([0.3, 0.2, 0.1])
    Rx, Ry, Rz = (sqm.euler_to_matrix(v) for v in np.diag(r))
    np.testing.assert_allclose(sqm.euler_to_matrix(r), Rz @ Ry @ Rx, atol=1e-12)


def test_euler_to_matrix_single_and_batched_paths_agree():
    r = np.random.default_rng(4).uniform(-np.pi, np.pi, (5, 3))
    batch = sqm.euler_to_matrix(r)  # array path
    assert batch.shape == (5, 3, 3)
    for i in range(5):
        np.testing.assert_allclose(sqm.euler_to_matrix(r[i]), batch[i], atol=1e-15)  # scalar path
        one = sqm.euler_to_matrix(r[i:i + 1])  # batch of one: scalar path, batch shape
        assert one.shape == (1, 3, 3)
        np.testing.assert_allclose(one[0], batch[i], atol=1e-15)


def test_euler_derivatives_match_finite_differences():
    r = np.array([0.3, -1.1, 2.0])
    h = 1e-6
    numeric = np.stack([(sqm.euler_to_matrix(r + h * e) - sqm.euler_to_matrix(r - h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(sqm.euler_derivatives(r), numeric, atol=1e-8)


def test_matrix_to_euler_rejects_non_rotation():
    with pytest.raises(ValueError, match="proper rotation"):
        sqm.matrix_to_euler(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="proper rotation"):
        sqm.matrix_to_euler(np.stack([np.eye(3), 2.0 * np.eye(3)]))
    with pytest.raises(ValueError, match=r"R must have shape \(3, 3\) or \(n, 3, 3\)"):
        sqm.matrix_to_euler(np.eye(4))
    with pytest.raises(ValueError, match="R must be finite"):
        sqm.matrix_to_euler(np.full((3, 3), np.nan))


def test_matrix_to_euler_closed_form_equals_scipy_batched():
    rng = np.random.default_rng(7)
    R = Rotation.random(500, random_state=rng).as_matrix()
    r = sqm.matrix_to_euler(R)
    assert r.shape == (len(R), 3)
    np.testing.assert_allclose(r, Rotation.from_matrix(R).as_euler("xyz"), rtol=0, atol=1e-12)
    for i in (0, 1, len(R) - 1):  # single matrices: the same numbers as in the batch
        np.testing.assert_array_equal(sqm.matrix_to_euler(R[i]), r[i])
    # near (not at) gimbal lock, |ry| 1e-5 rad from pi/2, both round to ~eps / cos(ry) in angle
    near = Rotation.from_euler("xyz", [[0.4, np.pi / 2 - 1e-5, -1.0], [-2.0, -np.pi / 2 + 1e-5, 0.3]]).as_matrix()
    r = sqm.matrix_to_euler(near)
    np.testing.assert_allclose(r, Rotation.from_matrix(near).as_euler("xyz"), rtol=0, atol=1e-9)
    np.testing.assert_allclose(sqm.euler_to_matrix(r), near, rtol=0, atol=1e-12)


@pytest.mark.parametrize("ry", [np.pi / 2, -np.pi / 2])
def test_matrix_to_euler_gimbal_lock_puts_the_free_angle_in_rx(ry):
    R = sqm.euler_to_matrix([0.3, ry, 0.5])
    r = sqm.matrix_to_euler(R)
    assert r[2] == 0.0 and abs(r[1]) == np.pi / 2
    np.testing.assert_allclose(sqm.euler_to_matrix(r), R, atol=1e-12)
    with pytest.warns(UserWarning, match="Gimbal lock"):  # scipy makes the same choice
        np.testing.assert_allclose(r, Rotation.from_matrix(R).as_euler("xyz"), atol=1e-12)


def test_pose_maps_local_to_world():
    sq = make()
    local = np.array([[1.0, 0.0, 0.0]])
    world = (sq.pose @ np.append(local[0], 1.0))[:3]
    np.testing.assert_allclose(sqm.to_local(sq, world[None]), local, atol=1e-12)


@pytest.mark.parametrize("resolution, count", [(32, 26), (7, 8), (2, 26)])
def test_mesh_anchors_are_vertices_of_the_mesh(resolution, count):
    from sqfit.geometry.superquadric import mesh_anchors, to_mesh

    sq = Superquadric([0.4, 1.2, 2.0], [0.15, 1.7], [1.0, -2.0, 0.5], [0.3, -1.1, 2.5])
    anchors = mesh_anchors(sq, resolution)
    vertices = np.asarray(to_mesh(sq, resolution).vertices)
    assert anchors.shape == (count, 3)
    gaps = np.linalg.norm(anchors[:, None] - vertices[None], axis=2).min(axis=1)
    assert gaps.max() < 1e-12
    # the axis tips are among them for an even resolution
    if resolution % 2 == 0:
        tips = sq.position + (sq.rotation_matrix * np.asarray(sq.size)).T
        assert np.linalg.norm(anchors[:, None] - tips[None], axis=2).min(axis=0).max() < 1e-9
    with pytest.raises(ValueError, match="resolution must be an integer >= 2"):
        mesh_anchors(sq, 1)
