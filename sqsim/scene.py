"""Scene files: a validated, immutable description of a simulation, and seeded trial sampling.

A scene is a TOML file with the sections ``[experiment]``, ``[camera]``, ``[trajectory]``,
``[objects]``, ``[masks]``, ``[noise]`` and ``[fit]`` (keys and defaults: README, "Scene files"; example: scenes/paper.toml).
Every section and key is optional (defaults are the paper's values, Table I); an unknown section
or key, a malformed file or a bad value raises ``ValueError`` naming the file, the key and the
problem.

Sampling (:func:`sample_geometry`): a trial draws, per object and in this order, the half-axis
lengths ``a`` (3, uniform in ``objects.size``), the shape exponents (2, uniform in
``objects.shape``), the position (3, uniform in ``objects.position``) and the Euler angles (3,
uniform in ``objects.rotation``), from ``np.random.default_rng(trial_seed(seed, index))``, so a
trial never depends on other trials, worker count or order. The mesh kinds use the same draws:

- ``superquadric``: ``sqfit.Superquadric`` meshed with ``sqfit.superquadric.to_mesh``;
- ``box``: extents ``2 a`` (the box the superquadric tends to as ``e -> 0``);
- ``cylinder``: elliptic cylinder, semi-axes ``ax, ay``, length ``2 az`` along local z;
- ``capsule``: a capsule of radius 1 and total length 4, scaled by ``(ax, ay, az / 2)``: elliptic
  cross-section ``ax, ay``, total length ``2 az``;
- ``cone``: elliptic base ``ax, ay`` at local ``z = -az``, apex at ``z = +az``;
- ``mesh``: the file at ``objects.path`` (relative to the scene file), centred on its bounding
  box and scaled per axis so that its bounding box is ``2 a``.

The shape exponents are drawn for every kind (so kinds share the random stream) and ignored by
the mesh kinds. Cameras sit on a circle (``trajectory``) and look at ``look_at`` with +z up.
A trial is observable when every object's mesh is in front of every camera (depth > ``ZNEAR``),
its projection lies inside every image without touching the border pixels (or, with
``masks.max_cut_fraction > 0``, at most that fraction of its projected area -- the convex hull of
its projected mesh vertices -- lies outside the image: truncated objects), and its visible
(rendered, possibly occluded) mask has at least ``masks.min_area_px`` pixels in every view;
otherwise the objects are drawn again (up to ``objects.max_attempts`` times) and the number of
re-draws is reported as ``resampled``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

import sqfit
from sqfit.observation import POLYGON_KINDS, SAMPLING_METHODS
from sqfit.superquadric import euler_to_matrix, to_mesh

from ._scene_values import (_bool, _choice, _float, _int, _optional_path, _range, _string,  # noqa: F401
                            _strings, _vector, _waypoints)

__all__ = ["Scene", "ExperimentConfig", "CameraConfig", "TrajectoryConfig", "ObjectsConfig",
           "MasksConfig", "NoiseConfig", "FitConfig", "SceneObject", "OBJECT_KINDS",
           "load_scene", "parse_scene", "trial_seed", "child_seed", "camera_poses", "make_object",
           "sample_objects", "draw_objects", "make_objects", "surely_not_visible", "geometry_visible", "ZNEAR"]

OBJECT_KINDS = ("superquadric", "box", "cylinder", "capsule", "cone", "mesh")
RENDERERS = ("osmesa", "egl", "polygon")
TRAJECTORIES = ("circle", "orbit", "waypoints")  # orbit, waypoints: sequences (sqsim.trajectory)
LAYOUTS = ("free", "ground")  # sqsim.layout
#: Minimum depth (metres) of every mesh vertex in every camera for a trial to be observable.
ZNEAR = 0.05
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
    # Sequences only (kind "orbit" or "waypoints"; sqsim.trajectory): None = not given.
    frames: int | None = None
    frame_rate_hz: float | None = None
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
    layout: str = "free"  # "free": positions uniform in a cube; "ground": on the floor (sqsim.layout)
    upright: bool = False  # ground layout: only the yaw (rz) is drawn, rx = ry = 0


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


@dataclass(frozen=True)
class FitConfig:
    polygon: str = "hull"
    penalty_riou: float = 1.0
    penalty_analytic: float = 100.0
    pose_sigma_deg: float = sqfit.FitOptions.pose_sigma_deg
    occlusion_aware: bool = sqfit.FitOptions.occlusion_aware


_CHECKS = {
    "experiment": {"name": _string, "seed": _int(0), "trials": _int(1), "chains": _strings},
    "camera": {"width": _int(1), "height": _int(1), "fx": _float(0, lo_open=True),
               "fy": _float(0, lo_open=True), "cx": _float(), "cy": _float()},
    "trajectory": {"kind": _choice(TRAJECTORIES), "radius": _float(0, lo_open=True), "views": _int(1),
                   "height": _float(), "arc_deg": _float(0, 360, lo_open=True), "look_at": _vector(3),
                   "start_deg": _float(), "frames": _int(2), "frame_rate_hz": _float(0, lo_open=True),
                   "radius_amplitude": _float(0), "height_amplitude": _float(0), "look_at_wander": _float(0),
                   "waypoints": _waypoints, "waypoints_file": _optional_path},
    "objects": {"count": _int(1), "kind": _choice(OBJECT_KINDS), "size": _range(0, lo_open=True),
                "position": _range(), "rotation": _range(), "shape": _range(lo=sqfit.constants.SHAPE_DOMAIN[0], hi=sqfit.constants.SHAPE_DOMAIN[1]),
                "path": _optional_path, "mesh_resolution": _int(2), "max_attempts": _int(1),
                "layout": _choice(LAYOUTS), "upright": _bool},
    "masks": {"renderer": _choice(RENDERERS), "samples": _int(3), "sampling": _choice(SAMPLING_METHODS),
              "min_area_px": _int(0), "cleanup": _bool, "max_cut_fraction": _float(0, 1, hi_open=True)},
    "noise": {"erosion_px": _int(0), "dilation_px": _int(0), "boundary_jitter_px": _float(0),
              "dropout": _float(0, 1, hi_open=True), "false_blobs": _int(0),
              "pose_rotation_deg": _float(0), "pose_translation_m": _float(0),
              "odometry_rotation_deg": _float(0), "odometry_translation_m": _float(0)},
    "fit": {"polygon": _choice(POLYGON_KINDS), "penalty_riou": _float(0, lo_open=True),
            "penalty_analytic": _float(0, lo_open=True), "pose_sigma_deg": _float(0),
            "occlusion_aware": _bool},
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
        """True when every noise parameter is zero."""
        return not any(asdict(self.noise).values())

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
            section, _, key = str(dotted).partition(".")
            if section not in _SECTIONS or key not in _CHECKS[section]:
                raise ValueError(f"{self.source}: unknown override key {dotted!r} "
                                 f"(use 'section.key', e.g. 'noise.dropout')")
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


def load_scene(path):
    """Read and validate a scene TOML file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    scene : Scene

    Raises
    ------
    OSError
        The file cannot be read.
    ValueError
        Malformed TOML, unknown section or key, or a bad value (message names file and key).
    """
    return parse_scene(read_toml(path), source=str(path))


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


def parse_scene(mapping, source="<string>"):
    """Validate a scene mapping (the parsed TOML) into a :class:`Scene`.

    Parameters
    ----------
    mapping : dict
        ``section -> {key -> value}``; missing sections and keys take their defaults.
    source : str
        File name used in error messages and to resolve a relative ``objects.path``.

    Returns
    -------
    scene : Scene
    """
    if not isinstance(mapping, dict):
        raise ValueError(f"{source}: a scene must be a mapping of sections, got {type(mapping).__name__}")
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
        scene = replace(scene, objects=replace(obj, path=str(path)))
    elif obj.path is not None:
        raise ValueError(f"{src}: objects.path is only used with objects.kind = \"mesh\", "
                         f"not {obj.kind!r}")
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
    its frames (``sqsim.trajectory.sequence_poses``).

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


# --- objects --------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SceneObject:
    """A ground-truth object of a trial.

    Attributes
    ----------
    id : int
        Instance id in the rendered images, 1-based.
    kind : str
        One of ``OBJECT_KINDS``.
    size, position, rotation : (3,) tuple of float
        Half-extents ``a`` (m), centre (m), Euler angles (rad, ``sqfit.superquadric`` convention).
    shape : (2,) tuple of float or None
        Shape exponents, superquadrics only.
    superquadric : sqfit.Superquadric or None
        Superquadrics only.
    mesh : trimesh.Trimesh
        World-frame mesh (every kind).
    path : str or None
        Source mesh file of the ``mesh`` kind.
    outward : bool
        The mesh is closed with outward-facing triangles (lets the renderer cull back faces);
        built-in kinds always are, a mesh file is checked when loaded.
    """

    id: int
    kind: str
    size: tuple
    position: tuple
    rotation: tuple
    shape: tuple | None
    superquadric: object
    mesh: object
    path: str | None = None
    outward: bool = True

    @property
    def pose(self):
        """``(4, 4) float``: ``T_world_object``."""
        T = np.eye(4)
        T[:3, :3] = euler_to_matrix(self.rotation)
        T[:3, 3] = self.position
        return T

    def to_dict(self):
        """JSON-friendly record; superquadrics carry ``params`` (the 11-vector, paper order)."""
        d = {"id": self.id, "kind": self.kind, "size": list(self.size), "position": list(self.position),
             "rotation": list(self.rotation)}
        if self.superquadric is not None:
            d["shape"] = list(self.shape)
            d["params"] = [float(x) for x in self.superquadric.to_vector()]
        if self.path is not None:
            d["path"] = self.path
        return d


def _unit_mesh_kind(kind, path=None):
    """Mesh of a mesh kind with half-extents 1, centred at the origin (local frame)."""
    import trimesh

    if kind == "box":
        return trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=1.0, height=2.0, sections=64)
    if kind == "capsule":
        mesh = trimesh.creation.capsule(height=2.0, radius=1.0, count=(32, 32))
        mesh.apply_scale((1.0, 1.0, 0.5))
        return mesh
    if kind == "cone":
        mesh = trimesh.creation.cone(radius=1.0, height=2.0, sections=64)
        mesh.apply_translation((0.0, 0.0, -1.0))
        return mesh
    mesh = _load_mesh(path)
    lo, hi = mesh.bounds
    mesh.apply_translation(-(lo + hi) / 2)
    mesh.apply_scale(2.0 / np.maximum(hi - lo, 1e-12))
    return mesh


_MESH_FILES = {}


def _load_mesh(path):
    import trimesh

    if path not in _MESH_FILES:
        try:
            mesh = trimesh.load(path, force="mesh")
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ValueError(f"cannot read mesh file {path}: {exc}") from None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ValueError(f"mesh file {path} holds no triangles")
        outward = bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)
        _MESH_FILES[path] = (mesh, outward)
    return _MESH_FILES[path][0].copy()


def make_object(oid, kind, size, shape, position, rotation, path=None, resolution=32):
    """Build a ground-truth object from its sampled values (see the module docstring per kind)."""
    if kind == "superquadric":
        sq = sqfit.Superquadric(size, shape, position, rotation)
        return SceneObject(oid, kind, sq.size, sq.position, sq.rotation, sq.shape, sq, to_mesh(sq, resolution))
    mesh = _unit_mesh_kind(kind, path)
    mesh.apply_scale(np.asarray(size, dtype=np.float64))
    T = np.eye(4)
    T[:3, :3] = euler_to_matrix(rotation)
    T[:3, 3] = position
    mesh.apply_transform(T)
    as_tuple = lambda v: tuple(float(x) for x in v)  # noqa: E731
    outward = _MESH_FILES[path][1] if kind == "mesh" else True
    return SceneObject(oid, kind, as_tuple(size), as_tuple(position), as_tuple(rotation), None, None,
                       mesh, path, outward)


def sample_objects(objects, rng):
    """Draw ``objects.count`` ground-truth objects.

    Parameters
    ----------
    objects : ObjectsConfig
    rng : numpy.random.Generator

    Returns
    -------
    objects : list of SceneObject
        Ids ``1 .. count``.
    """
    return make_objects(objects, draw_objects(objects, rng))


def draw_objects(objects, rng):
    """The random values of ``objects.count`` objects, without building them (no meshing).

    Returns
    -------
    draws : list of tuple
        ``(id, size (3,), shape (2,), position (3,), rotation (3,))`` per object, drawn in the
        order of the module docstring; :func:`make_objects` builds them.
    """
    out = []
    for oid in range(1, objects.count + 1):
        size = rng.uniform(*objects.size, 3)
        shape = rng.uniform(*objects.shape, 2)
        position = rng.uniform(*objects.position, 3)
        rotation = rng.uniform(*objects.rotation, 3)
        out.append((oid, size, shape, position, rotation))
    return out


def make_objects(objects, draws):
    """Build the objects of :func:`draw_objects` (``objects.kind``, meshed)."""
    return [make_object(oid, objects.kind, size, shape, position, rotation, objects.path, objects.mesh_resolution)
            for oid, size, shape, position, rotation in draws]


#: Margin (pixels and metres) by which a mesh anchor must fail :func:`geometry_visible`'s test
#: for :func:`surely_not_visible` to reject: far above rounding, so that it never rejects a draw
#: the full test would accept.
_ANCHOR_MARGIN = 1e-6


def surely_not_visible(objects, draws, cameras):
    """Whether a draw is certain to fail :func:`geometry_visible`, judged before meshing.

    Superquadrics only (other kinds: always ``False``): a few vertices of each mesh
    (``sqfit.superquadric.mesh_anchors``) are tested with the same rule, by a margin. ``True``
    implies ``geometry_visible`` of the built objects is ``False``, so re-drawing at once gives the
    same trials as building and testing every draw, only faster.

    Parameters
    ----------
    objects : ObjectsConfig
    draws : list
        From :func:`draw_objects`.
    cameras : list of sqfit.Camera

    Returns
    -------
    hidden : bool
    """
    if objects.kind != "superquadric":
        return False
    from sqfit.superquadric import mesh_anchors

    m = _ANCHOR_MARGIN
    points = np.concatenate([mesh_anchors(sqfit.Superquadric(size, shape, position, rotation), objects.mesh_resolution)
                             for _, size, shape, position, rotation in draws])
    for cam in cameras:  # sqfit.project's arithmetic, without its per-call checks
        k = cam.intrinsics
        local = (points - cam.center) @ cam.rotation
        depth = local[:, 2]
        if depth.min() <= ZNEAR - m:
            return True
        if depth.min() > ZNEAR + m:
            u = k.fx * local[:, 0] / depth + k.cx
            v = k.fy * local[:, 1] / depth + k.cy
            if min(u.min(), v.min()) < 1.0 - m or u.max() > k.width - 1.0 + m or v.max() > k.height - 1.0 + m:
                return True
    return False


def geometry_visible(objects, cameras, max_cut_fraction=0.0):
    """Whether every object is in front of every camera and inside every image.

    With ``max_cut_fraction == 0`` "inside" means strictly: no pixel of the first or last row or
    column can be covered, every projected vertex has ``1 <= u <= width - 1`` and
    ``1 <= v <= height - 1``. Above 0, at most that fraction of each object's projected area (see
    :func:`sqsim.visibility.cut_fractions`) may lie outside the image.

    Parameters
    ----------
    objects : list of SceneObject
    cameras : list of sqfit.Camera
    max_cut_fraction : float
        In [0, 1).

    Returns
    -------
    ok : bool
    """
    if max_cut_fraction > 0:
        from .visibility import cut_fractions

        cut = cut_fractions(objects, cameras, ZNEAR)
        return bool(np.all(np.isfinite(cut)) and cut.max() <= max_cut_fraction)
    for cam in cameras:
        k = cam.intrinsics
        for obj in objects:
            pixels, depth = sqfit.project(cam, np.asarray(obj.mesh.vertices))
            if depth.min() <= ZNEAR:
                return False
            if (pixels.min() < 1.0 or pixels[:, 0].max() > k.width - 1.0
                    or pixels[:, 1].max() > k.height - 1.0):
                return False
    return True
