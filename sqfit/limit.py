"""The representation limit: the superquadric of highest 3D IoU with a watertight mesh.

A ground truth that is not a superquadric (a mug, a chair, a scanned figure) cannot be fitted
exactly by any superquadric; :func:`best_superquadric` finds the one that comes closest in 3D
IoU, so a fit can be scored against what a single superquadric can express at all.

Method (all seeded by ``rng``):

1. **Interior sample** (:func:`interior_points`): one uniform random point per cell of a regular
   grid over the mesh's bounding box (cells of ``(|M| / points) ** (1/3)``), kept when inside the
   mesh by the parity of the crossings of a +z ray from it: about ``points`` points uniform in
   the mesh (stratified). The intersection volume of a superquadric and the mesh is then
   ``|M| * (fraction of the sample inside the superquadric)``, with the superquadric's volume in
   closed form, so each evaluation of the IoU is one ``log F`` test of the sample. (Cell centres
   instead of random points let the search shrink the superquadric by half a cell for free.)
2. **Global search**: starts in several frames: the whole mesh in the principal axes of the
   interior sample and in trimesh's minimum-volume oriented bounding box, and the parts found by
   k-means of the sample (2 to :data:`PART_CLUSTERS` clusters) in their own principal axes; in
   each, every choice of the frame axis that becomes the superquadric's z axis (``e1`` acts on z,
   ``e2`` on the xy section), the half-extents scaled by :data:`START_SCALES` and the shape
   exponents on the grid :data:`START_SHAPES` x :data:`START_SHAPES`; all scored on a
   ``search_points`` subset of the sample.
3. **Local refinement**: Nelder-Mead (scipy) on the 11 parameters (log sizes, log shape
   exponents, centre, a rotation vector composed with the start's rotation), by successive
   halving: the best start of every (frame, z axis) pair for :data:`SCREEN_EVALUATIONS`
   evaluations on the subset, the best ``starts`` of those for :data:`SEARCH_EVALUATIONS` more,
   the best :data:`FINAL_STARTS` for :data:`FINAL_EVALUATIONS` on the whole sample.
4. **Report**: the accurate IoU of the refined candidates by an exact mesh boolean
   (:func:`sqfit.metrics.iou_3d_mesh`); the best one is the limit.

Steps 2-3 are :func:`search_volume`, which takes any uniform sample of a solid's inside and its
volume (the mesh path adds the oriented bounding box as a frame and sizes the whole-mesh starts on
the vertices); ``scripts/hull_volume.py`` runs it on a carved visual hull.

The search is local and seeded, so the limit it reports is a lower bound of the true one: on
nine kinds of the household catalogue (two objects each) a search four times as long
(``starts=24``, 600 / 2000 evaluations, 4 final candidates, 4 parts, one more start scale) found
IoUs higher by 0.10 on chairs, by up to 0.04 on laptops and tables, by at most 0.01 on mugs,
bottles, bowls, monitors, lamps and toys.

Shape exponents are searched in ``constants.SILHOUETTE_SHAPE_BOUNDS`` (the widest range the
fitter itself produces), sizes are free (> 0). The sample's parity labels need no spatial index:
``trimesh.Trimesh.contains`` (ray tests through rtree) took 34 s for 64 000 points on a
1 700-face mug here, the binned ray parity takes milliseconds. A ray that passes exactly through
a mesh edge or vertex (probability 0 for random points) could be labelled wrongly; edges shared
by two triangles are tested with bit-identical arithmetic on both sides, so no ray is counted
twice or missed by rounding.

>>> import numpy as np
>>> from sqfit.geometry.superquadric import Superquadric, to_mesh
>>> sq = Superquadric((1.0, 0.6, 0.4), (0.5, 1.2))
>>> limit = best_superquadric(to_mesh(sq, 32), rng=0)
>>> bool(limit.iou > 0.98)
True
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from . import constants as C
from ._checks import check_shape
from .geometry.superquadric import Superquadric, log_implicit_unit, matrix_to_euler, unit_volume
from .metrics import iou_3d_mesh

__all__ = ["LIMIT_POINTS", "LIMIT_SHAPE_BOUNDS", "SEARCH_POINTS", "LIMIT_STARTS", "RepresentationLimit", "best_superquadric",
           "interior_points", "search_volume"]

#: Interior sample of the refinement (points inside the mesh, about).
LIMIT_POINTS = 2**13
#: Subset of the interior sample scored in the global search and the first refinement.
SEARCH_POINTS = 2**11
#: (frame, z axis) pairs refined at length on the subset (after a short refinement of all).
LIMIT_STARTS = 6
#: Candidates refined again on the whole sample and scored by the mesh boolean.
FINAL_STARTS = 2
#: Largest number of parts (k-means clusters of the interior sample) whose frames are starts.
PART_CLUSTERS = 3
#: Fewest sample points of a part that gives a start.
MIN_PART_POINTS = 64
#: Shape exponents of the start grid (``e1`` and ``e2`` each), unitless.
START_SHAPES = (0.1, 0.4, 0.8, 1.2)
#: Factors on the mesh's half-extents of the starts (a superquadric inside the box of a shape
#: with parts, e.g. a mug's body without its handle, starts from the smaller ones).
START_SCALES = (1.0, 0.85, 0.7)
#: Shape exponents searched, unitless.
LIMIT_SHAPE_BOUNDS = C.SILHOUETTE_SHAPE_BOUNDS
#: Nelder-Mead evaluations per refinement: short and long on the subset, then on the whole sample.
SCREEN_EVALUATIONS = 250
SEARCH_EVALUATIONS = 750
FINAL_EVALUATIONS = 600
#: Initial simplex steps: log size, log shape exponents (unitless), centre (fraction of the mesh's
#: largest half-extent), rotation vector (radians); the final refinement starts at half of them.
SIMPLEX_STEPS = (0.1, 0.3, 0.05, 0.1)
#: Mesh resolution of the superquadric in the final mesh boolean (``to_mesh``).
BOOLEAN_RESOLUTION = 48


@dataclass(frozen=True)
class RepresentationLimit:
    """The best superquadric of a mesh (:func:`best_superquadric`).

    Attributes
    ----------
    superquadric : Superquadric
        In the mesh's coordinates.
    iou : float
        Its 3D IoU with the mesh, exact mesh boolean (``sqfit.metrics.iou_3d_mesh``).
    iou_estimate : float
        The same on the interior sample (what the search maximised).
    evaluations : int
        IoU evaluations of the search.
    seconds : float
        Wall time.
    """

    superquadric: Superquadric
    iou: float
    iou_estimate: float
    evaluations: int
    seconds: float


# --------------------------------------------------------------------------- interior sample

def _mesh_arrays(mesh, name="mesh"):
    """``(vertices (v, 3) float, faces (f, 3) int)`` of a closed mesh with a positive volume."""
    if not hasattr(mesh, "vertices") or not hasattr(mesh, "faces"):
        raise ValueError(f"{name} must be a triangle mesh (trimesh.Trimesh), got {type(mesh).__name__}")
    vertices = check_shape(mesh.vertices, (None, 3), f"{name}.vertices")
    faces = check_shape(mesh.faces, (None, 3), f"{name}.faces", dtype=np.int64)
    if len(faces) == 0 or faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"{name}.faces must index {name}.vertices and be non-empty")
    if not getattr(mesh, "is_watertight", False) or not mesh.volume > 0:
        raise ValueError(f"{name} must be watertight with outward faces (positive volume); "
                         "repair it first, e.g. with trimesh.repair.fill_holes or manifold3d")
    return vertices, faces


def _edge_values(px, py, tri_xy, faces):
    """Signed edge functions of points against the triangles' projected edges.

    Each edge is evaluated from its lower-indexed vertex, so the two triangles that share it
    compute bit-identical values (negated by ``sign``), and a point is never on both sides.

    Returns
    -------
    edges : (m, 3) float
        Edge ``k`` joins corners ``k + 1`` and ``k + 2`` (opposite corner ``k``); all three have
        the sign of the triangle's projected area when the point is inside it.
    """
    out = np.empty((len(px), 3))
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        swap = faces[:, i] > faces[:, j]
        u = np.where(swap[:, None], tri_xy[:, j], tri_xy[:, i])
        w = np.where(swap[:, None], tri_xy[:, i], tri_xy[:, j])
        value = (w[:, 0] - u[:, 0]) * (py - u[:, 1]) - (w[:, 1] - u[:, 1]) * (px - u[:, 0])
        out[:, k] = np.where(swap, -value, value)
    return out


def _ray_parity(vertices, faces, points, cells, origin, cell):
    """Whether points lie inside a closed mesh: the parity of the crossings of a +z ray from each.

    Parameters
    ----------
    vertices, faces : (v, 3) float, (f, 3) int
    points : (nx, ny, nz, 3) float
        Points binned by the cell of a regular grid they lie in (``points[i, j, k]`` in cell
        ``(i, j, k)``).
    cells : (2,) int
        ``(nx, ny)``.
    origin : (3,) float
        Lower corner of the grid; cells are cubes of ``cell`` metres.

    Returns
    -------
    inside : (nx, ny, nz) bool
    """
    nx, ny = cells
    nz, z0 = points.shape[2], origin[2]
    tri = vertices[faces]  # (f, 3 corners, 3)
    lo = [np.clip(np.floor((tri[:, :, k].min(axis=1) - origin[k]) / cell).astype(np.int64), 0, n)
          for k, n in ((0, nx), (1, ny))]
    hi = [np.clip(np.floor((tri[:, :, k].max(axis=1) - origin[k]) / cell).astype(np.int64) + 1, 0, n)
          for k, n in ((0, nx), (1, ny))]
    ni, nj = hi[0] - lo[0], hi[1] - lo[1]
    # Points of a column above a triangle's highest cell cannot cross it: only the layers below.
    layers = np.clip(np.floor((tri[:, :, 2].max(axis=1) - z0) / cell).astype(np.int64) + 1, 0, nz)
    counts = ni * nj * layers
    owner = np.repeat(np.arange(len(tri)), counts)  # one row per (triangle, point below it in its xy box)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
    cell_k, point_k = k // layers[owner], k % layers[owner]
    ci, cj = lo[0][owner] + cell_k // nj[owner], lo[1][owner] + cell_k % nj[owner]
    p = points[ci, cj, point_k]
    edges = _edge_values(p[:, 0], p[:, 1], tri[owner, :, :2], faces[owner])
    total = edges.sum(axis=1)
    hit = (total != 0) & (np.all(edges > 0, axis=1) | np.all(edges < 0, axis=1))
    weights = edges[hit] / total[hit, None]
    above = np.einsum("mk,mk->m", weights, tri[owner[hit], :, 2]) > p[hit, 2]
    index = (ci[hit] * ny + cj[hit]) * nz + point_k[hit]
    crossings = np.bincount(index[above], minlength=nx * ny * nz)
    return (crossings % 2 == 1).reshape(nx, ny, nz)


def interior_points(mesh, n=LIMIT_POINTS, rng=None):
    """About ``n`` points uniformly distributed inside a closed mesh (a stratified sample).

    The mesh's bounding box is cut into cubic cells of ``(|M| / n) ** (1/3)`` metres; one point
    per cell, uniform in its cell; those inside the mesh are kept. Uniform in the mesh, so the
    fraction of them inside another solid estimates the fraction of the mesh's volume it covers
    without bias (and, stratified, with a smaller error than independent points).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight, positive volume.
    n : int
        Wanted number of interior points (>= 64).
    rng : numpy.random.Generator or int, optional

    Returns
    -------
    points : (m, 3) float
        ``m`` close to ``n``, metres, in the mesh's coordinates.
    """
    vertices, faces = _mesh_arrays(mesh)
    if int(n) != n or n < 64:
        raise ValueError(f"n must be an integer >= 64, got {n!r}")
    rng = np.random.default_rng(rng)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    cell = (float(mesh.volume) / n) ** (1.0 / 3.0)
    shape = tuple(max(int(np.ceil(v)), 1) for v in (hi - lo) / cell)
    index = np.stack(np.meshgrid(*(np.arange(m) for m in shape), indexing="ij"), axis=-1)
    points = lo + cell * (index + rng.uniform(0.0, 1.0, (*shape, 3)))
    inside = _ray_parity(vertices, faces, points, shape[:2], lo, cell) & np.all(points < hi, axis=-1)
    return points[inside]


# --------------------------------------------------------------------------- objective

def _rotvec_matrix(w):
    """Rodrigues: ``(3,)`` rotation vector -> ``(3, 3)`` matrix (scipy's ``from_rotvec``, without
    its per-call overhead in the search's inner loop)."""
    angle = float(np.sqrt(w @ w))
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


class _Objective:
    """Estimated IoU of superquadrics and a mesh on a fixed interior sample.

    A candidate is a start rotation ``R0 (3, 3)`` and a vector ``z (11,)``: log sizes (over
    ``scale``, metres), log shape exponents (clipped to :data:`LIMIT_SHAPE_BOUNDS`), centre
    (metres) and a rotation vector applied in the start's frame, ``R = R0 @ exp(z[8:])``.
    """

    def __init__(self, points, mesh_volume, scale):
        self.points = points
        self.mesh_volume = float(mesh_volume)
        self.scale = float(scale)
        self.evaluations = 0

    def _decode(self, R0, z):
        size = self.scale * np.exp(np.clip(z[0:3], -30.0, 30.0))
        return size, np.clip(np.exp(z[3:5]), *LIMIT_SHAPE_BOUNDS), R0 @ _rotvec_matrix(z[8:11])

    def superquadric(self, R0, z):
        size, shape, R = self._decode(R0, z)
        return Superquadric(size, shape, z[5:8], matrix_to_euler(R))

    def iou(self, R0, z, points=None):
        self.evaluations += 1
        points = self.points if points is None else points
        size, shape, R = self._decode(R0, z)
        inside = log_implicit_unit(((points - z[5:8]) @ R) / size, shape) <= 0.0
        inter = self.mesh_volume * np.count_nonzero(inside) / len(points)
        return inter / (np.prod(size) * unit_volume(shape) + self.mesh_volume - inter)


def _frame_of(R, vertices):
    """``(R, centre (3,), half-extents (3,))`` of points in the frame ``R`` (made right-handed)."""
    if np.linalg.det(R) < 0:
        R = R * np.array([1.0, 1.0, -1.0])
    local = vertices @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    return R, R @ ((lo + hi) / 2), (hi - lo) / 2


def _principal_axes(points):
    centred = points - points.mean(axis=0)
    return np.linalg.eigh(centred.T @ centred)[1]


def _frames(points, extent, rotations, rng):
    """Candidate frames ``(R (3, 3), centre (3,), half-extents (3,))``.

    The whole volume in the principal axes of its sample ``points`` and in each of ``rotations``
    (boxes measured on ``extent``), then the parts of the sample found by k-means (k = 2 ..
    :data:`PART_CLUSTERS`), each in its own principal axes: the best superquadric of a shape with
    parts often covers one part (a chair's seat and back, a lamp's shade) rather than the whole.
    """
    from scipy.cluster.vq import kmeans2

    frames = [_frame_of(R, extent) for R in (_principal_axes(points), *rotations)]
    for k in range(2, PART_CLUSTERS + 1):
        _, labels = kmeans2(points, k, minit="++", seed=rng)
        for part in range(k):
            members = points[labels == part]
            if len(members) >= MIN_PART_POINTS:
                frames.append(_frame_of(_principal_axes(members), members))
    return frames


def _z_axis_choices(R, half):
    """The frame with each of its axes as z in turn (cyclic, so ``det`` stays +1)."""
    for k in range(3):
        order = [(k + 1) % 3, (k + 2) % 3, k]
        yield k, R[:, order], half[order]


def _starts(objective, frames, points):
    """Score every start on ``points``; returns ``[(estimate, key, R0, z)]`` best first."""
    scored = []
    for f, (R, centre, half) in enumerate(frames):
        for k, R0, h in _z_axis_choices(R, half):
            for s in START_SCALES:
                for e1 in START_SHAPES:
                    for e2 in START_SHAPES:
                        z = np.concatenate([np.log(np.maximum(s * h, 1e-9) / objective.scale), np.log([e1, e2]),
                                            centre, np.zeros(3)])
                        scored.append((objective.iou(R0, z, points), (f, k), R0, z))
    scored.sort(key=lambda t: -t[0])
    return scored


def _refine(objective, R0, z, points, evaluations, step):
    steps = np.repeat(np.asarray(SIMPLEX_STEPS) * step, (3, 2, 3, 3))
    steps[5:8] *= objective.scale
    simplex = np.vstack([z, z + np.diag(steps)])
    res = minimize(lambda x: -objective.iou(R0, x, points), z, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "maxfev": evaluations, "adaptive": True,
                            "xatol": 1e-4, "fatol": 1e-5})
    return -float(res.fun), res.x


