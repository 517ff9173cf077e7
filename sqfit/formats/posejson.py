"""Plain JSON pose files: one record per image with its intrinsics and pose.

::

    {"images": [{"file_name": "frames/0001.png",
                 "intrinsics": {"width": 640, "height": 480, "fx": 400.0, "fy": 300.0,
                                "cx": 320.0, "cy": 240.0},
                 "T_world_camera": [[...4 floats...] x 4]},
                ...]}

A record gives exactly one of ``T_world_camera`` (camera -> world, the fitter's convention,
used as is) or ``T_camera_world`` (world -> camera, as COLMAP and OpenCV's ``solvePnP`` give
it; inverted here, once). Camera frame, pixel grid and intrinsics are those of
:mod:`sqfit.geometry.camera` (OpenCV frame, top-left pixel centred at ``(0.5, 0.5)``); no distortion.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._checks import check_shape
from ..geometry.camera import Camera, Intrinsics
from ._rigid import invert
from .jsonfile import read_json

__all__ = ["POSE_KEYS", "read_pose_json", "write_pose_json"]

#: Accepted pose keys, with whether the matrix must be inverted to get ``T_world_camera``.
POSE_KEYS = {"T_world_camera": False, "T_camera_world": True}


def read_pose_json(path):
    """Cameras of a JSON pose file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    cameras : dict
        ``file name -> sqfit.Camera``, in file order.

    Raises
    ------
    OSError
        The file does not exist.
    ValueError
        Not JSON, no ``images`` list, or a record with a missing / duplicate file name, bad
        intrinsics, no pose key or both, or a pose that is not a rigid ``(4, 4)`` transform (the
        message names the file and the record).
    """
    path = Path(path)
    data = read_json(path, "pose file")
    records = data.get("images") if isinstance(data, dict) else None
    if not isinstance(records, list):
        raise ValueError(f"{path}: a pose file needs a list 'images' of {{file_name, intrinsics, T_world_camera}}")
    cameras = {}
    for k, rec in enumerate(records):
        where = f"{path}: images[{k}]"
        if not isinstance(rec, dict) or not isinstance(rec.get("file_name"), str):
            raise ValueError(f"{where} needs a string 'file_name'")
        where += f" ({rec['file_name']})"
        if rec["file_name"] in cameras:
            raise ValueError(f"{where}: duplicate file_name")
        cameras[rec["file_name"]] = _camera(rec, where)
    return cameras


def _camera(rec, where):
    keys = [k for k in POSE_KEYS if k in rec]
    if len(keys) != 1:
        raise ValueError(f"{where} needs exactly one of {' or '.join(POSE_KEYS)}, got {keys or 'neither'}")
    try:
        intrinsics = Intrinsics(**rec["intrinsics"])
        T = check_shape(rec[keys[0]], (4, 4), keys[0])
        if POSE_KEYS[keys[0]]:
            if not np.allclose(T[3], [0, 0, 0, 1]):
                raise ValueError(f"{keys[0]} must have last row [0, 0, 0, 1]")
            T = invert(T)
        return Camera(intrinsics, T)
    except KeyError:
        raise ValueError(f"{where} needs 'intrinsics' (width, height, fx, fy, cx, cy)") from None
    except TypeError as exc:
        raise ValueError(f"{where}: intrinsics must be {{width, height, fx, fy, cx, cy}}: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def write_pose_json(path, cameras):
    """Write ``file name -> sqfit.Camera`` as a JSON pose file (``T_world_camera``)."""
    records = [{"file_name": str(name), "intrinsics": cam.intrinsics.to_dict(), "T_world_camera": cam.pose.tolist()}
               for name, cam in cameras.items()]
    Path(path).write_text(json.dumps({"images": records}, indent=1) + "\n", encoding="utf-8")
