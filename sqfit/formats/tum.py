"""TUM RGB-D trajectory files: one pose per line, ``t tx ty tz qx qy qz qw``.

Conventions (pinned by ``tests/test_tum.py``):

- ``t`` is a timestamp in seconds; ``tx ty tz`` the camera centre in the world frame (metres);
  ``qx qy qz qw`` the unit quaternion (scalar last) of the camera -> world rotation. A line is
  thus the pose ``T_world_camera`` of the ``sqfit.geometry.camera`` convention, as evo and the TUM
  benchmark tools read it.
- Lines starting with ``#`` and blank lines are ignored; fields are separated by spaces (tabs and
  commas are accepted on reading, as the TUM tools do).
- Written numbers use Python's shortest round-trip ``repr``, so a file read back gives the same
  timestamps and positions bit for bit and rotations to ~1e-16, and the same poses always give
  the same bytes. Quaternions are written with ``qw >= 0``.

Why not evo's ``file_interface``: evo is an optional extra (``slam``), but these functions are used
by the dataset writer (``sqsim generate``) and the dataset reader (``sqfit.views.dataset``), which must work
with the core install; evo's reader reports a malformed file without naming the line, and its
writer (``numpy.savetxt``, ``%.18e``) is no more precise than ``repr``. The files are checked to
read back identically through evo in both directions (``tests/test_tum.py``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .._checks import check_shape

__all__ = ["read_tum", "write_tum", "poses_to_rows", "rows_to_poses", "QUATERNION_NORM_TOLERANCE"]

#: How far a quaternion's norm may be from 1 and still be read as a rotation (it is normalised);
#: files written with 6 decimals (the TUM tools) are within 1e-5.
QUATERNION_NORM_TOLERANCE = 1e-3


def rows_to_poses(rows, name="rows"):
    """Poses from TUM rows.

    Parameters
    ----------
    rows : (n, 8) float
        ``t tx ty tz qx qy qz qw`` per row.
    name : str
        Used in error messages (``name[k]`` names a bad row).

    Returns
    -------
    timestamps : (n,) float
    poses : (n, 4, 4) float
        ``T_world_camera``.

    Raises
    ------
    ValueError
        Wrong shape, NaN/inf, or a quaternion whose norm is not 1 within
        :data:`QUATERNION_NORM_TOLERANCE` (not a rotation).
    """
    from scipy.spatial.transform import Rotation

    rows = check_shape(rows, (None, 8), name)
    quats = rows[:, 4:8]
    norms = np.linalg.norm(quats, axis=1)
    problem = _quaternion_problem(quats)
    if problem is not None:
        raise ValueError(f"{name}[{problem[0]}]: {problem[1]}")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    if len(rows):
        poses[:, :3, :3] = Rotation.from_quat(quats / norms[:, None]).as_matrix()
    poses[:, :3, 3] = rows[:, 1:4]
    return rows[:, 0].copy(), poses


def _quaternion_problem(quats):
    """``(row, message)`` of the first quaternion that is not a rotation, or None."""
    norms = np.linalg.norm(quats, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if not bad.size:
        return None
    k = int(bad[0])
    return k, (f"quaternion (qx, qy, qz, qw) = {quats[k].tolist()} has norm {norms[k]:.6g}, "
               f"not a rotation (must be 1 within {QUATERNION_NORM_TOLERANCE})")


def poses_to_rows(timestamps, poses):
    """TUM rows of poses.

    Parameters
    ----------
    timestamps : (n,) float
        Seconds.
    poses : (n, 4, 4) float
        ``T_world_camera``; the rotation blocks must be proper rotations.

    Returns
    -------
    rows : (n, 8) float
        ``t tx ty tz qx qy qz qw`` with ``qw >= 0``.
    """
    from scipy.spatial.transform import Rotation

    timestamps = check_shape(timestamps, (None,), "timestamps")
    poses = check_shape(poses, (len(timestamps), 4, 4), "poses")
    R = poses[:, :3, :3]
    err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2)) if len(R) else np.zeros(0)
    bad = np.flatnonzero((err > 1e-6) | (np.linalg.det(R) <= 0)) if len(R) else []
    if len(bad):
        raise ValueError(f"poses[{int(bad[0])}] rotation block is not a proper rotation")
    quats = Rotation.from_matrix(R).as_quat() if len(R) else np.zeros((0, 4))
    quats[quats[:, 3] < 0] *= -1.0
    return np.column_stack([timestamps, poses[:, :3, 3], quats])


def write_tum(path, timestamps, poses):
    """Write a trajectory as a TUM file (see the module docstring for the format).

    Parameters
    ----------
    path : str or os.PathLike
    timestamps : (n,) float
        Seconds, strictly increasing.
    poses : (n, 4, 4) float
        ``T_world_camera`` (camera -> world).
    """
    rows = poses_to_rows(timestamps, poses)
    if np.any(np.diff(rows[:, 0]) <= 0):
        raise ValueError("timestamps must be strictly increasing")
    text = "".join(" ".join(repr(float(x)) for x in row) + "\n" for row in rows)
    Path(os.fspath(path)).write_text("# timestamp tx ty tz qx qy qz qw (T_world_camera)\n" + text,
                                     encoding="utf-8")


def data_lines(text):
    """``(line number, line, fields)`` of each line that is not blank or a ``#`` comment.

    Lines are stripped; fields are split at spaces, tabs and commas, as the TUM tools do.
    """
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield number, line, line.replace(",", " ").split()


def read_tum(path):
    """Read a TUM trajectory file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    timestamps : (n,) float
        Seconds, as written (strictly increasing).
    poses : (n, 4, 4) float
        ``T_world_camera`` (camera -> world).

    Raises
    ------
    OSError
        The file does not exist.
    ValueError
        A line without 8 numbers, a non-unit quaternion, timestamps not strictly increasing, or
        no pose at all; the message names the file and the line.
    """
    path = Path(os.fspath(path))
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise OSError(f"TUM trajectory file not found: {path}") from None
    rows, lines = [], []
    for number, line, fields in data_lines(text):
        try:
            values = [float(x) for x in fields]
        except ValueError:
            values = []
        if len(values) != 8 or not all(math.isfinite(v) for v in values):
            raise ValueError(f"{path}:{number}: expected 8 finite numbers 't tx ty tz qx qy qz qw', "
                             f"got {line!r}")
        rows.append(values)
        lines.append(number)
    if not rows:
        raise ValueError(f"{path}: no poses (a TUM file has lines 't tx ty tz qx qy qz qw')")
    rows = np.array(rows)
    problem = _quaternion_problem(rows[:, 4:8])
    if problem is not None:
        raise ValueError(f"{path}:{lines[problem[0]]}: {problem[1]}")
    timestamps, poses = rows_to_poses(rows, name=str(path))
    back = np.flatnonzero(np.diff(timestamps) <= 0)
    if back.size:
        raise ValueError(f"{path}:{lines[int(back[0]) + 1]}: timestamps must be strictly increasing")
    return timestamps, poses