def search_volume(sample, volume, rng=None, *, extent=None, rotations=(), search_points=SEARCH_POINTS,
                  starts=LIMIT_STARTS, final=FINAL_STARTS):
    """Superquadrics of highest estimated 3D IoU with a solid given by a uniform sample of its inside.

    Steps 2-3 of the module docstring, for any solid: a mesh (:func:`best_superquadric`), a
    carved visual hull (``scripts/hull_volume.py``).

    Parameters
    ----------
    sample : (n, 3) float
        Points uniformly distributed inside the solid (n >= 64), metres.
    volume : float
        The solid's volume, cubic metres (> 0): the intersection with a superquadric is
        ``volume * (fraction of the sample inside it)``.
    rng : numpy.random.Generator or int, optional
        Seeds the search subset and the k-means of the parts.
    extent : (m, 3) float, optional
        Points whose bounding boxes size the whole-solid starts (a mesh's vertices); default
        ``sample``.
    rotations : sequence of (3, 3) float
        More whole-solid frames besides the sample's principal axes (columns: the axes).
    search_points : int
        Subset of the sample for the global search (>= 64, at most ``n``).
    starts : int
        (frame, z axis) pairs refined at length (1 to 24).
    final : int
        Candidates refined on the whole sample and returned (>= 1).

    Returns
    -------
    candidates : list of (float, Superquadric)
        ``final`` candidates (fewer if the starts are fewer) with their estimated IoU on the whole
        sample, best first.
    evaluations : int
        IoU evaluations of the search.
    """
    sample = check_shape(sample, (None, 3), "sample")
    if len(sample) < 64:
        raise ValueError(f"sample must hold >= 64 points, got {len(sample)}")
    if not np.isfinite(volume) or volume <= 0:
        raise ValueError(f"volume must be a positive number of cubic metres, got {volume!r}")
    extent = sample if extent is None else check_shape(extent, (None, 3), "extent")
    if int(search_points) != search_points or search_points < 64:
        raise ValueError(f"search_points must be an integer >= 64, got {search_points!r}")
    if int(starts) != starts or not 1 <= starts <= 24:
        raise ValueError(f"starts must be an integer in [1, 24], got {starts!r}")
    if int(final) != final or final < 1:
        raise ValueError(f"final must be an integer >= 1, got {final!r}")
    rng = np.random.default_rng(rng)
    subset = sample[rng.choice(len(sample), min(int(search_points), len(sample)), replace=False)]
    frames = _frames(sample, extent, rotations, rng)
    objective = _Objective(sample, volume, max(h.max() for _, _, h in frames))

    best_per_pair = {}
    for estimate, key, R0, z in _starts(objective, frames, subset):
        best_per_pair.setdefault(key, (estimate, R0, z))
    # Successive halving: every (frame, z axis) pair briefly, the best ``starts`` longer, the best
    # ``final`` on the whole sample.
    pool = [(estimate, R0, z) for estimate, R0, z in best_per_pair.values()]
    for keep, evaluations, step in ((len(pool), SCREEN_EVALUATIONS, 1.0), (int(starts), SEARCH_EVALUATIONS, 0.5)):
        pool = sorted(pool, key=lambda t: -t[0])[:keep]
        pool = [(*_refine(objective, R0, z, subset, evaluations, step), R0) for _, R0, z in pool]
        pool = [(estimate, R0, z) for estimate, z, R0 in pool]
    pool.sort(key=lambda t: -t[0])
    candidates = []
    for _, R0, z in pool[:int(final)]:
        estimate, z = _refine(objective, R0, z, None, FINAL_EVALUATIONS, 0.25)
        candidates.append((float(estimate), objective.superquadric(R0, z)))
    candidates.sort(key=lambda t: -t[0])
    return candidates, objective.evaluations


