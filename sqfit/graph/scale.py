"""The trajectory's scale: the one direction of the graph the silhouettes cannot see.

Silhouettes are scale-free: scaling every camera position, landmark position and landmark size by
the same factor ``s`` about a point leaves every ray residual unchanged (the gauge ``m`` of a ray
depends only on the ray and the superquadric in the landmark's frame, and both scale together). With
the centre at frame 0's camera, the prior on frame 0 is unchanged too, so the graph's error along this
direction comes from the odometry alone (and the landmarks' weak priors and the size bound). That
makes the optimum sit at the end of a long, nearly flat valley: Levenberg-Marquardt's damping turns
its steps away from low-curvature directions, so it stops part way, at a scale that depends on
rounding (measured on ``scenes/sequence-eval*.toml``: the scale of one sequence's solution moved by
1 % between runs 1e-9 apart). :func:`best_scale` moves along the valley directly: a 1-D minimisation
of the error of the factors the scale changes, over the factor ``s``, then :func:`rescaled` applies it.
"""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.optimize import minimize_scalar

from .shapevar import PLAIN

__all__ = ["rescaled", "best_scale", "scale_dependent_factors"]

#: The scale factor is searched in ``[1 - SCALE_RANGE, 1 + SCALE_RANGE]`` (the odometry's scale
#: error of a sequence is a few per cent at most; a wider bracket only slows the search).
SCALE_RANGE = 0.1
#: Absolute tolerance of the scale factor (a 1e-6 scale error is 10 micrometres at 10 m).
SCALE_XTOL = 1e-7


def rescaled(values, centre, s, pose_keys, landmark_keys, shape_keys, variable=PLAIN):
    """``values`` with positions scaled by ``s`` about ``centre`` and landmark sizes by ``s``.

    Parameters
    ----------
    values : gtsam.Values
    centre : (3,) float
        The fixed point (world frame), e.g. frame 0's camera centre.
    s : float
        Scale factor, > 0.
    pose_keys, landmark_keys : iterable of int
        Keys of ``Pose3`` variables (camera poses, landmark poses): their translations scale.
    shape_keys : iterable of int
        Keys of ``[ax, ay, az, e1, e2]`` vectors: the sizes ``a`` scale, the shapes ``e`` do not.
    variable : ShapeVariable
        How those vectors are stored (:mod:`sqfit.graph.shapevar`).

    Returns
    -------
    values : gtsam.Values
        A new ``Values``; rotations unchanged.
    """
    return _Scaling(values, centre, pose_keys, landmark_keys, shape_keys, variable)(s)


class _Scaling:
    """:func:`rescaled` of one ``values`` for any ``s``: the variables are read once, not at each of
    :func:`best_scale`'s ~30 evaluations (reading them was half of each)."""

    def __init__(self, values, centre, pose_keys, landmark_keys, shape_keys, variable):
        self.values, self.variable = values, variable
        self.centre = np.asarray(centre, dtype=np.float64)
        self.poses = list(pose_keys) + list(landmark_keys)
        read = [values.atPose3(key) for key in self.poses]
        self.rotations = [T.rotation() for T in read]
        self.translations = [T.translation() for T in read]
        self.shapes = [(key, values.atVector(key)) for key in shape_keys]

    def __call__(self, s):
        if not s > 0:
            raise ValueError(f"scale factor must be > 0, got {s}")
        centre, out = self.centre, gtsam.Values(self.values)
        for key, R, t in zip(self.poses, self.rotations, self.translations):
            out.update(key, gtsam.Pose3(R, centre + s * (t - centre)))
        for key, z in self.shapes:
            out.update(key, self.variable.scaled(z, s))
        return out


def scale_dependent_factors(graph, invariant):
    """The factors of ``graph`` for which ``invariant(factor)`` is false (a new graph)."""
    out = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        factor = graph.at(k)
        if not invariant(factor):
            out.add(factor)
    return out


def best_scale(graph, values, centre, pose_keys, landmark_keys, shape_keys, variable=PLAIN):
    """The scale factor about ``centre`` that minimises ``graph``'s error (arguments: :func:`rescaled`).

    ``graph`` should hold only the factors the scale changes (:func:`scale_dependent_factors`): the
    search evaluates it some 30 times.

    Returns
    -------
    s : float
        In ``[1 - SCALE_RANGE, 1 + SCALE_RANGE]``; 1.0 when no other factor lowers the error.
    """
    scaling = _Scaling(values, centre, pose_keys, landmark_keys, shape_keys, variable)

    def error(s):
        return graph.error(scaling(s))

    found = minimize_scalar(error, bounds=(1.0 - SCALE_RANGE, 1.0 + SCALE_RANGE), method="bounded",
                            options={"xatol": SCALE_XTOL})
    return float(found.x) if found.success and found.fun < error(1.0) else 1.0
