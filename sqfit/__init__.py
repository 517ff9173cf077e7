"""sqfit: recover superquadrics from multi-view binary instance masks.

Pure numpy/scipy: importing this package never imports OpenGL or a renderer.

Quick start::

    import sqfit
    cams = [sqfit.Camera(intrinsics, T_world_camera) for T_world_camera in poses]
    obs = [sqfit.Observation.from_mask(cam, mask, rng=0) for cam, mask in zip(cams, masks)]
    result = sqfit.fit(obs, chain="1-2-3D-3A")   # result.superquadric, result.stages, ...
"""

from .camera import Camera, Intrinsics, back_project, look_at, project
from .observation import Observation
from .pipeline import DEFAULT_CHAIN, PAPER_CHAINS, FitOptions, FitResult, StageRecord, fit
from .stages import STAGES
from . import stage3g  # noqa: F401  (registers stage 3G)
from . import multistart  # noqa: F401  (registers stage 3S)
from . import axis_search  # noqa: F401  (registers stage 3H)
from .superquadric import Superquadric

__version__ = "0.1.0"

__all__ = ["Superquadric", "Camera", "Intrinsics", "Observation", "look_at", "project", "back_project",
           "fit", "FitOptions", "FitResult", "StageRecord", "PAPER_CHAINS", "DEFAULT_CHAIN", "STAGES"]
