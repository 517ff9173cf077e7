"""Superquadric landmarks in a factor graph: joint camera-pose and object optimisation (GTSAM).

Importing this subpackage imports ``gtsam`` (the ``slam`` extra); ``import sqfit`` never does.

Quick start::

    from sqfit import graph
    results = graph.run(intrinsics, odometry_poses, {(frame, object_id): observation, ...})
    results["graph"].poses, results["graph"].objects    # (n, 4, 4) T_world_camera, {id: Superquadric}

Methods (:data:`METHODS`): ``odometry``, ``fixed`` (per-object fits on the odometry poses),
``quadric`` (QuadricSLAM: dual quadrics from boxes), ``graph`` (batch Levenberg-Marquardt) and
``graph-isam2`` (iSAM2, frame by frame). Inputs and bad input: :mod:`sqfit.graph.problem`; options:
:mod:`sqfit.graph.options`; the methods: :mod:`sqfit.graph.solve`; building the graph as frames
arrive: :mod:`sqfit.graph.growth`; re-initialising landmarks: :mod:`sqfit.graph.refit`; when iSAM2
is rebuilt: :mod:`sqfit.graph.schedule`; the silhouette factor: :mod:`sqfit.graph.landmark`.
"""

from .landmark import (bounds_residuals, camera_rays, landmark_to_superquadric, silhouette_residuals,
                       superquadric_to_landmark)
from .options import GraphOptions
from .problem import SlamResult, check_inputs, observations_from_instances
from .quadric import box_residuals, initialise_quadric
from .solve import METHODS, fixed_pose_fits, odometry, quadric_graph, run, superquadric_graph, superquadric_isam2

__all__ = ["GraphOptions", "SlamResult", "METHODS", "run", "odometry", "fixed_pose_fits", "superquadric_graph",
           "superquadric_isam2", "quadric_graph", "check_inputs", "observations_from_instances", "camera_rays",
           "silhouette_residuals", "bounds_residuals", "landmark_to_superquadric", "superquadric_to_landmark",
           "box_residuals", "initialise_quadric"]
