"""Cameras of COCO images from a timestamped trajectory (a TUM file): intrinsics, image times, association.

A TUM trajectory (:mod:`.tum`, ``t tx ty tz qx qy qz qw`` per line) has poses and timestamps but
neither intrinsics nor image names. The user gives them, and each COCO image is joined to a pose:

- **Intrinsics** (:func:`read_intrinsics`), one pinhole camera for every image: the six numbers
  ``fx fy cx cy width height`` (inline, or a text file; ``#`` comments, spaces or commas) or a
  JSON object with these six keys. No distortion: more numbers (TUM's ``d0 .. d4``) are refused;
  undistort the images first.
- **Image timestamps** (:func:`image_timestamps`): by default the file name stem as a number of
  seconds (TUM RGB-D names its frames ``rgb/1305031102.175304.png``); or an association list as
  TUM RGB-D's ``rgb.txt`` (:func:`read_image_times`: lines ``timestamp filename``, further
  columns such as ``associate.py``'s depth pair ignored), whose names are matched to COCO
  ``file_name`` as pose names are (exact, else a unique base name).
- **Association** (:func:`associate`): each image takes the pose nearest in time, as TUM's
  ``associate.py`` does, if it is at most ``max_time_diff`` seconds away
  (:data:`DEFAULT_MAX_TIME_DIFF`, ``associate.py``'s default); several images may share a pose (no
  interpolation). An image without a timestamp, without a pose that near, or whose COCO size is
  not the intrinsics' is unusable, with the reason (each object seen there records it as a dropped
  view, as for the other pose sources).

Conventions, converted here once (pinned by ``tests/test_formats_tum.py``):

- A TUM line is ``T_world_camera`` of the optical frame (x right, y down, z forward), as the TUM
  RGB-D benchmark defines it and :mod:`sqfit.geometry.camera` uses: :func:`.tum.read_tum` turns the
  quaternion into the rotation and nothing else changes.
- The principal point: ``convention="opencv"`` (the default) reads ``cx, cy`` as OpenCV
  calibration, ROS ``CameraInfo`` and the TUM RGB-D camera parameters give them, with the centre
  of the top-left pixel at ``(0, 0)``, and adds 0.5 to put it at sqfit's ``(0.5, 0.5)``;
  ``convention="sqfit"`` takes them as they are (COLMAP, a JSON pose file, ``cameras.json``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path, PurePosixPath

import numpy as np

from .._checks import check_shape
from ..geometry.camera import Camera, Intrinsics
from ._names import NameIndex, base_name
from .tum import data_lines, read_tum

__all__ = ["DEFAULT_MAX_TIME_DIFF", "INTRINSICS_CONVENTIONS", "INTRINSICS_FIELDS", "read_intrinsics",
           "write_intrinsics", "read_image_times", "write_image_times", "image_timestamps", "associate",
           "match_trajectory"]

#: Largest time between an image and the pose it is given, seconds (TUM ``associate.py``'s default).
DEFAULT_MAX_TIME_DIFF = 0.02

#: Principal point conventions of user intrinsics -> pixels added to ``cx, cy`` to get sqfit's.
INTRINSICS_CONVENTIONS = {"opencv": 0.5, "sqfit": 0.0}

#: The intrinsics, in the order of the plain-text form.
INTRINSICS_FIELDS = ("fx", "fy", "cx", "cy", "width", "height")

_TEXT_FORM = "'fx fy cx cy width height'"


def read_intrinsics(source, convention="opencv"):
    """Pinhole intrinsics given by a user for a trajectory's images.

    Parameters
    ----------
    source : sqfit.Intrinsics, dict, sequence, str or os.PathLike
        An ``Intrinsics`` (used as is: already sqfit's convention), a dict with the keys of
        :data:`INTRINSICS_FIELDS`, six numbers in that order, the path of a text file ``fx fy cx cy width height`` or of a JSON
        file holding such a dict, or that text itself (``"525 525 319.5 239.5 640 480"``).
    convention : {"opencv", "sqfit"}
        Where ``cx, cy`` put the centre of the top-left pixel (module docstring).

    Returns
    -------
    intrinsics : sqfit.Intrinsics

    Raises
    ------
    OSError
        ``source`` names a file that does not exist.
    ValueError
        Not six numbers (with a hint about distortion coefficients or a missing image size),
        missing or unknown keys, or values :class:`sqfit.Intrinsics` refuses; the message names
        the file.
    """
    if isinstance(source, Intrinsics):
        return source
    if convention not in INTRINSICS_CONVENTIONS:
        raise ValueError(f"intrinsics convention must be one of {list(INTRINSICS_CONVENTIONS)}, got {convention!r}")
    where = "intrinsics"
    if isinstance(source, dict):
        values = _from_dict(source, where)
    elif isinstance(source, (list, tuple, np.ndarray)):
        values = _from_text(" ".join(str(x) for x in np.ravel(np.asarray(source, dtype=object))), where)
    elif not isinstance(source, (str, os.PathLike)):
        raise ValueError(f"intrinsics must be a sqfit.Intrinsics, a dict, six numbers {_TEXT_FORM} or a file, "
                         f"got {type(source).__name__}")
    else:
        text = str(os.fspath(source))
        if Path(text).is_file():
            where = f"intrinsics file {text}"
            text = Path(text).read_text(encoding="utf-8")
        elif isinstance(source, os.PathLike) or not _looks_like_numbers(text):
            raise OSError(f"intrinsics file not found: {text} (give a file, or the numbers {_TEXT_FORM})")
        if text.lstrip()[:1] in ("{", "["):
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise ValueError(f"{where} is not valid JSON: {exc}") from None
            values = _from_dict(data, where)
        else:
            values = _from_text(text, where)
    shift = INTRINSICS_CONVENTIONS[convention]
    try:
        return Intrinsics(values["width"], values["height"], values["fx"], values["fy"],
                          values["cx"] + shift, values["cy"] + shift)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None


def _looks_like_numbers(text):
    fields = text.replace(",", " ").split()
    try:
        [float(x) for x in fields]
    except ValueError:
        return False
    return bool(fields)


def _from_text(text, where):
    fields = " ".join(line.split("#")[0] for line in text.splitlines()).replace(",", " ").split()
    try:
        numbers = [float(x) for x in fields]
    except ValueError:
        raise ValueError(f"{where}: expected the numbers {_TEXT_FORM}, got {' '.join(fields)!r}") from None
    if len(numbers) != len(INTRINSICS_FIELDS):
        hint = ""
        if len(numbers) == 4:
            hint = ": add the image size (width height) after fx fy cx cy"
        elif len(numbers) > 6:
            hint = (": distortion coefficients cannot be used (the fitter's projection has no distortion "
                    "term); undistort the images first and give the undistorted camera")
        raise ValueError(f"{where}: expected 6 numbers {_TEXT_FORM}, got {len(numbers)}{hint}")
    return dict(zip(INTRINSICS_FIELDS, numbers))


def _from_dict(data, where):
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be an object with keys {', '.join(INTRINSICS_FIELDS)}")
    missing = [k for k in INTRINSICS_FIELDS if k not in data]
    unknown = sorted(set(data) - set(INTRINSICS_FIELDS))
    if missing or unknown:
        raise ValueError(f"{where} needs exactly the keys {', '.join(INTRINSICS_FIELDS)}"
                         + (f"; missing {missing}" if missing else "") + (f"; unknown {unknown}" if unknown else ""))
    for k in INTRINSICS_FIELDS:
        if not isinstance(data[k], (int, float)) or isinstance(data[k], bool):
            raise ValueError(f"{where}: {k} must be a number, got {data[k]!r}")
    return dict(data)


def write_intrinsics(path, intrinsics, convention="opencv"):
    """Write intrinsics as the text :func:`read_intrinsics` reads back (``fx fy cx cy width height``).

    Parameters
    ----------
    path : str or os.PathLike
    intrinsics : sqfit.Intrinsics
    convention : {"opencv", "sqfit"}
        Principal point convention to write ``cx, cy`` in (module docstring).
    """
    if convention not in INTRINSICS_CONVENTIONS:
        raise ValueError(f"intrinsics convention must be one of {list(INTRINSICS_CONVENTIONS)}, got {convention!r}")
    k, shift = intrinsics, INTRINSICS_CONVENTIONS[convention]
    values = [k.fx, k.fy, k.cx - shift, k.cy - shift, k.width, k.height]
    Path(os.fspath(path)).write_text(f"# fx fy cx cy width height (principal point: {convention} convention)\n"
                                     + " ".join(repr(v) for v in values) + "\n", encoding="utf-8")


def write_image_times(path, times):
    """Write ``file name -> seconds`` as a list :func:`read_image_times` reads back (``rgb.txt`` style)."""
    lines = []
    for name, t in times.items():
        if not name or any(c.isspace() or c == "," for c in str(name)):
            raise ValueError(f"image name {name!r} cannot be written: it is empty or holds a space or comma")
        if not math.isfinite(float(t)):
            raise ValueError(f"timestamp of {name!r} must be finite, got {t}")
        lines.append(f"{float(t)!r} {name}\n")
    Path(os.fspath(path)).write_text("# timestamp filename\n" + "".join(lines), encoding="utf-8")


def read_image_times(path):
    """Timestamps of images from an association list as TUM RGB-D's ``rgb.txt``.

    Parameters
    ----------
    path : str or os.PathLike
        Lines ``timestamp filename [...]`` (seconds; spaces, tabs or commas); ``#`` lines and blank
        lines are skipped, columns after the file name are ignored.

    Returns
    -------
    times : dict
        ``file name -> timestamp`` (seconds), in file order.

    Raises
    ------
    OSError
        The file does not exist.
    ValueError
        A line without a finite timestamp and a name, a name listed twice, or no entry; the message
        names the file and the line.
    """
    path = Path(os.fspath(path))
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise OSError(f"image timestamp list not found: {path}") from None
    times, lines = {}, {}
    for number, line, fields in data_lines(text):
        try:
            t = float(fields[0])
        except ValueError:
            t = math.nan
        if len(fields) < 2 or not math.isfinite(t):
            raise ValueError(f"{path}:{number}: expected 'timestamp filename' (seconds, then the image's file "
                             f"name), got {line!r}")
        if fields[1] in times:
            raise ValueError(f"{path}:{number}: {fields[1]!r} is listed twice (also line {lines[fields[1]]})")
        times[fields[1]] = t
        lines[fields[1]] = number
    if not times:
        raise ValueError(f"{path}: no entries (an image timestamp list has lines 'timestamp filename')")
    return times


def image_timestamps(images, image_times=None, source=None):
    """Timestamp of each COCO image, from its file name or from an association list.

    Parameters
    ----------
    images : dict
        ``image id -> CocoImage``.
    image_times : None, dict, str or os.PathLike
        None: the file name stem as seconds (``rgb/1305031102.175304.png``). Otherwise
        ``file name -> seconds`` or the path of a list read by :func:`read_image_times`.
    source : str, optional
        Name of the list in messages (default: its path).

    Returns
    -------
    times : dict
        ``image id -> timestamp`` (seconds).
    unusable : dict
        ``image id -> reason`` for images without a timestamp.
    """
    if image_times is not None and not isinstance(image_times, dict):
        source = source or str(image_times)
        image_times = read_image_times(image_times)
    index = NameIndex(image_times) if image_times is not None else None
    times, unusable = {}, {}
    for image_id, image in images.items():
        name = image.file_name
        if index is None:
            stem = PurePosixPath(base_name(name)).stem
            try:
                t = float(stem)
            except ValueError:
                t = math.nan
            if not math.isfinite(t):
                unusable[image_id] = (f"image {name!r}: its file name stem {stem!r} is not a timestamp in seconds; "
                                      "name the images by time (rgb/1305031102.175304.png) or give a list "
                                      "'timestamp filename' (--image-times rgb.txt)")
                continue
        else:
            found, how = index.find(name, what="entry")
            if found is None:
                unusable[image_id] = f"image {name!r} is not in {source or 'the image timestamp list'}: {how}"
                continue
            t = image_times[found]
        times[image_id] = t
    return times, unusable


def associate(times, trajectory_times):
    """Nearest trajectory timestamp of each time.

    Parameters
    ----------
    times : (n,) float
        Seconds.
    trajectory_times : (m,) float
        Seconds, strictly increasing, ``m >= 1``.

    Returns
    -------
    index : (n,) int
        Index into ``trajectory_times`` of the nearest time (the earlier one on a tie).
    difference : (n,) float
        ``|times - trajectory_times[index]|``, seconds.
    """
    times = check_shape(times, (None,), "times")
    trajectory_times = check_shape(trajectory_times, (None,), "trajectory_times")
    if not len(trajectory_times):
        raise ValueError("trajectory_times is empty")
    if np.any(np.diff(trajectory_times) <= 0):
        raise ValueError("trajectory_times must be strictly increasing")
    last = len(trajectory_times) - 1
    after = np.searchsorted(trajectory_times, times)
    lo, hi = np.clip(after - 1, 0, last), np.clip(after, 0, last)
    index = np.where(np.abs(times - trajectory_times[lo]) <= np.abs(trajectory_times[hi] - times), lo, hi)
    return index, np.abs(times - trajectory_times[index])


def match_trajectory(images, trajectory, intrinsics, image_times=None, max_time_diff=DEFAULT_MAX_TIME_DIFF,
                     source=None):
    """Camera of each COCO image from a trajectory, matched by time (module docstring).

    Parameters
    ----------
    images : dict
        ``image id -> CocoImage``.
    trajectory : str, os.PathLike or tuple
        A TUM file, or ``(timestamps (m,), poses (m, 4, 4))`` with poses ``T_world_camera``.
    intrinsics : sqfit.Intrinsics
        Of every image (:func:`read_intrinsics` reads a user's).
    image_times : None, dict, str or os.PathLike
        As :func:`image_timestamps`.
    max_time_diff : float
        Seconds, >= 0.
    source : str, optional
        Name of the trajectory in messages (default: its path).

    Returns
    -------
    cameras : dict
        ``image id -> sqfit.Camera``.
    unusable : dict
        ``image id -> reason``.
    """
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics must be a sqfit.Intrinsics (read_intrinsics reads a user's), "
                         f"got {type(intrinsics).__name__}")
    try:
        max_time_diff = float(max_time_diff)
    except (TypeError, ValueError):
        max_time_diff = math.nan
    if not math.isfinite(max_time_diff) or max_time_diff < 0:
        raise ValueError(f"max_time_diff must be a finite number of seconds >= 0, got {max_time_diff}")
    if isinstance(trajectory, tuple):
        traj_times, poses = trajectory
        traj_times = check_shape(traj_times, (None,), "trajectory timestamps")
        poses = check_shape(poses, (len(traj_times), 4, 4), "trajectory poses")
        source = source or "the trajectory"
    else:
        source = source or str(trajectory)
        traj_times, poses = read_tum(trajectory)
    times, unusable = image_timestamps(images, image_times)
    ids = list(times)
    index, diff = associate([times[i] for i in ids], traj_times)
    cameras = {}
    for image_id, k, dt in zip(ids, index, diff):
        image = images[image_id]
        if dt > max_time_diff:
            unusable[image_id] = (f"image {image.file_name!r} (t = {times[image_id]:.6f} s) has no pose in {source} "
                                  f"within {max_time_diff:g} s: the nearest is {dt:.3g} s away "
                                  f"(t = {traj_times[k]:.6f} s; --max-time-diff)")
        elif (intrinsics.width, intrinsics.height) != (image.width, image.height):
            unusable[image_id] = (f"image {image.file_name!r} is {image.width}x{image.height} in COCO but the "
                                  f"intrinsics are {intrinsics.width}x{intrinsics.height}")
        else:
            cameras[image_id] = Camera(intrinsics, poses[k])
    return cameras, {i: unusable[i] for i in images if i in unusable}
