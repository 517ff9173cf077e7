"""Ground-truth objects of a trial: meshes of every kind, seeded draws, and the observability tests.

Sampling (:func:`draw_objects`): a trial draws, per object and in this order, the half-axis
lengths ``a`` (3, uniform in ``objects.size``), the shape exponents (2, uniform in
``objects.shape``), the position (3, uniform in ``objects.position``) and the Euler angles (3,
uniform in ``objects.rotation``), from ``np.random.default_rng(trial_seed(seed, index))``, so a
trial never depends on other trials, worker count or order. The mesh kinds use the same draws:

- ``superquadric``: ``sqfit.Superquadric`` meshed with ``sqfit.geometry.superquadric.to_mesh``;
- ``box``: extents ``2 a`` (the box the superquadric tends to as ``e -> 0``);
- ``cylinder``: elliptic cylinder, semi-axes ``ax, ay``, length ``2 az`` along local z;
- ``capsule``: a capsule of radius 1 and total length 4, scaled by ``(ax, ay, az / 2)``: elliptic
  cross-section ``ax, ay``, total length ``2 az``;
- ``cone``: elliptic base ``ax, ay`` at local ``z = -az``, apex at ``z = +az``;
- ``mesh``: the file at ``objects.path`` (relative to the scene file; it must be watertight),
  centred on its bounding box;
- ``household``: a kind of ``objects.catalogue`` (default: all of :data:`sqsim.world.household.CATALOGUE`)
  drawn uniformly, built with seeded proportions (:func:`sqsim.world.household.build_household`),
  centred on its bounding box. After the Euler angles each object draws the kind (an index into
  the catalogue) and the builder's seed (an integer below 2**32), recorded as ``item`` and
  ``item_seed``.

``mesh`` and ``household`` objects keep their proportions by default (``objects.proportions =
"keep"``): they are scaled uniformly so that their longest half-extent is ``ax`` (``ay`` and
``az`` are drawn and ignored); ``"stretch"`` scales them per axis so that their bounding box is
``2 a``, like the other mesh kinds. The shape exponents are drawn for every kind (so kinds share
the random stream up to the household draws) and ignored by the mesh kinds. Cameras sit on a
circle (``trajectory``) and look at ``look_at`` with +z up.
A trial is observable when every object's mesh is in front of every camera (depth > ``ZNEAR``),
its projection lies inside every image without touching the border pixels (or, with
``masks.max_cut_fraction > 0``, at most that fraction of its projected area -- the convex hull of
its projected mesh vertices -- lies outside the image: truncated objects), and its visible
(rendered, possibly occluded) mask has at least ``masks.min_area_px`` pixels in every view;
otherwise the objects are drawn again (up to ``objects.max_attempts`` times) and the number of
re-draws is reported as ``resampled``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import sqfit
from sqfit.geometry.superquadric import euler_to_matrix, to_mesh

__all__ = ["ZNEAR", "PROPORTIONS", "SceneObject", "make_object", "sample_objects", "draw_objects", "draw_item",
           "make_objects", "proportions_of", "check_mesh_file", "surely_not_visible", "geometry_visible",
           "cut_fractions"]

#: Metres: every mesh vertex must be deeper than this in every camera.
ZNEAR = 0.05
#: Values of ``objects.proportions``; the first is the default of :data:`KEEPS_PROPORTIONS`.
PROPORTIONS = ("keep", "stretch")
#: Kinds whose natural proportions are kept by default (the others are defined by ``a`` alone).
KEEPS_PROPORTIONS = ("mesh", "household")
#: Household builder seeds are drawn below this.
_ITEM_SEEDS = 2**32


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
        Half-extents ``a`` (m), centre (m), Euler angles (rad, ``sqfit.geometry.superquadric`` convention).
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
    item, item_seed : str or None, int or None
        ``household`` only: the catalogue kind (e.g. ``"mug"``) and its builder's seed.
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
    item: str | None = None
    item_seed: int | None = None

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
        if self.item is not None:
            d["item"], d["item_seed"] = self.item, self.item_seed
        return d


def _unit_mesh_kind(kind):
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
    raise ValueError(f"unknown object kind {kind!r}")


def _natural_mesh(kind, path, item, item_seed):
    """Mesh of a ``mesh`` or ``household`` object in its own units, centred on its bounding box."""
    if kind == "household":
        from .household import build_household

        if item is None:
            raise ValueError("a household object needs its catalogue kind (item)")
        return build_household(item, np.random.default_rng(item_seed))
    mesh = _load_mesh(path)
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def _scale_natural(mesh, size, proportions):
    """Scale a centred mesh in place (module docstring); returns its half-extents ``(3,)``, metres."""
    half = np.maximum(mesh.extents / 2, 1e-12)
    if proportions == "keep":
        factor = size[0] / half.max()
        mesh.apply_scale(factor)
        return half * factor
    mesh.apply_scale(np.asarray(size) / half)
    return np.asarray(size, dtype=np.float64)


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


def check_mesh_file(path):
    """Read a mesh file (cached) and refuse it unless it is a closed surface.

    Raises
    ------
    ValueError
        Unreadable, no triangles, or not watertight (the message names the file).
    """
    mesh = _load_mesh(path)
    if not mesh.is_watertight:
        raise ValueError(f"mesh file {path} is not watertight (a 3D IoU against it needs a closed surface; "
                         "repair it, e.g. with trimesh.repair.fill_holes or manifold3d)")


def proportions_of(objects):
    """``"keep"`` or ``"stretch"``: ``objects.proportions``, or the default of ``objects.kind``."""
    if objects.proportions is not None:
        return objects.proportions
    return PROPORTIONS[0] if objects.kind in KEEPS_PROPORTIONS else "stretch"


def make_object(oid, kind, size, shape, position, rotation, path=None, resolution=32, proportions=None,
                item=None):
    """Build a ground-truth object from its sampled values (see the module docstring per kind).

    ``proportions`` (``"keep"`` or ``"stretch"``; default: the kind's) applies to ``mesh`` and
    ``household``; ``item`` is a household object's ``(kind, seed)`` (:func:`draw_item`).
    """
    if kind == "superquadric":
        sq = sqfit.Superquadric(size, shape, position, rotation)
        return SceneObject(oid, kind, sq.size, sq.position, sq.rotation, sq.shape, sq, to_mesh(sq, resolution))
    name, seed = item if item is not None else (None, None)
    if kind in KEEPS_PROPORTIONS:
        if proportions is None:
            proportions = PROPORTIONS[0]
        mesh = _natural_mesh(kind, path, name, seed)
        size = _scale_natural(mesh, np.asarray(size, dtype=np.float64), proportions)
    else:
        mesh = _unit_mesh_kind(kind)
        mesh.apply_scale(np.asarray(size, dtype=np.float64))
    T = np.eye(4)
    T[:3, :3] = euler_to_matrix(rotation)
    T[:3, 3] = position
    mesh.apply_transform(T)
    as_tuple = lambda v: tuple(float(x) for x in v)  # noqa: E731
    outward = _MESH_FILES[path][1] if kind == "mesh" else True
    return SceneObject(oid, kind, as_tuple(size), as_tuple(position), as_tuple(rotation), None, None,
                       mesh, path, outward, name, None if seed is None else int(seed))


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
        ``(id, size (3,), shape (2,), position (3,), rotation (3,), item)`` per object, drawn in
        the order of the module docstring (``item``: :func:`draw_item`); :func:`make_objects`
        builds them.
    """
    out = []
    for oid in range(1, objects.count + 1):
        size = rng.uniform(*objects.size, 3)
        shape = rng.uniform(*objects.shape, 2)
        position = rng.uniform(*objects.position, 3)
        rotation = rng.uniform(*objects.rotation, 3)
        out.append((oid, size, shape, position, rotation, draw_item(objects, rng)))
    return out


def draw_item(objects, rng):
    """A household object's ``(kind, builder seed)``, drawn from ``rng``; ``None`` (no draw) for
    the other kinds."""
    if objects.kind != "household":
        return None
    from .household import CATALOGUE

    names = objects.catalogue if objects.catalogue is not None else tuple(CATALOGUE)
    return names[int(rng.integers(len(names)))], int(rng.integers(_ITEM_SEEDS))


def make_objects(objects, draws):
    """Build the objects of :func:`draw_objects` (``objects.kind``, meshed)."""
    return [make_object(oid, objects.kind, size, shape, position, rotation, objects.path, objects.mesh_resolution,
                        proportions_of(objects), item)
            for oid, size, shape, position, rotation, item in draws]


#: Margin (pixels and metres) by which a mesh anchor must fail :func:`geometry_visible`'s test
#: for :func:`surely_not_visible` to reject: far above rounding, so that it never rejects a draw
#: the full test would accept.
_ANCHOR_MARGIN = 1e-6


def surely_not_visible(objects, draws, cameras):
    """Whether a draw is certain to fail :func:`geometry_visible`, judged before meshing.

    Superquadrics only (other kinds: always ``False``): a few vertices of each mesh
    (``sqfit.geometry.superquadric.mesh_anchors``) are tested with the same rule, by a margin. ``True``
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
    from sqfit.geometry.superquadric import mesh_anchors

    m = _ANCHOR_MARGIN
    points = np.concatenate([mesh_anchors(sqfit.Superquadric(size, shape, position, rotation), objects.mesh_resolution)
                             for _, size, shape, position, rotation, _item in draws])
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
    :func:`sqsim.imaging.visibility.cut_fractions`) may lie outside the image.

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


def cut_fractions(objects, cameras, znear):
    """Fraction of each object's projected area outside each image: ``1 - |hull & image| / |hull|``
    of the convex hull of its projected mesh vertices (the cut the scene's ``masks.max_cut_fraction`` bounds).

    Parameters
    ----------
    objects : list of SceneObject
    cameras : list of sqfit.Camera
    znear : float
        Metres: an object with a vertex at depth <= ``znear`` gets ``inf``.

    Returns
    -------
    cut : (count, v) float
        In [0, 1], or ``inf`` where the object is not in front of the camera.
    """
    from scipy.spatial import ConvexHull, QhullError

    from sqfit.geometry.polygon import polygon_area, polygon_iou

    out = np.zeros((len(objects), len(cameras)))
    for j, cam in enumerate(cameras):
        k = cam.intrinsics
        image = np.array([[0.0, 0.0], [k.width, 0.0], [k.width, k.height], [0.0, k.height]])
        for i, obj in enumerate(objects):
            pixels, depth = sqfit.project(cam, np.asarray(obj.mesh.vertices))
            if depth.min() <= znear:
                out[i, j] = np.inf
                continue
            if (pixels.min(axis=0) >= 0).all() and pixels[:, 0].max() <= k.width and pixels[:, 1].max() <= k.height:
                continue  # the hull lies inside the image: nothing cut (most objects; skips Qhull)
            try:
                hull = pixels[ConvexHull(pixels).vertices]
            except (QhullError, ValueError):
                continue  # degenerate projection: no area to cut
            area = abs(polygon_area(hull))
            if area <= 0:
                continue
            # |hull & image| from the IoU: inter = iou (|A| + |B|) / (1 + iou).
            iou = polygon_iou(hull, image)
            cut = 1.0 - iou * (area + k.width * k.height) / (1.0 + iou) / area
            out[i, j] = float(np.clip(cut, 0.0, 1.0)) if cut > 1e-9 else 0.0  # rounding of the IoU
    return out
