"""Camera trajectories of image sequences: ordered, timestamped ``T_world_camera`` per frame.

Two sequence kinds (``[trajectory] kind``); the multi-view ``circle`` stays in ``sqsim.world.scene``.

``orbit``
    ``frames`` cameras going round ``look_at`` over ``arc_deg`` degrees from ``start_deg`` (a
    full turn, ``arc_deg = 360``, does not repeat the first pose), frame ``k`` at time
    ``k / frame_rate_hz`` seconds; with ``laps = L`` (> 1, full turns only) the camera goes round
    ``L`` times, ``360 L`` degrees over the ``frames``. With ``u`` the fraction of the sweep
    (``k / frames`` for full turns, ``k / (frames - 1)`` otherwise), the camera is at distance
    ``radius + radius_amplitude * sin(2 pi * ORBIT_RADIUS_CYCLES * u)`` from the (wandering)
    centre in the horizontal plane, at height ``height + height_amplitude *
    sin(2 pi * ORBIT_HEIGHT_CYCLES * u)``, and looks at ``look_at + look_at_wander * w(u)`` with
    ``w(u) = (sin(2 pi u), sin(4 pi u), LOOK_AT_WANDER_Z * sin(6 pi u))`` (a Lissajous curve),
    world +z up in the image. How ``u`` runs over several laps (``lap_pattern``):

    - ``"run"`` (the default): over the whole run, so the radius, height and gaze vary over all
      laps as over one turn, and no lap passes the objects from the places and gazes of the one
      before (the gaze's first term never repeats a lap's, and the radius (2 cycles) and the height
      (3 cycles) never both do: revisits, not repeated images).
    - ``"lap"``: over each lap, each lap's ``u`` shifted by :data:`LAP_SHIFT` more than the lap's
      before (``u = s - l + LAP_SHIFT * l`` in lap ``l = floor(s)`` of ``s = laps * k / frames``):
      every lap is a one-lap orbit of the same step, from other places and gazes (the shift is
      irrational, so no two laps repeat each other's), and the first ``frames / laps`` frames of a
      run of ``laps`` laps are the one-lap orbit of that many frames. Runs of 1, 2, 4
      ... laps then differ in length only, each the one before plus laps like it: what a test of
      growth with length needs (with ``"run"`` the first lap of two is another path than one lap
      alone: docs/slam-history.md, twenty-eighth pass).
    - ``"revisit"``: every lap the one-lap orbit's path, the same places and gazes at the same
      bearings, each lap's frames :data:`LAP_SHIFT` ``* l`` (modulo 1) of a step further along it
      (``s = laps * k / frames + (LAP_SHIFT * l mod 1) * laps / frames``, ``u = s - l``, and the
      bearing from ``s``): a camera patrolling one loop, frames between the earlier laps' frames,
      never on them. As with ``"lap"``, the first laps of a run are the run of fewer laps, so runs
      differ in length only, but here every lap passes the objects as the first did.

    The path is the same for every trial of a scene (objects and odometry noise are what a trial draws).
``waypoints``
    Poses given as TUM rows ``[t, tx, ty, tz, qx, qy, qz, qw]`` (camera -> world, as
    ``sqfit.formats.tum``), inline (``waypoints``) or in a TUM file (``waypoints_file``, relative
    to the scene file). ``frames`` timestamps are spread evenly from the first to the last
    waypoint time (both included); positions are interpolated linearly and rotations by
    spherical linear interpolation (``scipy.spatial.transform.Slerp``) between the two waypoints
    around each timestamp, so a frame at a waypoint's time has that waypoint's pose.

Keys used only by sequences (``frames``, ``frame_rate_hz``, ``laps``, ``lap_pattern``, ``*_amplitude``, ``look_at_wander``,
``waypoints``, ``waypoints_file``, ``noise.odometry_*``) are an error on a ``circle`` scene, and the
per-view ``noise.pose_*`` noise is an error on a sequence scene (sequences get odometry noise,
``sqsim.world.odometry``); every message names the key.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

import sqfit
from sqfit.formats.tum import read_tum, rows_to_poses

__all__ = ["SEQUENCE_KINDS", "DEFAULT_FRAMES", "DEFAULT_FRAME_RATE_HZ", "LAP_PATTERNS", "LAP_SHIFT", "is_sequence",
           "sequence_poses",
           "orbit_poses", "waypoint_poses", "check_waypoint_rows", "check_sequence_keys"]

SEQUENCE_KINDS = ("orbit", "waypoints")
#: Frames of a sequence when ``trajectory.frames`` is not given.
DEFAULT_FRAMES = 40
#: Frame rate (Hz) of an orbit when ``trajectory.frame_rate_hz`` is not given.
DEFAULT_FRAME_RATE_HZ = 10.0
#: Oscillations of the orbit radius and height over one sweep.
ORBIT_RADIUS_CYCLES, ORBIT_HEIGHT_CYCLES = 2, 3
#: Vertical extent of the look-at wander, as a fraction of ``look_at_wander``.
LOOK_AT_WANDER_Z = 0.25
#: How an orbit's radius, height and gaze cycles run over several laps (module docstring).
LAP_PATTERNS = ("run", "lap", "revisit")
#: With ``lap_pattern = "lap"``, the shift of each lap's cycles against the lap's before, as a
#: fraction of the sweep; with ``"revisit"``, of each lap's frames along the path, as a fraction of
#: a step. The golden ratio's conjugate, the irrational whose multiples modulo 1 spread most
#: evenly, so laps never repeat.
LAP_SHIFT = (5.0 ** 0.5 - 1.0) / 2.0

_ORBIT_ONLY = ("frame_rate_hz", "laps", "lap_pattern", "radius_amplitude", "height_amplitude", "look_at_wander")
_WAYPOINTS_ONLY = ("waypoints", "waypoints_file")
_SEQUENCE_NOISE = ("odometry_rotation_deg", "odometry_translation_m")
_VIEW_NOISE = ("pose_rotation_deg", "pose_translation_m")


def is_sequence(scene):
    """Whether a scene (or its ``trajectory`` section) describes an image sequence."""
    trajectory = getattr(scene, "trajectory", scene)
    return trajectory.kind in SEQUENCE_KINDS


def check_waypoint_rows(value):
    """Validate inline waypoints: at least 2 TUM rows, rotations, strictly increasing times.

    Returns
    -------
    rows : tuple of (8,) tuple of float
    """
    if not isinstance(value, (list, tuple)) or len(value) < 2:
        raise ValueError("must be a list of at least 2 rows [t, tx, ty, tz, qx, qy, qz, qw]")
    for k, row in enumerate(value):
        if (not isinstance(row, (list, tuple)) or len(row) != 8
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in row)):
            raise ValueError(f"row[{k}] must be 8 numbers [t, tx, ty, tz, qx, qy, qz, qw], got {row!r}")
    times, _ = rows_to_poses(np.array(value, dtype=np.float64), name="row")
    back = np.flatnonzero(np.diff(times) <= 0)
    if back.size:
        raise ValueError(f"row[{int(back[0]) + 1}]: times must be strictly increasing")
    return tuple(tuple(float(x) for x in row) for row in value)


def check_sequence_keys(scene):
    """Cross-key checks of the trajectory and noise sections; fills the sequence defaults.

    Parameters
    ----------
    scene : sqsim.world.scene.Scene

    Returns
    -------
    scene : sqsim.world.scene.Scene
        With ``frames`` (and an orbit's ``frame_rate_hz`` and amplitudes) filled in, and
        ``waypoints_file`` resolved against the scene file's directory.
    """
    src, t, noise = scene.source, scene.trajectory, scene.noise
    if not is_sequence(t):
        given = [k for k in ("frames",) + _ORBIT_ONLY + _WAYPOINTS_ONLY if getattr(t, k) is not None]
        given += [f"noise.{k}" for k in _SEQUENCE_NOISE if getattr(noise, k)]
        if given:
            key = given[0] if given[0].startswith("noise.") else f"trajectory.{given[0]}"
            raise ValueError(f"{src}: {key} is only used by sequences (trajectory.kind = \"orbit\" or "
                             f"\"waypoints\"), not kind = {t.kind!r}")
        return scene
    for k in _VIEW_NOISE:
        if getattr(noise, k):
            raise ValueError(f"{src}: noise.{k} is per-view noise of multi-view scenes; a sequence "
                             f"(trajectory.kind = {t.kind!r}) drifts through noise.odometry_rotation_deg "
                             "and noise.odometry_translation_m instead")
    fill = {"frames": DEFAULT_FRAMES if t.frames is None else t.frames}
    if t.kind == "orbit":
        for k in _WAYPOINTS_ONLY:
            if getattr(t, k) is not None:
                raise ValueError(f"{src}: trajectory.{k} is only used with kind = \"waypoints\"")
        fill.update(frame_rate_hz=t.frame_rate_hz or DEFAULT_FRAME_RATE_HZ, laps=t.laps or 1,
                    lap_pattern=t.lap_pattern or LAP_PATTERNS[0],
                    radius_amplitude=t.radius_amplitude or 0.0, height_amplitude=t.height_amplitude or 0.0,
                    look_at_wander=t.look_at_wander or 0.0)
        if fill["lap_pattern"] not in LAP_PATTERNS:  # a scene file's is checked as it is read; one set in code here
            raise ValueError(f"{src}: trajectory.lap_pattern must be one of {list(LAP_PATTERNS)}, got "
                             f"{fill['lap_pattern']!r}")
        if fill["laps"] > 1 and t.arc_deg < 360.0:
            raise ValueError(f"{src}: trajectory.laps > 1 needs full turns (trajectory.arc_deg = 360), got "
                             f"laps = {fill['laps']} with arc_deg = {t.arc_deg}")
        if fill["radius_amplitude"] >= t.radius:
            raise ValueError(f"{src}: trajectory.radius_amplitude must be < trajectory.radius "
                             f"({t.radius}), got {fill['radius_amplitude']}")
        if fill["look_at_wander"] >= t.radius - fill["radius_amplitude"]:
            raise ValueError(f"{src}: trajectory.look_at_wander must be < trajectory.radius - "
                             f"radius_amplitude ({t.radius - fill['radius_amplitude']}), got {fill['look_at_wander']}")
    else:
        for k in _ORBIT_ONLY:
            if getattr(t, k) is not None:
                raise ValueError(f"{src}: trajectory.{k} is only used with kind = \"orbit\"")
        if (t.waypoints is None) == (t.waypoints_file is None):
            raise ValueError(f"{src}: trajectory.kind = \"waypoints\" needs exactly one of trajectory.waypoints "
                             "(inline TUM rows) and trajectory.waypoints_file (a TUM file)")
        if t.waypoints_file is not None:
            path = Path(t.waypoints_file)
            if not path.is_absolute() and Path(src).is_file():
                path = Path(src).resolve().parent / path
            if not path.is_file():
                raise ValueError(f"{src}: trajectory.waypoints_file: TUM file not found: {path}")
            try:
                times, _ = read_tum(path)
            except ValueError as exc:
                raise ValueError(f"{src}: trajectory.waypoints_file: {exc}") from None
            if len(times) < 2:
                raise ValueError(f"{src}: trajectory.waypoints_file: {path} needs at least 2 poses")
            fill["waypoints_file"] = str(path)
    return replace(scene, trajectory=replace(t, **fill))


def sequence_poses(trajectory):
    """Timestamps and true poses of every frame of a sequence trajectory.

    Parameters
    ----------
    trajectory : sqsim.world.scene.TrajectoryConfig
        ``kind`` ``"orbit"`` or ``"waypoints"``, checked by :func:`check_sequence_keys`.

    Returns
    -------
    timestamps : (frames,) float
        Seconds, strictly increasing.
    poses : (frames, 4, 4) float
        ``T_world_camera``.
    """
    if trajectory.kind == "orbit":
        return orbit_poses(trajectory)
    if trajectory.kind == "waypoints":
        if trajectory.waypoints_file is not None:
            times, poses = read_tum(trajectory.waypoints_file)
        else:
            times, poses = rows_to_poses(np.array(trajectory.waypoints), name="trajectory.waypoints")
        return waypoint_poses(times, poses, trajectory.frames)
    raise ValueError(f"trajectory.kind {trajectory.kind!r} is not a sequence (one of {list(SEQUENCE_KINDS)})")


def orbit_poses(t):
    """Frames of an ``orbit`` trajectory (module docstring); returns ``(timestamps, poses)``."""
    n, laps = t.frames, t.laps or 1
    k = np.arange(n)
    u = k / n if t.arc_deg >= 360.0 else k / (n - 1)
    theta = np.radians(t.start_deg + t.arc_deg * laps * u)
    if laps > 1 and t.lap_pattern in ("lap", "revisit"):
        # k * laps / n exactly, so a lap starts at an exact integer and lap 0 is the one-lap orbit
        sweep = k * laps / n
        lap = np.floor(sweep)
        if t.lap_pattern == "lap":
            u = sweep - lap + LAP_SHIFT * lap
        else:
            sweep = sweep + np.mod(LAP_SHIFT * lap, 1.0) * laps / n
            u = sweep - lap
            theta = np.radians(t.start_deg + t.arc_deg * sweep)
    two_pi_u = 2 * np.pi * u
    wander = np.stack([np.sin(two_pi_u), np.sin(2 * two_pi_u), LOOK_AT_WANDER_Z * np.sin(3 * two_pi_u)], axis=1)
    targets = np.asarray(t.look_at, dtype=np.float64) + t.look_at_wander * wander
    radius = t.radius + t.radius_amplitude * np.sin(ORBIT_RADIUS_CYCLES * two_pi_u)
    height = t.height + t.height_amplitude * np.sin(ORBIT_HEIGHT_CYCLES * two_pi_u)
    eyes = np.stack([t.look_at[0] + radius * np.cos(theta), t.look_at[1] + radius * np.sin(theta), height], axis=1)
    poses = np.stack([sqfit.look_at(eye, target) for eye, target in zip(eyes, targets)])
    return k / t.frame_rate_hz, poses


def waypoint_poses(times, poses, frames):
    """Resample waypoints at ``frames`` evenly spaced times (linear position, slerp rotation).

    Parameters
    ----------
    times : (m,) float
        Strictly increasing, ``m >= 2``.
    poses : (m, 4, 4) float
        ``T_world_camera`` of each waypoint.
    frames : int
        ``>= 2``.

    Returns
    -------
    timestamps : (frames,) float
        From ``times[0]`` to ``times[-1]`` inclusive.
    poses : (frames, 4, 4) float
    """
    from scipy.spatial.transform import Rotation, Slerp

    times = np.asarray(times, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    stamps = np.linspace(times[0], times[-1], int(frames))
    out = np.tile(np.eye(4), (len(stamps), 1, 1))
    out[:, :3, :3] = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))(stamps).as_matrix()
    out[:, :3, 3] = np.stack([np.interp(stamps, times, poses[:, i, 3]) for i in range(3)], axis=1)
    return stamps, out
