"""Representation limits of ground-truth objects, cached per mesh and pose.

The limit of an object is the 3D IoU of the best superquadric its mesh allows
(:func:`sqfit.limit.best_superquadric`); a fit is then read as a fraction of it. A superquadric
ground truth has the limit 1 by definition (it is its own best superquadric) and is not searched.

The search runs on the object's mesh in its own frame, scaled by ``1 / max(size)``: the 3D IoU is
unchanged by a rigid motion and a uniform scaling, so the result is mapped back to the world by
the object's pose and scale. The cache key is a hash of that normalised mesh (vertices rounded to
:data:`KEY_DECIMALS` decimals, faces) and of the search settings: two objects share a limit when
their meshes are the same up to pose and uniform scale (a mesh file with ``proportions = "keep"``
in every trial; a household object in every chain of its trial). Limits are kept in memory for
the process and, with a ``directory``, as one small JSON file per key (a resumed or parallel run
reuses them). Every search uses the seed :data:`LIMIT_SEED`: the limit is a property of the mesh,
not of the trial.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import sqfit
from sqfit.geometry.superquadric import euler_to_matrix, matrix_to_euler
from sqfit.limit import LIMIT_POINTS, LIMIT_SHAPE_BOUNDS, LIMIT_STARTS, SEARCH_POINTS, best_superquadric

__all__ = ["LIMIT_SEED", "KEY_DECIMALS", "ObjectLimit", "LimitCache", "object_limit", "limit_key"]

#: Seed of every limit search.
LIMIT_SEED = 0
#: Decimals of the normalised (unit-size) vertices hashed into the cache key.
KEY_DECIMALS = 7
#: Bumped when the search changes, so that cached limits of an older search are not reused.
_SEARCH_VERSION = 1


@dataclass(frozen=True)
class ObjectLimit:
    """The representation limit of one ground-truth object.

    Attributes
    ----------
    superquadric : sqfit.Superquadric
        The best superquadric, world frame.
    iou : float
        Its 3D IoU with the object (exact mesh boolean); 1 for a superquadric ground truth.
    seconds : float
        Time of the search (0 when it came from the cache or the object is a superquadric).
    cached : bool
        Taken from the cache.
    """

    superquadric: object
    iou: float
    seconds: float
    cached: bool

    def to_dict(self):
        """JSON-friendly: ``iou``, ``params`` (11-vector, paper order), ``seconds``, ``cached``."""
        return {"iou": float(self.iou), "params": [float(v) for v in self.superquadric.to_vector()],
                "seconds": float(self.seconds), "cached": bool(self.cached)}


def _normalised(obj):
    """``(vertices (v, 3) float, faces (f, 3) int, scale)``: the object's mesh in its own frame / scale."""
    R = euler_to_matrix(obj.rotation)
    scale = float(max(obj.size))
    local = (np.asarray(obj.mesh.vertices) - np.asarray(obj.position)) @ R / scale
    return local, np.asarray(obj.mesh.faces, dtype=np.int64), scale


def limit_key(obj):
    """The cache key of an object's limit: a hex SHA-256 of its normalised mesh and the search settings."""
    local, faces, _ = _normalised(obj)
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(np.round(local, KEY_DECIMALS) + 0.0).tobytes())  # + 0.0: no -0.0
    digest.update(np.ascontiguousarray(faces).tobytes())
    digest.update(repr((_SEARCH_VERSION, LIMIT_SEED, LIMIT_POINTS, SEARCH_POINTS, LIMIT_STARTS,
                        tuple(LIMIT_SHAPE_BOUNDS))).encode())
    return digest.hexdigest()


class LimitCache:
    """Limits in the object frame by :func:`limit_key`: in memory, and optionally in a directory.

    Parameters
    ----------
    directory : str or Path, optional
        Where to keep ``<key>.json`` files (created when first written).
    """

    def __init__(self, directory=None):
        self.directory = None if directory is None else Path(directory)
        self._memory = {}
        self.hits = 0
        self.misses = 0

    def get(self, key):
        """``(params (11,) list, iou)`` in the normalised object frame, or ``None``."""
        if key not in self._memory and self.directory is not None:
            path = self.directory / f"{key}.json"
            if path.exists():
                try:
                    entry = json.loads(path.read_text())
                    self._memory[key] = (entry["params"], float(entry["iou"]))
                except (json.JSONDecodeError, KeyError, TypeError):
                    pass  # a file cut short by a kill: searched again and rewritten
        found = self._memory.get(key)
        if found is None:
            self.misses += 1
        else:
            self.hits += 1
        return found

    def put(self, key, params, iou):
        self._memory[key] = (list(params), float(iou))
        if self.directory is not None:
            self.directory.mkdir(parents=True, exist_ok=True)
            tmp = self.directory / f".{key}.{os.getpid()}.tmp"
            tmp.write_text(json.dumps({"params": list(params), "iou": float(iou)}))
            os.replace(tmp, self.directory / f"{key}.json")  # atomic: parallel workers may race


#: The cache of this process when none is given.
_PROCESS_CACHE = LimitCache()


def object_limit(obj, cache=None):
    """The representation limit of a ground-truth object (module docstring).

    Parameters
    ----------
    obj : sqsim.world.objects.SceneObject
    cache : LimitCache, optional
        Default: one cache per process, in memory.

    Returns
    -------
    limit : ObjectLimit
    """
    if obj.superquadric is not None:
        return ObjectLimit(obj.superquadric, 1.0, 0.0, False)
    import trimesh

    cache = _PROCESS_CACHE if cache is None else cache
    key = limit_key(obj)
    found = cache.get(key)
    cached, seconds = found is not None, 0.0
    if not cached:
        local, faces, _ = _normalised(obj)
        result = best_superquadric(trimesh.Trimesh(local, faces, process=False), rng=LIMIT_SEED)
        found = (result.superquadric.to_vector().tolist(), result.iou)
        cache.put(key, *found)
        seconds = result.seconds
    params, iou = found
    return ObjectLimit(_to_world(obj, sqfit.Superquadric.from_vector(params)), iou, seconds, cached)


def _to_world(obj, local):
    """Map a superquadric of the normalised object frame to the world (pose and scale of ``obj``)."""
    R = euler_to_matrix(obj.rotation)
    scale = float(max(obj.size))
    return sqfit.Superquadric(np.asarray(local.size) * scale, local.shape,
                              np.asarray(obj.position) + R @ (np.asarray(local.position) * scale),
                              matrix_to_euler(R @ local.rotation_matrix))
