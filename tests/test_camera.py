import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sqfit import Camera, Intrinsics, back_project, look_at, project
from sqfit.geometry.camera import pixel_centers, world_bearings

INTR = Intrinsics(640, 480, 400.0, 300.0, 320.0, 240.0)


def camera_at(eye=(10.0, 0.0, 0.0), target=(0.0, 0.0, 0.0)):
    return Camera(INTR, look_at(eye, target))


def test_look_at_is_opencv_frame():
    cam = camera_at((10.0, 0.0, 0.0))
    R = cam.rotation
    np.testing.assert_allclose(R[:, 2], [-1, 0, 0], atol=1e-12)  # z forward, towards the target
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # y down = world -z
    np.testing.assert_allclose(R[:, 0], [0, 1, 0], atol=1e-12)  # x right = forward x up
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_project_target_hits_principal_point_and_up_is_up():
    cam = camera_at()
    uv, depth = project(cam, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [320.0, 240.0])
    assert depth[0] == pytest.approx(10.0)
    assert uv[1, 1] < 240.0  # a point above the target appears higher in the image (smaller v)
    assert uv[1, 1] == pytest.approx(240.0 - 300.0 * 1.0 / 10.0)


@settings(max_examples=100, deadline=None)
@given(st.floats(0, 2 * np.pi), st.floats(-3, 3), st.floats(0.5, 50),
       st.floats(-100, 740), st.floats(-100, 580))
def test_project_back_project_round_trip(angle, height, depth, u, v):
    cam = camera_at((10 * np.cos(angle), 10 * np.sin(angle), height))
    pts = back_project(cam, np.array([[u, v]]), np.array([depth]))
    uv, d = project(cam, pts)
    np.testing.assert_allclose(uv, [[u, v]], atol=1e-6)
    np.testing.assert_allclose(d, [depth], rtol=1e-9)


def test_world_bearings_reach_back_projected_points_at_their_depth():
    cam = camera_at((6.0, -8.0, 3.0), (0.5, 0.2, -0.4))
    pixels, depth = np.array([[10.0, 20.0], [320.0, 240.0], [600.0, 470.0]]), np.array([1.0, 7.5, 30.0])
    rays = world_bearings(cam, pixels)
    np.testing.assert_allclose(cam.center + rays * depth[:, None], back_project(cam, pixels, depth), atol=1e-9)
    np.testing.assert_allclose(rays @ cam.rotation[:, 2], 1.0)  # unit depth along the optical axis


def test_pixel_centre_convention():
    # Pixel (row 0, col 0) is centred at (0.5, 0.5): it spans [0, 1) x [0, 1).
    np.testing.assert_allclose(pixel_centers([0, 479], [0, 639]), [[0.5, 0.5], [639.5, 479.5]])


def test_points_behind_camera_have_negative_depth():
    _, depth = project(camera_at(), np.array([[20.0, 0.0, 0.0]]))
    assert depth[0] < 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(width=0), "width must be a positive integer"),
        (dict(fx=-1.0), "fx must be a finite number > 0"),
        (dict(cy=np.nan), "cy must be finite"),
    ],
)
def test_invalid_intrinsics(kwargs, match):
    base = dict(width=640, height=480, fx=400.0, fy=300.0, cx=320.0, cy=240.0)
    with pytest.raises(ValueError, match=match):
        Intrinsics(**{**base, **kwargs})


def test_rigid_pose_fault_is_np_allclose_and_det_written_out():
    # the same verdicts as the np.allclose / np.linalg.det checks it replaces, at and around their
    # tolerances (rtol 1e-5; atol 1e-8 for the last row, 1e-6 for R R^T)
    from sqfit.geometry.camera import rigid_pose_fault

    def reference(T):
        R = T[:3, :3]
        if not np.allclose(T[3], [0, 0, 0, 1]):
            return "must have last row [0, 0, 0, 1]"
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            return "rotation block must be a proper rotation (orthonormal, det = +1)"
        return ""

    rng = np.random.default_rng(0)
    poses = [look_at(rng.normal(size=3) * 5, rng.normal(size=3)) for _ in range(20)]
    for T in list(poses):
        for eps in (1e-9, 5e-9, 9.9e-9, 1.1e-8, 1e-7, 4e-7, 6e-7, 1e-6, 1e-5):
            row, rot = T.copy(), T.copy()
            row[3, rng.integers(4)] += eps * rng.choice([-1, 1])
            rot[:3, :3] *= 1.0 + eps
            poses += [row, rot]
    reflected = np.diag([1.0, 1.0, -1.0, 1.0])
    nan = np.eye(4)
    nan[3, 3] = np.nan
    poses += [reflected, nan, np.eye(4)]
    verdicts = [rigid_pose_fault(T) for T in poses]
    assert verdicts == [reference(T) for T in poses]
    assert "" in verdicts and "must have last row [0, 0, 0, 1]" in verdicts
    assert rigid_pose_fault(reflected).startswith("rotation block must be a proper rotation")


def test_invalid_poses():
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="pose contains NaN"):
        Camera(INTR, bad)
    with pytest.raises(ValueError, match="proper rotation"):
        Camera(INTR, np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match=r"pose must have shape \(4, 4\)"):
        Camera(INTR, np.eye(3))
    with pytest.raises(ValueError, match="parallel to up"):
        look_at([0, 0, 10], [0, 0, 0])


def test_camera_dict_round_trip():
    cam = camera_at((3.0, 4.0, 1.0))
    again = Camera.from_dict(cam.to_dict())
    np.testing.assert_array_equal(again.pose, cam.pose)
    assert again.intrinsics == cam.intrinsics
    with pytest.raises(ValueError, match="needs 'intrinsics'"):
        Camera.from_dict({"T_world_camera": np.eye(4).tolist()})
