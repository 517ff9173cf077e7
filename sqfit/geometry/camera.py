"""Pinhole cameras: intrinsics, poses, projection and back-projection.

Conventions (stated once, pinned by ``tests/test_camera.py``):

- Camera frame is OpenCV's: x right, y down, z forward (along the optical axis).
- A pose is ``T_world_camera``, a ``(4, 4)`` transform taking camera coordinates to world
  coordinates (camera -> world).
- Projection: ``u = fx * x / z + cx``, ``v = fy * y / z + cy``, with depth ``z`` (not the ray
  length), as the paper's back-projection (eq. 10).
- Images are indexed ``mask[v, u]``; pixel ``(row i, column j)`` covers
  ``[j, j + 1) x [i, i + 1)`` in image coordinates, so its centre is at ``(j + 0.5, i + 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._checks import check_positive, check_shape

__all__ = ["Intrinsics", "Camera", "rigid_pose_fault", "look_at", "project", "back_project", "bearings", "world_bearings",
           "pixel_centers"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics, all in pixels.

    Attributes
    ----------
    width, height : int
        Image size.
    fx, fy : float
        Focal lengths.
    cx, cy : float
        Principal point in image coordinates (module convention).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        for name in ("width", "height"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be a positive integer (pixels), got {value}")
            object.__setattr__(self, name, int(value))
        for name in ("fx", "fy"):
            object.__setattr__(self, name, check_positive(getattr(self, name), name))
        for name in ("cx", "cy"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
            object.__setattr__(self, name, value)

    @property
    def K(self):
        """``(3, 3) float`` calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_dict(self):
        return {k: getattr(self, k) for k in ("width", "height", "fx", "fy", "cx", "cy")}


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_LAST_ROW_TOL = 1e-8 + 1e-5 * _LAST_ROW  # np.allclose's default rtol, atol
_EYE3 = np.eye(3)
_ORTHONORMAL_TOL = 1e-6 + 1e-5 * _EYE3  # np.allclose(R R^T, I, atol=1e-6)


def _det3(R):
    """Determinant of a ``(3, 3)`` matrix (its sign is what :func:`rigid_pose_fault` checks)."""
    r = R.tolist()
    return (r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]))


