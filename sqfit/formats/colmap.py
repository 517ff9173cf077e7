"""COLMAP models (``sparse/0``, binary or text) through pycolmap: cameras in, cameras out.

Conventions, converted here and nowhere else (pinned by ``tests/test_formats.py``):

- COLMAP stores each image's pose as ``cam_from_world`` (world -> camera); sqfit uses
  ``T_world_camera`` (camera -> world), its inverse. Both use the OpenCV camera frame
  (x right, y down, z forward), so only the inversion is needed.
- COLMAP's image coordinates put the centre of the top-left pixel at ``(0.5, 0.5)``, as
  :mod:`sqfit.geometry.camera` does, so ``cx, cy`` carry over unchanged.
- Only distortion-free pinhole models are accepted: ``PINHOLE`` (fx, fy, cx, cy) and
  ``SIMPLE_PINHOLE`` (f, cx, cy). Undistort other models first (``colmap image_undistorter``
  writes a PINHOLE model) - the fitter's projection has no distortion term.

pycolmap is imported inside the functions: ``import sqfit`` never loads it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.camera import Camera, Intrinsics
from ._rigid import invert

__all__ = ["PINHOLE_MODELS", "read_colmap", "write_colmap"]

#: COLMAP camera model -> names of its parameters, for the models the fitter can use.
PINHOLE_MODELS = {"PINHOLE": ("fx", "fy", "cx", "cy"), "SIMPLE_PINHOLE": ("f", "cx", "cy")}


def _pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise OSError("reading or writing COLMAP models needs pycolmap: pip install 'sqkit[formats]'") from None
    return pycolmap


def read_colmap(path):
    """Cameras of every registered image of a COLMAP model.

    Parameters
    ----------
    path : str or os.PathLike
        A model directory (``sparse/0``) with ``cameras``, ``images`` (and ``points3D``) as
        ``.bin`` or ``.txt`` files.

    Returns
    -------
    cameras : dict
        ``image name -> sqfit.Camera`` (pose ``T_world_camera``), in image id order.

    Raises
    ------
    OSError
        No model at ``path``.
    ValueError
        A camera model other than PINHOLE / SIMPLE_PINHOLE (the message names the model, the
        camera id and an image using it), or a model pycolmap cannot read.
    """
    path = Path(path)
    if not path.is_dir():
        raise OSError(f"COLMAP model directory not found: {path}")
    if not any((path / f"images{ext}").is_file() for ext in (".bin", ".txt")):
        raise OSError(f"{path} is not a COLMAP model: it has no images.bin or images.txt")
    pycolmap = _pycolmap()
    try:
        model = pycolmap.Reconstruction(str(path))
    except Exception as exc:  # pycolmap raises RuntimeError / ValueError for broken files
        raise ValueError(f"{path}: pycolmap cannot read this COLMAP model: {exc}") from None
    intrinsics = {}
    cameras = {}
    for image_id in sorted(model.images):
        image = model.images[image_id]
        if not image.has_pose:
            continue  # not registered: no pose, as if absent
        if image.camera_id not in intrinsics:
            intrinsics[image.camera_id] = _intrinsics(model.cameras[image.camera_id], image.name, path)
        T_camera_world = np.vstack([image.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]])
        cameras[image.name] = Camera(intrinsics[image.camera_id], invert(T_camera_world))
    return cameras


def _intrinsics(camera, image_name, path):
    model = camera.model.name
    if model not in PINHOLE_MODELS:
        raise ValueError(f"{path}: camera {camera.camera_id} (used by image {image_name!r}) has model {model}; "
                         f"only {' and '.join(PINHOLE_MODELS)} (no distortion) are supported: undistort the "
                         "images first (colmap image_undistorter writes a PINHOLE model)")
    params = [float(p) for p in camera.params]
    fx, fy, cx, cy = params if model == "PINHOLE" else (params[0], params[0], params[1], params[2])
    try:
        return Intrinsics(int(camera.width), int(camera.height), fx, fy, cx, cy)
    except ValueError as exc:
        raise ValueError(f"{path}: camera {camera.camera_id}: {exc}") from None


def write_colmap(path, cameras, binary=False):
    """Write cameras as a COLMAP model (no 3D points), readable by :func:`read_colmap` and COLMAP.

    Parameters
    ----------
    path : str or os.PathLike
        Model directory (created).
    cameras : dict
        ``image name -> sqfit.Camera``. Images with equal intrinsics share one PINHOLE camera;
        image ids are ``1..n`` in the dict's order.
    binary : bool
        ``.bin`` files instead of ``.txt``.
    """
    pycolmap = _pycolmap()
    model = pycolmap.Reconstruction()
    camera_ids = {}
    for image_id, (name, cam) in enumerate(cameras.items(), start=1):
        if not isinstance(cam, Camera):
            raise ValueError(f"cameras[{name!r}] must be a sqfit.Camera, got {type(cam).__name__}")
        k = cam.intrinsics
        key = (k.width, k.height, k.fx, k.fy, k.cx, k.cy)
        if key not in camera_ids:
            camera_ids[key] = len(camera_ids) + 1
            model.add_camera_with_trivial_rig(pycolmap.Camera(
                camera_id=camera_ids[key], model="PINHOLE", width=k.width, height=k.height,
                params=[k.fx, k.fy, k.cx, k.cy]))
        T = invert(cam.pose)  # cam_from_world
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(T[:3, :3]), T[:3, 3])
        model.add_image_with_trivial_frame(pycolmap.Image(name=str(name), camera_id=camera_ids[key],
                                                          image_id=image_id), pose)
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    (model.write_binary if binary else model.write_text)(str(path))
