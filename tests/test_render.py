import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import sqfit
from sqfit.geometry.superquadric import to_mesh
from sqsim.imaging.render import get_renderer, polygon_mask, projection_matrix

INTR = sqfit.Intrinsics(160, 120, 100.0, 75.0, 80.0, 60.0)


def circle_cameras(n=3, radius=10.0, intr=INTR):
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.3
    return [sqfit.Camera(intr, sqfit.look_at(radius * np.array([np.cos(a), np.sin(a), 0.4]), [0, 0, 0]))
            for a in angles]


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


@pytest.mark.parametrize("params", [
    [1.0, 2.0, 0.5, 0.5, 1.2, 0.5, 0.2, 0.1, 0.3, 0.2, 0.1],
    [2.0, 1.0, 1.5, 1.8, 0.2, -1.0, 1.0, 0.5, -0.7, 1.1, 2.5],
    [0.6, 0.6, 0.6, 1.0, 1.0, 2.0, -2.0, 1.0, 0.0, 0.0, 0.0],
])
def test_osmesa_agrees_with_polygon_projection(params):
    # Pins the OpenCV -> OpenGL conversion: the GL mask and the analytic hull of the projected
    # superquadric must agree, per view, and differ from a flipped image.
    sq = sqfit.Superquadric.from_vector(params)
    cams = circle_cameras()
    gl = get_renderer("osmesa", INTR).render([to_mesh(sq, 32)], cams)
    poly = get_renderer("polygon", INTR).render([to_mesh(sq, 64)], cams)
    for a, b in zip(gl > 0, poly > 0):
        assert a.sum() > 50
        assert iou(a, b) > 0.98
        assert iou(a, b[::-1]) < 0.98 or iou(a, b[:, ::-1]) < 0.98


def test_pixel_centre_convention_on_a_square():
    # A box whose front face projects to u in [40.2, 80.7] and v in [30.4, 50.9]: the pixels whose
    # centres (j + 0.5, i + 0.5) lie inside are columns 40..80 and rows 30..50.
    cam = sqfit.Camera(INTR, np.eye(4))
    z = 10.0
    u0, u1, v0, v1 = 40.2, 80.7, 30.4, 50.9
    x = (np.array([u0, u1]) - INTR.cx) / INTR.fx * z
    y = (np.array([v0, v1]) - INTR.cy) / INTR.fy * z
    box = trimesh.creation.box(bounds=[[x[0], y[0], z], [x[1], y[1], z + 1e-3]])  # thin: sides stay inside
    expected = np.zeros((120, 160), bool)
    expected[30:51, 40:81] = True
    for backend in ("osmesa", "polygon"):
        image = get_renderer(backend, INTR).render([box], [cam])[0]
        np.testing.assert_array_equal(image > 0, expected, err_msg=backend)


def test_touching_objects_have_exact_ids():
    # Two boxes that touch along a plane seen edge-on, and one in front of the other: every pixel
    # holds 0, 1 or 2 (no mixed value) and the nearer object wins where they overlap.
    cam = sqfit.Camera(INTR, sqfit.look_at([10.0, 0, 0], [0, 0, 0]))
    left = trimesh.creation.box(bounds=[[-1, -2, -1], [1, 0, 1]])
    right = trimesh.creation.box(bounds=[[-1, 0, -1], [1, 2, 1]])
    front = trimesh.creation.box(bounds=[[2, -0.5, -0.5], [3, 0.5, 0.5]])
    image = get_renderer("osmesa", INTR).render([left, right, front], [cam])[0]
    assert set(np.unique(image)) == {0, 1, 2, 3}
    # The boxes touch at world y = 0, which projects to u = cx = 80: pixel columns <= 79 (centres
    # < 80) show box 1, columns >= 80 box 2, with no gap and no other value in between.
    row = image[53]
    cols = np.nonzero(row)[0]
    assert set(row[cols.min():80]) == {1} and set(row[80:cols.max() + 1]) == {2}
    assert np.all(image[58:63, 78:82] == 3)
    # Swapping draw order does not change the result (depth test, not painter's order).
    again = get_renderer("osmesa", INTR).render([
        type("O", (), {"id": 3, "mesh": front})(), type("O", (), {"id": 2, "mesh": right})(),
        type("O", (), {"id": 1, "mesh": left})()], [cam])[0]
    np.testing.assert_array_equal(image, again)


def test_objects_with_attributes_and_empty_views():
    sq = sqfit.Superquadric((0.5, 0.5, 0.5), position=(0, 0, 0))
    obj = type("Obj", (), {"id": 7, "mesh": to_mesh(sq, 8)})()
    behind = sqfit.Camera(INTR, sqfit.look_at([10.0, 0, 0], [20.0, 0, 0]))
    images = get_renderer("osmesa", INTR).render([obj], circle_cameras(2) + [behind])
    assert images.dtype == np.uint16 and images.shape == (3, 120, 160)
    assert set(np.unique(images[0])) == {0, 7} and not images[2].any()


