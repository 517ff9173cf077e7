"""Object layouts of a scene: where the sampled objects go (``[objects] layout``).

``free`` (default, the paper's)
    :func:`sqsim.world.objects.sample_objects`: every position coordinate uniform in
    ``objects.position``; objects may interpenetrate.
``ground``
    A room floor: the plane ``z = 0`` (world +z up) over the square ``objects.position`` x
    ``objects.position``. Each object draws, in the same order as ``free`` (so kinds and layouts
    share the random stream), its size, shape exponents, position and Euler angles (with
    ``objects.upright = true`` the x and y angles are set to 0 after drawing: the object stands
    on the floor turned only about the vertical; a household object then draws its kind and
    seed, ``sqsim.world.objects.draw_item``). It is then lifted so that its lowest mesh vertex
    touches the floor (it rests on the plane; the drawn z is ignored). Objects do not
    interpenetrate: each one's footprint disc (centre = its position in the floor plane, radius =
    the largest horizontal distance of a mesh vertex from it, plus :data:`LAYOUT_GAP_M` / 2) must
    miss every disc placed before; a position that overlaps is drawn again (x, y only) up to
    :data:`PLACEMENT_TRIES` times, after which the whole draw fails (``None``) and the caller
    draws the scene again. Disjoint footprint discs imply disjoint objects (each object lies in
    the vertical cylinder over its disc). The floor itself is not rendered.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

import sqfit

from .objects import draw_item, make_object, proportions_of, sample_objects

__all__ = ["place_objects", "ground_layout", "footprint_radius", "check_layout", "LAYOUT_GAP_M",
           "PLACEMENT_TRIES"]

#: Minimum horizontal clearance between the footprints of two objects on the floor, metres.
LAYOUT_GAP_M = 0.05
#: Positions drawn for one object before the draw of a ``ground`` scene fails.
PLACEMENT_TRIES = 200


def place_objects(objects, rng):
    """Draw the objects of a scene with its layout.

    Parameters
    ----------
    objects : sqsim.world.scene.ObjectsConfig
    rng : numpy.random.Generator

    Returns
    -------
    objects : list of sqsim.world.objects.SceneObject or None
        ``None`` when the ``ground`` layout could not place every object (draw again).
    """
    if objects.layout == "ground":
        return ground_layout(objects, rng)
    return sample_objects(objects, rng)


def footprint_radius(obj):
    """``float``: largest horizontal distance (m) of a vertex of ``obj.mesh`` from ``obj.position``."""
    xy = np.asarray(obj.mesh.vertices)[:, :2] - np.asarray(obj.position)[:2]
    return float(np.sqrt((xy ** 2).sum(axis=1).max()))


def ground_layout(objects, rng):
    """The ``ground`` layout (module docstring).

    Returns
    -------
    objects : list of sqsim.world.objects.SceneObject or None
    """
    placed, discs = [], []
    for oid in range(1, objects.count + 1):
        size = rng.uniform(*objects.size, 3)
        shape = rng.uniform(*objects.shape, 2)
        xy = rng.uniform(*objects.position, 3)[:2]
        rotation = rng.uniform(*objects.rotation, 3)
        if objects.upright:
            rotation[:2] = 0.0
        item = draw_item(objects, rng)
        at_origin = make_object(oid, objects.kind, size, shape, np.zeros(3), rotation, objects.path,
                                objects.mesh_resolution, proportions_of(objects), item)
        radius = footprint_radius(at_origin) + LAYOUT_GAP_M / 2
        for _ in range(PLACEMENT_TRIES):
            if all(np.hypot(*(xy - c)) >= radius + r for c, r in discs):
                break
            xy = rng.uniform(*objects.position, 2)
        else:
            return None
        discs.append((xy, radius))
        position = np.array([xy[0], xy[1], -float(np.asarray(at_origin.mesh.vertices)[:, 2].min())])
        placed.append(_moved(at_origin, position))
    return placed


def _moved(obj, position):
    """``obj`` (built at the origin) translated to ``position``, mesh and superquadric alike."""
    mesh = obj.mesh.copy()
    mesh.apply_translation(position)
    sq = None
    if obj.superquadric is not None:
        sq = sqfit.Superquadric(obj.size, obj.shape, position, obj.rotation)
    return replace(obj, position=tuple(float(x) for x in position), superquadric=sq, mesh=mesh)


def check_layout(scene):
    """Reject a ``ground`` scene whose objects cannot fit on its floor, naming the keys.

    Every object's footprint radius is at least ``objects.size[0]`` (a superquadric or mesh kind
    reaches ``a`` along each of its axes), so ``count`` discs need centres ``2 size[0]`` apart in
    a square of side ``position[1] - position[0]``; more than ``(side / (2 size[0]) + 1)^2`` of
    them never fit. Objects that keep their proportions (``sqsim.world.objects.proportions_of``) may be
    narrower than ``size[0]``: no bound is checked for them (a floor too small then fails when
    the objects are drawn).
    """
    obj = scene.objects
    if obj.layout != "ground":
        if obj.upright:
            raise ValueError(f"{scene.source}: objects.upright is only used with objects.layout = \"ground\"")
        return scene
    if proportions_of(obj) == "keep":
        return scene
    side = obj.position[1] - obj.position[0]
    spacing = 2 * obj.size[0] + LAYOUT_GAP_M
    most = (math.floor(side / spacing) + 1) ** 2
    if obj.count > most:
        raise ValueError(f"{scene.source}: objects.count = {obj.count} objects of size >= {obj.size[0]} m "
                         f"cannot rest side by side on the objects.position floor [{obj.position[0]}, "
                         f"{obj.position[1]}]^2 (at most {most}); enlarge objects.position or reduce "
                         "objects.count / objects.size")
    return scene