def best_superquadric(mesh, rng=None, *, points=LIMIT_POINTS, search_points=SEARCH_POINTS, starts=LIMIT_STARTS):
    """The superquadric of highest 3D IoU with a watertight mesh (module docstring: method).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight, outward faces, metres (any frame).
    rng : numpy.random.Generator or int, optional
        Seeds the interior sample and its subset; the same seed gives the same answer.
    points : int
        Interior sample of the refinement (>= 64).
    search_points : int
        Subset of it for the global search (>= 64, at most ``points``).
    starts : int
        (frame, z axis) pairs refined at length (1 to 24).

    Returns
    -------
    limit : RepresentationLimit
    """
    t0 = time.perf_counter()
    vertices, _ = _mesh_arrays(mesh)
    if int(search_points) != search_points or not 64 <= search_points <= points:
        raise ValueError(f"search_points must be an integer in [64, points={points}], got {search_points!r}")
    if int(starts) != starts or not 1 <= starts <= 24:
        raise ValueError(f"starts must be an integer in [1, 24], got {starts!r}")
    rng = np.random.default_rng(rng)
    sample = interior_points(mesh, points, rng)
    if len(sample) < 64:
        raise ValueError(f"mesh has too little volume for an interior sample ({len(sample)} points)")
    obb = np.asarray(mesh.bounding_box_oriented.primitive.transform)[:3, :3]
    found, evaluations = search_volume(sample, mesh.volume, rng, extent=vertices, rotations=(obb,),
                                       search_points=search_points, starts=starts)
    candidates = [(iou_3d_mesh(sq, mesh, BOOLEAN_RESOLUTION), estimate, sq) for estimate, sq in found]
    iou, estimate, sq = max(candidates, key=lambda t: (t[0], t[1]))
    return RepresentationLimit(sq, float(iou), float(estimate), evaluations, time.perf_counter() - t0)