def test_renderer_is_cached_per_process():
    assert get_renderer("osmesa", INTR) is get_renderer("osmesa", INTR)


@pytest.mark.parametrize("call, match", [
    (lambda: get_renderer("vulkan", INTR), "renderer backend must be one of"),
    (lambda: get_renderer("osmesa", (640, 480)), "intrinsics must be a sqfit.Intrinsics"),
    (lambda: (get_renderer("osmesa", INTR), get_renderer("egl", INTR)), "PYOPENGL_PLATFORM"),
    (lambda: get_renderer("polygon", INTR).render([np.zeros(3)], circle_cameras(1)), "must be a trimesh"),
    (lambda: get_renderer("polygon", INTR).render([trimesh.creation.box()], [np.eye(4)]), "sqfit.Camera"),
    (lambda: get_renderer("polygon", INTR).render(
        [trimesh.creation.box()], circle_cameras(1, intr=sqfit.Intrinsics(10, 10, 5, 5, 5, 5))), "intrinsics"),
    (lambda: get_renderer("polygon", INTR).render(
        [type("O", (), {"id": 0, "mesh": trimesh.creation.box()})()], circle_cameras(1)), r"id must be an integer"),
    (lambda: get_renderer("polygon", INTR).render(
        [type("O", (), {"id": 1, "mesh": trimesh.creation.box()})()] * 2, circle_cameras(1)), "unique"),
    (lambda: get_renderer("polygon", INTR).render([trimesh.creation.box()], [sqfit.Camera(INTR, np.eye(4))]),
     "behind the camera"),
    (lambda: projection_matrix(INTR, 1.0, 0.5), "znear < zfar"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_nan_vertices_are_rejected():
    box = trimesh.creation.box()
    box.vertices[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        get_renderer("osmesa", INTR).render([box], circle_cameras(1))


def test_polygon_mask_uses_pixel_centres():
    mask = polygon_mask(np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 2.0], [1.0, 2.0]]), (4, 5))
    expected = np.zeros((4, 5), bool)
    expected[1, 1:3] = True  # centres (1.5, 1.5), (2.5, 1.5)
    np.testing.assert_array_equal(mask, expected)


def test_egl_backend_in_its_own_process():
    # One OpenGL platform per process: EGL runs in a fresh interpreter (Mesa llvmpipe on a CPU).
    code = """
import os, numpy as np, sqfit
from sqfit.geometry.superquadric import to_mesh
from sqsim.imaging.render import get_renderer
intr = sqfit.Intrinsics(160, 120, 100.0, 75.0, 80.0, 60.0)
sq = sqfit.Superquadric((1.0, 2.0, 0.5), (0.5, 1.2), (0.5, 0.2, 0.1), (0.3, 0.2, 0.1))
cam = sqfit.Camera(intr, sqfit.look_at([10.0, 1.0, 2.0], [0, 0, 0]))
a = get_renderer("egl", intr).render([to_mesh(sq, 32)], [cam])[0] > 0
b = get_renderer("polygon", intr).render([to_mesh(sq, 64)], [cam])[0] > 0
assert os.environ["PYOPENGL_PLATFORM"] == "egl"
print((a & b).sum() / (a | b).sum())
"""
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    if out.returncode != 0 and "cannot create an off-screen OpenGL context" in out.stderr:
        pytest.skip("EGL is not available on this machine")
    assert out.returncode == 0, out.stderr
    assert float(out.stdout.split()[-1]) > 0.98


def test_culling_keeps_the_nearest_surface():
    # A is nearer at its front face (depth 7) but its back face (depth 11) lies behind B's
    # (depth 10): with the wrong faces culled B would win. Outward meshes allow culling.
    cam = sqfit.Camera(INTR, sqfit.look_at([10.0, 0, 0], [0, 0, 0]))
    a = trimesh.creation.box(bounds=[[-1, -2, -1], [3, 2, 1]])
    b = trimesh.creation.box(bounds=[[0, -0.5, -0.5], [2, 0.5, 0.5]])
    make = lambda oid, mesh, outward: type("O", (), {"id": oid, "mesh": mesh, "outward": outward})()  # noqa: E731
    culled = get_renderer("osmesa", INTR).render([make(1, a, True), make(2, b, True)], [cam])[0]
    plain = get_renderer("osmesa", INTR).render([make(1, a, False), make(2, b, False)], [cam])[0]
    assert set(np.unique(culled)) == {0, 1}
    np.testing.assert_array_equal(culled, plain)
