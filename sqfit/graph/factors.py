"""GTSAM factors of the graph: thin ``gtsam.CustomFactor`` wrappers around the residual functions
of :mod:`sqfit.graph.landmark` and :mod:`sqfit.graph.quadric`.

A factor is one (frame, object) pair, never one pixel: the Python callback is the cost, so a view's
rays are evaluated together (one call of :func:`sqfit.raycost.ray_residuals`). Each callback keeps
the ray minimisers of its last call as the warm start of the next (valid for any nearby value).
"""

from __future__ import annotations

import gtsam
import numpy as np

from .landmark import bounds_residuals, silhouette_residuals
from .quadric import box_residuals

__all__ = ["silhouette_factor", "bounds_factor", "box_factor"]


def silhouette_factor(noise, camera_key, pose_key, shape_key, rays):
    """Silhouette factor of one view of one superquadric landmark.

    Parameters
    ----------
    noise : gtsam.noiseModel.Base
        Of dimension ``len(rays)`` (robust in the graph: :func:`sqfit.graph.solve`).
    camera_key, pose_key, shape_key : int
        Keys of the camera ``Pose3``, the landmark ``Pose3`` and its size/shape vector (5,).
    rays : RaySet
        Camera-frame rays (:func:`sqfit.graph.landmark.camera_rays`).
    """
    last = {}

    def error(this, values, jacobians):
        Tc = values.atPose3(camera_key).matrix()
        Tl = values.atPose3(pose_key).matrix()
        s = values.atVector(shape_key)
        x = np.concatenate([Tc.ravel(), Tl.ravel(), s])
        # Levenberg-Marquardt linearises at the point whose error it has just evaluated: the residual
        # function returns the Jacobians anyway, so that second call is served from here.
        if "x" in last and np.array_equal(x, last["x"]):
            r, Jc, Jl, Js = last["out"]
        else:
            with np.errstate(all="ignore"):
                r, Jc, Jl, Js, d = silhouette_residuals(Tc, Tl, s, rays, last.get("d"))
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Jc)) and np.all(np.isfinite(Jl))
                    and np.all(np.isfinite(Js))):
                raise FloatingPointError(f"silhouette factor ({gtsam.DefaultKeyFormatter(camera_key)}, "
                                         f"{gtsam.DefaultKeyFormatter(pose_key)}): non-finite residual at shape {s}")
            last.update(x=x, out=(r, Jc, Jl, Js), d=d)
        if jacobians is not None:
            jacobians[0], jacobians[1], jacobians[2] = Jc, Jl, Js
        return r

    return gtsam.CustomFactor(noise, [camera_key, pose_key, shape_key], error)


def bounds_factor(shape_key, weight):
    """Unary factor of the bound penalty (:func:`sqfit.graph.landmark.bounds_residuals`)."""
    def error(this, values, jacobians):
        r, J = bounds_residuals(values.atVector(shape_key), weight)
        if jacobians is not None:
            jacobians[0] = J
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(5), [shape_key], error)


def box_factor(noise, camera_key, pose_key, radii_key, K, box):
    """QuadricSLAM's bounding-box factor of one view of one dual-quadric landmark.

    Parameters
    ----------
    noise : gtsam.noiseModel.Base
        Of dimension 4 (pixels).
    camera_key, pose_key, radii_key : int
        Keys of the camera ``Pose3``, the quadric ``Pose3`` and its radii vector (3,).
    K : (3, 3) float
        Calibration matrix.
    box : (4,) float
        Detected box ``[u_min, v_min, u_max, v_max]``, pixels.
    """
    K, box = np.array(K, dtype=np.float64), np.array(box, dtype=np.float64)

    def error(this, values, jacobians):
        Tc = values.atPose3(camera_key).matrix()
        Tq = values.atPose3(pose_key).matrix()
        radii = values.atVector(radii_key)
        r, Jc, Jq, Jr = box_residuals(Tc, Tq, radii, K, box)
        if jacobians is not None:
            jacobians[0], jacobians[1], jacobians[2] = Jc, Jq, Jr
        return r

    return gtsam.CustomFactor(noise, [camera_key, pose_key, radii_key], error)