def rigid_pose_fault(T):
    """Why a ``(4, 4)`` float pose ``T`` is not a rigid transform with a proper rotation, as the end of
    a sentence about it (``"must have last row [0, 0, 0, 1]"`` or ``"rotation block must be a proper
    rotation (orthonormal, det = +1)"``), or ``""`` when it is. The tolerances are ``np.allclose``'s
    (rtol 1e-5; atol 1e-8 for the last row, 1e-6 for ``R R^T = I``), written out: ``np.allclose`` and
    ``np.linalg.det`` cost ~0.15 ms a pose, and the factor graph builds thousands of moved cameras.
    A NaN fails, as in ``np.allclose``."""
    if not (np.abs(T[3] - _LAST_ROW) <= _LAST_ROW_TOL).all():
        return "must have last row [0, 0, 0, 1]"
    R = T[:3, :3]
    if not (np.abs(R @ R.T - _EYE3) <= _ORTHONORMAL_TOL).all() or _det3(R) < 0:
        return "rotation block must be a proper rotation (orthonormal, det = +1)"
    return ""


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera at a pose.

    Attributes
    ----------
    intrinsics : Intrinsics
    pose : (4, 4) float
        ``T_world_camera`` (camera -> world), read-only; the rotation block must be a proper
        rotation.
    """

    intrinsics: Intrinsics
    pose: np.ndarray

    def __post_init__(self):
        if not isinstance(self.intrinsics, Intrinsics):
            raise ValueError(f"intrinsics must be an Intrinsics, got {type(self.intrinsics).__name__}")
        pose = check_shape(self.pose, (4, 4), "pose").copy()
        fault = rigid_pose_fault(pose)
        if fault:
            raise ValueError(f"pose {fault}")
        pose.flags.writeable = False
        object.__setattr__(self, "pose", pose)

    @property
    def rotation(self):
        """``(3, 3) float``: camera -> world rotation."""
        return self.pose[:3, :3]

    @property
    def center(self):
        """``(3,) float``: camera centre in world coordinates."""
        return self.pose[:3, 3]

    def to_dict(self):
        return {"intrinsics": self.intrinsics.to_dict(), "T_world_camera": self.pose.tolist()}

    @classmethod
    def from_dict(cls, d):
        try:
            return cls(Intrinsics(**d["intrinsics"]), np.asarray(d["T_world_camera"], dtype=float))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"camera record needs 'intrinsics' and 'T_world_camera': {exc}") from None


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """Pose of a camera at ``eye`` looking at ``target`` with image-up along ``up``.

    Parameters
    ----------
    eye, target : (3,) float
        World points, metres.
    up : (3,) float
        World direction that appears upwards in the image (default +z).

    Returns
    -------
    T_world_camera : (4, 4) float
    """
    eye = check_shape(eye, (3,), "eye")
    target = check_shape(target, (3,), "target")
    up = check_shape(up, (3,), "up")
    z = target - eye
    if np.linalg.norm(z) == 0:
        raise ValueError("eye and target must differ")
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("viewing direction is parallel to up; choose another up vector")
    x = x / np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def project(camera, points):
    """Project world points into the image.

    Parameters
    ----------
    camera : Camera
    points : (n, 3) float
        World coordinates, metres.

    Returns
    -------
    pixels : (n, 2) float
        Image coordinates ``(u, v)`` (module convention); meaningless where ``depth <= 0``.
    depth : (n,) float
        Camera-frame ``z``, metres; <= 0 for points behind the camera.
    """
    points = check_shape(points, (None, 3), "points")
    local = (points - camera.center) @ camera.rotation
    depth = local[:, 2]
    safe = np.where(np.abs(depth) > 1e-12, depth, 1e-12)
    k = camera.intrinsics
    pixels = np.stack([k.fx * local[:, 0] / safe + k.cx, k.fy * local[:, 1] / safe + k.cy], axis=1)
    return pixels, depth


def back_project(camera, pixels, depth):
    """World points at the given depths along the rays through image points (eq. 10).

    Parameters
    ----------
    camera : Camera
    pixels : (n, 2) float
        Image coordinates ``(u, v)``.
    depth : (n,) float or float
        Camera-frame ``z``, metres.

    Returns
    -------
    points : (n, 3) float
        World coordinates.
    """
    pixels = check_shape(pixels, (None, 2), "pixels")
    depth = np.broadcast_to(np.asarray(depth, dtype=np.float64), (len(pixels),))
    return camera.center + (bearings(camera, pixels) * depth[:, None]) @ camera.rotation.T


def bearings(camera, pixels):
    """Camera-frame ray directions with unit depth: ``[(u - cx) / fx, (v - cy) / fy, 1]``.

    Parameters
    ----------
    camera : Camera
    pixels : (n, 2) float

    Returns
    -------
    rays : (n, 3) float
    """
    k = camera.intrinsics
    pixels = np.asarray(pixels, dtype=np.float64)
    out = np.empty((len(pixels), 3))
    out[:, 0], out[:, 1], out[:, 2] = (pixels[:, 0] - k.cx) / k.fx, (pixels[:, 1] - k.cy) / k.fy, 1.0
    return out


def world_bearings(camera, pixels):
    """World-frame directions ``(n, 3)`` of the rays through image points ``pixels`` ``(n, 2)`` of
    ``camera``: :func:`bearings` rotated into the world (unit camera-frame depth, not unit length)."""
    return bearings(camera, pixels) @ camera.rotation.T


def pixel_centers(rows, cols):
    """Image coordinates of pixel centres (module convention).

    Parameters
    ----------
    rows, cols : (n,) int
        Pixel indices ``mask[rows, cols]``.

    Returns
    -------
    pixels : (n, 2) float
        ``(cols + 0.5, rows + 0.5)``.
    """
    return np.stack([np.asarray(cols) + 0.5, np.asarray(rows) + 0.5], axis=1).astype(np.float64)
