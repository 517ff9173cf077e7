"""Parallax: the angle two camera centres subtend at a triangulated mask centroid, from the masks alone
(no landmark needed). It decides when a landmark's first frames are enough for its initial fit
(:func:`ready_to_initialise`, :mod:`sqfit.graph.growth`) and paces iSAM2's rebuilds
(:mod:`sqfit.graph.schedule`)."""

from __future__ import annotations

import numpy as np

from ..geometry.camera import bearings

__all__ = ["parallax_deg", "centroid_bearing", "rays_parallax_deg", "ready_to_initialise"]


def parallax_deg(first, last, T_first, T_last):
    """Angle at the triangulated mask centroid between two cameras' centres, degrees (0 when the
    centroid rays do not meet in front of both cameras).

    Parameters
    ----------
    first, last : Observation
    T_first, T_last : (4, 4) float
        The frames' ``T_world_camera``.
    """
    d = [T[:3, :3] @ centroid_bearing(o) for o, T in ((first, T_first), (last, T_last))]
    return float(rays_parallax_deg(T_first[:3, 3], T_last[:3, 3], d[0][None], d[1][None])[0])


def centroid_bearing(observation):
    """The bearing of ``observation``'s mask centroid in its camera frame, at unit depth, (3,)."""
    return bearings(observation.camera, observation.centroid[None])[0]


def rays_parallax_deg(c0, c1, d0, d1):
    """:func:`parallax_deg` of ``k`` ray pairs from two camera centres ``c0``, ``c1`` (3,) along
    world directions ``d0``, ``d1`` (k, 3): the angle at each pair's triangulated point (the
    midpoint of the rays' closest points) between the centres, degrees; 0 where the rays are
    parallel or do not meet in front of both cameras. (k,)."""
    d0, d1 = np.asarray(d0, dtype=np.float64), np.asarray(d1, dtype=np.float64)
    base = np.asarray(c1, dtype=np.float64) - np.asarray(c0, dtype=np.float64)
    # closest points c0 + t0 d0 and c1 + t1 d1: [[a, -b], [b, -e]] (t0, t1) = (d0 . base, d1 . base)
    a, b, e = np.einsum("ij,ij->i", d0, d0), np.einsum("ij,ij->i", d0, d1), np.einsum("ij,ij->i", d1, d1)
    r0, r1 = d0 @ base, d1 @ base
    det = b * b - a * e
    ok = np.abs(det) >= 1e-12
    det = np.where(ok, det, 1.0)
    t0, t1 = (b * r1 - e * r0) / det, (a * r1 - b * r0) / det
    ok &= (t0 > 0) & (t1 > 0)
    X = 0.5 * (c0 + t0[:, None] * d0 + c1 + t1[:, None] * d1)
    u, v = c0 - X, c1 - X
    cos = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300)
    return np.where(ok, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), 0.0)


def ready_to_initialise(problem, oid, frames, poses, options):
    """True when ``frames`` (the first frames seeing ``oid``, in order) are enough for its initial
    fit (:class:`GraphOptions`: ``init_frames`` and ``init_parallax_deg``); ``poses`` maps a frame to
    its current ``T_world_camera``."""
    if len(frames) < options.init_frames:
        return False
    first, last = frames[0], frames[-1]
    return parallax_deg(problem.observations[first, oid], problem.observations[last, oid], poses[first],
                        poses[last]) >= options.init_parallax_deg
