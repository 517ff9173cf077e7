"""Scene files: a validated, immutable description of a simulation, and seeded trial sampling.

A scene is a TOML file with the sections ``[experiment]``, ``[camera]``, ``[trajectory]``,
``[objects]``, ``[masks]``, ``[noise]`` and ``[fit]`` (keys and defaults: README, "Scene files"; example: scenes/paper.toml).
Every section and key is optional (defaults are the paper's values, Table I); an unknown section
or key, a malformed file or a bad value raises ``ValueError`` naming the file, the key and the
problem. The commands that read a scene take ``--set SECTION.KEY=VALUE`` to replace keys without
editing the file (:func:`scene_overrides`, ``load_scene(path, overrides)``).

Objects of a trial (meshes, sampling, the observability tests): :mod:`sqsim.world.objects`.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

import sqfit
from sqfit.fitting.pipeline import OUTLINE_OFFSETS
from sqfit.views.observation import POLYGON_KINDS, SAMPLING_METHODS

from .objects import KEEPS_PROPORTIONS, PROPORTIONS, check_mesh_file
from .trajectory import LAP_PATTERNS
from .values import (boolean, catalogue, choice, integer, interval, nonempty_string, nonempty_strings, number,
                     optional_path, vector, waypoint_rows)

__all__ = ["Scene", "ExperimentConfig", "CameraConfig", "TrajectoryConfig", "ObjectsConfig",
           "MasksConfig", "NoiseConfig", "FitConfig", "OBJECT_KINDS", "load_scene", "parse_scene", "trial_seed",
           "child_seed", "camera_poses", "scene_overrides", "add_set_option", "SET_HELP", "PATH_KEYS"]

OBJECT_KINDS = ("superquadric", "box", "cylinder", "capsule", "cone", "mesh", "household")
RENDERERS = ("osmesa", "egl", "polygon")
TRAJECTORIES = ("circle", "orbit", "waypoints")  # orbit, waypoints: sequences (sqsim.world.trajectory)
LAYOUTS = ("free", "ground")  # sqsim.world.layout
MIN_VIEWS = sqfit.constants.MIN_VIEWS
_PAPER_CHAINS = ("3A", "3B", "1-3A", "1-2-3A", "1-2-3B", "3E", "1-3E", "1-2-3C", "1-2-3D", "1-2-3E",
                 "1-2-3D-3E", "1-2-3D-3A", "1-2-3D-3F")


# --- sections: frozen dataclasses with per-field checkers in field metadata -----------------------

@dataclass(frozen=True)
class ExperimentConfig:
    name: str = "paper"
    seed: int = 0
    trials: int = 100
    chains: tuple = _PAPER_CHAINS
    limit: bool = True  # score non-superquadric ground truths against their best superquadric (sqsim.world.limit)


@dataclass(frozen=True)
class CameraConfig:
    width: int = 640
    height: int = 480
    fx: float = 400.0
    fy: float = 300.0
    cx: float = 320.0
    cy: float = 240.0


@dataclass(frozen=True)
class TrajectoryConfig:
    kind: str = "circle"
    radius: float = 10.0
    views: int = 3
    height: float = 0.0
    arc_deg: float = 360.0
    look_at: tuple = (0.0, 0.0, 0.0)
    start_deg: float = 0.0  # angle of the first camera on the circle, from +x towards +y
    # Sequences only (kind "orbit" or "waypoints"; sqsim.world.trajectory): None = not given.
    frames: int | None = None
    frame_rate_hz: float | None = None
    laps: int | None = None
    lap_pattern: str | None = None
    radius_amplitude: float | None = None
    height_amplitude: float | None = None
    look_at_wander: float | None = None
    waypoints: tuple | None = None
    waypoints_file: str | None = None


@dataclass(frozen=True)
class ObjectsConfig:
    count: int = 1
    kind: str = "superquadric"
    size: tuple = (0.1, 5.0)
    position: tuple = (-5.0, 5.0)
    rotation: tuple = (-math.pi, math.pi)
    shape: tuple = (0.1, 1.9)
    path: str | None = None
    mesh_resolution: int = 32  # cube-sphere subdivisions of a superquadric mesh
    max_attempts: int = 10000  # draws per trial before giving up on an unobservable scene
    layout: str = "free"  # "free": positions uniform in a cube; "ground": on the floor (sqsim.world.layout)
    upright: bool = False  # ground layout: only the yaw (rz) is drawn, rx = ry = 0
    catalogue: tuple | None = None  # household kinds drawn from (sqsim.world.household); None = all
    proportions: str | None = None  # mesh, household: "keep" (default) or "stretch" (sqsim.world.objects)


@dataclass(frozen=True)
class MasksConfig:
    renderer: str = "osmesa"
    samples: int = 100
    sampling: str = "uniform"
    min_area_px: int = 200
    cleanup: bool = True
    max_cut_fraction: float = 0.0  # projected area an object may have outside an image (0: none)


@dataclass(frozen=True)
class NoiseConfig:
    erosion_px: int = 0
    dilation_px: int = 0
    boundary_jitter_px: float = 0.0
    dropout: float = 0.0
    false_blobs: int = 0
    pose_rotation_deg: float = 0.0
    pose_translation_m: float = 0.0
    odometry_rotation_deg: float = 0.0  # sequences: per-step noise of the relative poses
    odometry_translation_m: float = 0.0
    # Segmenter-like mask models (sqsim.imaging.mask_models), per object and view.
    boundary_bias_px: float = 0.0  # mean outline offset, px (> 0 over-, < 0 under-segmentation)
    boundary_bias_std_px: float = 0.0  # its standard deviation across objects and views, px
    smooth_error_px: float = 0.0  # RMS of a smooth normal displacement of the outline, px
    smooth_error_wavelength_px: float = 32.0  # its wavelength, px
    thin_part_width_px: float = 0.0  # parts narrower than this vanish (opening), px
    hole_rate: float = 0.0  # interior holes per 1000 px of mask area
    hole_radius_px: float = 2.0


#: Keys of [noise] that shape a model rather than turn it on (they leave clean masks clean).
NOISE_SHAPE_KEYS = ("smooth_error_wavelength_px", "hole_radius_px")


@dataclass(frozen=True)
class FitConfig:
    polygon: str = "hull"
    penalty_riou: float = 1.0
    penalty_analytic: float = 100.0
    pose_sigma_deg: float = sqfit.FitOptions.pose_sigma_deg
    occlusion_aware: bool = sqfit.FitOptions.occlusion_aware
    outline_offset_sigma_px: float = sqfit.FitOptions.outline_offset_sigma_px
    outline_offset: str = sqfit.FitOptions.outline_offset
    outline_offset_view_sigma_px: float = sqfit.FitOptions.outline_offset_view_sigma_px
    size_min_m: float = sqfit.FitOptions.size_min_m
    n_contour: int = sqfit.FitOptions.n_contour


_CHECKS = {
    "experiment": {"name": nonempty_string, "seed": integer(0), "trials": integer(1), "chains": nonempty_strings,
                   "limit": boolean},
    "camera": {"width": integer(1), "height": integer(1), "fx": number(0, lo_open=True),
               "fy": number(0, lo_open=True), "cx": number(), "cy": number()},
    "trajectory": {"kind": choice(TRAJECTORIES), "radius": number(0, lo_open=True), "views": integer(1),
                   "height": number(), "arc_deg": number(0, 360, lo_open=True), "look_at": vector(3),
                   "start_deg": number(), "frames": integer(2), "frame_rate_hz": number(0, lo_open=True),
                   "laps": integer(1), "lap_pattern": choice(LAP_PATTERNS),
                   "radius_amplitude": number(0), "height_amplitude": number(0), "look_at_wander": number(0),
                   "waypoints": waypoint_rows, "waypoints_file": optional_path},
    "objects": {"count": integer(1), "kind": choice(OBJECT_KINDS), "size": interval(0, lo_open=True),
                "position": interval(), "rotation": interval(), "shape": interval(lo=sqfit.constants.SHAPE_DOMAIN[0], hi=sqfit.constants.SHAPE_DOMAIN[1]),
                "path": optional_path, "mesh_resolution": integer(2), "max_attempts": integer(1),
                "layout": choice(LAYOUTS), "upright": boolean, "catalogue": catalogue,
                "proportions": choice(PROPORTIONS)},
    "masks": {"renderer": choice(RENDERERS), "samples": integer(3), "sampling": choice(SAMPLING_METHODS),
              "min_area_px": integer(0), "cleanup": boolean, "max_cut_fraction": number(0, 1, hi_open=True)},
    "noise": {"erosion_px": integer(0), "dilation_px": integer(0), "boundary_jitter_px": number(0),
              "dropout": number(0, 1, hi_open=True), "false_blobs": integer(0),
              "pose_rotation_deg": number(0), "pose_translation_m": number(0),
              "odometry_rotation_deg": number(0), "odometry_translation_m": number(0),
              "boundary_bias_px": number(), "boundary_bias_std_px": number(0), "smooth_error_px": number(0),
              "smooth_error_wavelength_px": number(0, lo_open=True), "thin_part_width_px": number(0),
              "hole_rate": number(0), "hole_radius_px": number(0, lo_open=True)},
    "fit": {"polygon": choice(POLYGON_KINDS), "penalty_riou": number(0, lo_open=True),
            "penalty_analytic": number(0, lo_open=True), "pose_sigma_deg": number(0),
            "occlusion_aware": boolean, "outline_offset_sigma_px": number(0),
            "outline_offset": choice(OUTLINE_OFFSETS), "outline_offset_view_sigma_px": number(0, lo_open=True),
            "size_min_m": number(0, lo_open=True), "n_contour": integer(3)},
}
_SECTIONS = {"experiment": ExperimentConfig, "camera": CameraConfig, "trajectory": TrajectoryConfig,
             "objects": ObjectsConfig, "masks": MasksConfig, "noise": NoiseConfig, "fit": FitConfig}


@dataclass(frozen=True)
class Scene:
    """An immutable, validated scene: one attribute per TOML section.

    Attributes
    ----------
    experiment, camera, trajectory, objects, masks, noise, fit
        Frozen section records whose fields are the TOML keys.
    source : str
        Where the scene came from (a file path or ``"<string>"``), for error messages.
    """

    experiment: ExperimentConfig = ExperimentConfig()
    camera: CameraConfig = CameraConfig()
    trajectory: TrajectoryConfig = TrajectoryConfig()
    objects: ObjectsConfig = ObjectsConfig()
    masks: MasksConfig = MasksConfig()
    noise: NoiseConfig = NoiseConfig()
    fit: FitConfig = FitConfig()
    source: str = "<string>"

    @property
    def intrinsics(self):
        """``sqfit.Intrinsics`` of every camera."""
        return sqfit.Intrinsics(**asdict(self.camera))

    @property
    def noise_free(self):
        """True when every noise amount is zero (model shapes, :data:`NOISE_SHAPE_KEYS`, aside)."""
        return not any(v for k, v in asdict(self.noise).items() if k not in NOISE_SHAPE_KEYS)

    def to_dict(self):
        """Plain, TOML/JSON-friendly mapping (lists, not tuples); :func:`parse_scene` round-trips it."""
        out = {}
        for name in _SECTIONS:
            section = {}
            for key, value in asdict(getattr(self, name)).items():
                if value is None:
                    continue
                section[key] = list(value) if isinstance(value, tuple) else value
            out[name] = section
        return out

    def with_overrides(self, overrides):
        """A validated copy with some keys replaced.

        Parameters
        ----------
        overrides : dict
            ``"section.key" -> value``, e.g. ``{"noise.boundary_jitter_px": 2.0}``.

        Returns
        -------
        scene : Scene
        """
        data = self.to_dict()
        for dotted, value in dict(overrides).items():
            section, key = _override_key(dotted, self.source)
            data[section][key] = list(value) if isinstance(value, tuple) else value
        return parse_scene(data, source=self.source)

    def cameras(self):
        """The true cameras of every trial: ``list[sqfit.Camera]`` on the trajectory."""
        # Built once per scene (cameras are immutable): every trial and re-draw asks for them.
        cached = self.__dict__.get("_cameras")
        if cached is None:
            intr = self.intrinsics
            cached = tuple(sqfit.Camera(intr, T) for T in camera_poses(self.trajectory))
            object.__setattr__(self, "_cameras", cached)
        return list(cached)


#: Help of the commands' ``--set`` option (:func:`scene_overrides`).
SET_HELP = ("replace a scene key without editing the file, e.g. --set 'objects.catalogue=[mug,can]' "
            "--set noise.pose_rotation_deg=1 (repeatable; VALUE is a TOML value; bare words are strings)")
#: A ``--set`` value that is no TOML but a word (``household``, ``1-2-3D``) or a path (``meshes/duck.obj``).
_BARE_WORD = re.compile(r"[A-Za-z0-9_./~+:][A-Za-z0-9_./~+:\-]*")
#: Keys that name files: relative in a scene file to the file's directory, relative in ``--set`` to the
#: current directory (where the user typed it).
PATH_KEYS = ("objects.path", "trajectory.waypoints_file")


def add_set_option(parser, note=""):
    """Give an ``argparse`` parser the commands' ``--set SECTION.KEY=VALUE`` option (repeatable, read by
    :func:`scene_overrides`); ``note`` is added to its help."""
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help=SET_HELP + (f"; {note}" if note else ""))


def scene_overrides(items):
    """Scene keys to replace, from ``--set`` items.

    Parameters
    ----------
    items : iterable of str
        ``"SECTION.KEY=VALUE"``, VALUE a TOML value (``2``, ``0.5``, ``true``, ``"mug"``,
        ``["mug", "can"]``); a bare word (``household``, ``1-2-3D``, a path without spaces) is taken
        as a string, and a list of bare words (``[mug, can]``) as a list of strings, so the shell
        needs no quotes inside.

    Returns
    -------
    overrides : dict
        ``{"section.key": value}`` in the order given (a key set twice keeps the last value).

    Raises
    ------
    ValueError
        An item without ``=``, a key that is not ``section.key`` of a scene, or a value that is
        not TOML; the message names the item.
    """
    out = {}
    for item in items or ():
        dotted, sep, text = str(item).partition("=")
        dotted, text = dotted.strip(), text.strip()
        section, _, key = dotted.partition(".")
        if not sep or not text or not key:
            raise ValueError(f"--set {item!r}: expected SECTION.KEY=VALUE, e.g. noise.dropout=0.1")
        if section not in _SECTIONS:
            raise ValueError(f"--set {item!r}: unknown section {section!r} (known: {', '.join(_SECTIONS)})")
        if key not in _CHECKS[section]:
            known = ", ".join(_CHECKS[section])
            raise ValueError(f"--set {item!r}: unknown key {key!r} in [{section}] (known: {known})")
        try:
            value = tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError as exc:
            words = [w.strip() for w in text[1:-1].split(",")] if text[:1] + text[-1:] == "[]" else [text]
            if not all(_BARE_WORD.fullmatch(w) for w in words):
                raise ValueError(f"--set {item!r}: the value is neither TOML nor a bare word or list of bare "
                                 f"words ({exc})") from None
            value = words if text.startswith("[") else text
        out[dotted] = value
    return out


def load_scene(path, overrides=None):
    """Read and validate a scene TOML file.

    Parameters
    ----------
    path : str or os.PathLike
    overrides : dict, optional
        ``{"section.key": value}`` replacing keys of the file before it is validated (the
        commands' ``--set``, :func:`scene_overrides`), so a key may be set that the file's other
        keys need (``objects.kind`` with ``objects.catalogue``). A relative path given for one of
        :data:`PATH_KEYS` is taken from the current directory, not from the file's.

    Returns
    -------
    scene : Scene

    Raises
    ------
    OSError
        The file cannot be read.
    ValueError
        Malformed TOML, unknown section or key, or a bad value (message names file and key, and
        the overrides where there are any).
    """
    return parse_scene(read_toml(path), source=str(path), overrides=overrides)


def _override_key(dotted, source):
    """``(section, key)`` of an override key ``"section.key"``; ValueError naming ``source`` if no scene has it."""
    section, _, key = str(dotted).partition(".")
    if section not in _SECTIONS or key not in _CHECKS[section]:
        raise ValueError(f"{source}: unknown override key {dotted!r} (use 'section.key', e.g. 'noise.dropout')")
    return section, key


def read_toml(path):
    """The parsed TOML mapping of a scene (or sweep) file, with clear errors.

    Raises
    ------
    OSError
        The file does not exist.
    ValueError
        Malformed TOML (the message names the file).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise OSError(f"scene file not found: {path}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: malformed TOML: {exc}") from None


def parse_scene(mapping, source="<string>", overrides=None):
    """Validate a scene mapping (the parsed TOML) into a :class:`Scene`.

    Parameters
    ----------
    mapping : dict
        ``section -> {key -> value}``; missing sections and keys take their defaults.
    source : str
        File name used in error messages and to resolve a relative ``objects.path``.
    overrides : dict, optional
        ``{"section.key": value}`` replacing keys of ``mapping`` (not changed) before it is
        validated, as :func:`load_scene` takes them; an error then also names them.

    Returns
    -------
    scene : Scene
    """
    if not isinstance(mapping, dict):
        raise ValueError(f"{source}: a scene must be a mapping of sections, got {type(mapping).__name__}")
    if overrides:
        mapping = {name: dict(values) if isinstance(values, dict) else values for name, values in mapping.items()}
        for dotted, value in dict(overrides).items():
            section, key = _override_key(dotted, source)
            table = mapping.setdefault(section, {})
            if not isinstance(table, dict):
                raise ValueError(f"{source}: [{section}] must be a table of keys, got {table!r}")
            if dotted in PATH_KEYS and isinstance(value, str) and value:
                value = str(Path.cwd() / Path(value).expanduser())  # an absolute path stays itself
            table[key] = value
        try:
            return parse_scene(mapping, source)
        except ValueError as exc:
            changed = ", ".join(f"{k}={v!r}" for k, v in dict(overrides).items())
            raise ValueError(f"{exc} (with {changed} set over the file's keys)") from None
    sections = {}
    for name, values in mapping.items():
        if name not in _SECTIONS:
            raise ValueError(f"{source}: unknown section [{name}] (known: {', '.join(_SECTIONS)})")
        if not isinstance(values, dict):
            raise ValueError(f"{source}: [{name}] must be a table of keys, got {values!r}")
        clean = {}
        for key, value in values.items():
            check = _CHECKS[name].get(key)
            if check is None:
                raise ValueError(f"{source}: unknown key '{key}' in [{name}] "
                                 f"(known: {', '.join(_CHECKS[name])})")
            try:
                clean[key] = check(value)
            except ValueError as exc:
                raise ValueError(f"{source}: {name}.{key} {exc}") from None
        sections[name] = _SECTIONS[name](**clean)
    scene = Scene(**sections, source=str(source))
    return _check_scene(scene)


def _check_scene(scene):
    src, obj = scene.source, scene.objects
    if scene.trajectory.views < MIN_VIEWS:
        raise ValueError(f"{src}: trajectory.views = {scene.trajectory.views}: fitting needs >= {MIN_VIEWS} views "
                         f"of each object (set trajectory.views >= {MIN_VIEWS})")
    if obj.kind == "mesh":
        if obj.path is None:
            raise ValueError(f"{src}: objects.path is required when objects.kind = \"mesh\"")
        path = Path(obj.path)
        if not path.is_absolute() and Path(src).is_file():
            path = Path(src).resolve().parent / path
        if not path.is_file():
            raise ValueError(f"{src}: objects.path: mesh file not found: {path}")
        try:
            check_mesh_file(str(path))
        except ValueError as exc:
            raise ValueError(f"{src}: objects.path: {exc}") from None
        scene = replace(scene, objects=replace(obj, path=str(path)))
    elif obj.path is not None:
        raise ValueError(f"{src}: objects.path is only used with objects.kind = \"mesh\", "
                         f"not {obj.kind!r}")
    if obj.catalogue is not None and obj.kind != "household":
        raise ValueError(f"{src}: objects.catalogue is only used with objects.kind = \"household\", "
                         f"not {obj.kind!r}")
    if obj.proportions is not None and obj.kind not in KEEPS_PROPORTIONS:
        raise ValueError(f"{src}: objects.proportions is only used with objects.kind = \"mesh\" or "
                         f"\"household\", not {obj.kind!r} (its size is the half-axes a)")
    if obj.count > np.iinfo(np.uint16).max:
        raise ValueError(f"{src}: objects.count must be <= 65535 (uint16 instance ids)")
    from .layout import check_layout
    from .trajectory import check_sequence_keys

    return check_sequence_keys(check_layout(scene))


# --- seeds ----------------------------------------------------------------------------------------

def trial_seed(seed, index):
    """Seed of one trial: ``np.random.SeedSequence(seed).spawn(n)[index]`` for any ``n > index``.

    Parameters
    ----------
    seed : int
        Experiment seed, >= 0.
    index : int
        Trial index, >= 0.

    Returns
    -------
    seed_sequence : numpy.random.SeedSequence
    """
    if int(index) != index or index < 0:
        raise ValueError(f"trial index must be an integer >= 0, got {index}")
    return np.random.SeedSequence(int(seed), spawn_key=(int(index),))


def child_seed(seed_sequence, k):
    """The ``k``-th child of a seed sequence (``seed_sequence.spawn(n)[k]``), without mutating it."""
    return np.random.SeedSequence(seed_sequence.entropy, spawn_key=tuple(seed_sequence.spawn_key) + (int(k),))


# --- cameras --------------------------------------------------------------------------------------

def camera_poses(trajectory):
    """``T_world_camera`` of every view of a trajectory.

    Views on a ``circle`` of ``radius`` around ``look_at`` at height ``height`` (world z), at
    angles ``start_deg + arc_deg * k / views`` for a full circle (``arc_deg = 360``) and spread
    from ``start_deg`` to ``start_deg + arc_deg`` inclusive otherwise, each looking at
    ``look_at`` with world +z up in the image. A sequence kind (``orbit``, ``waypoints``) gives
    its frames (``sqsim.world.trajectory.sequence_poses``).

    Returns
    -------
    poses : (views, 4, 4) float
    """
    t = trajectory
    if t.kind != "circle":
        from .trajectory import sequence_poses

        return sequence_poses(t)[1]
    if t.arc_deg >= 360.0 or t.views == 1:
        angles = t.start_deg + t.arc_deg * np.arange(t.views) / t.views
    else:
        angles = t.start_deg + np.linspace(0.0, t.arc_deg, t.views)
    theta = np.radians(angles)
    target = np.asarray(t.look_at, dtype=np.float64)
    eyes = np.stack([target[0] + t.radius * np.cos(theta), target[1] + t.radius * np.sin(theta),
                     np.full(len(theta), t.height)], axis=1)
    return np.stack([sqfit.look_at(eye, target) for eye in eyes])
