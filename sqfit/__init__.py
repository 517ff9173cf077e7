"""sqfit: recover superquadrics from multi-view binary instance masks.

Pure numpy/scipy: importing this package never imports OpenGL or a renderer.

Quick start::

    import sqfit
    cams = [sqfit.Camera(intrinsics, T_world_camera) for T_world_camera in poses]
    obs = [sqfit.Observation.from_mask(cam, mask, rng=0) for cam, mask in zip(cams, masks)]
    result = sqfit.fit(obs, chain="1-2-3D-3A")   # result.superquadric, result.stages, ...

Layers, each importing only from those before it (README, "Development"): :mod:`sqfit.kernels`
(compiled loops, numba imported lazily), :mod:`sqfit.geometry`,
:mod:`sqfit.formats`, :mod:`sqfit.views`, :mod:`sqfit.fitting`, then :mod:`sqfit.metrics`,
:mod:`sqfit.limit`, :mod:`sqfit.recording`, :mod:`sqfit.testing`, :mod:`sqfit.graph` (needs gtsam)
and :mod:`sqfit.cli`.
"""

from .fitting import DEFAULT_CHAIN, PAPER_CHAINS, STAGES, FitOptions, FitResult, StageRecord, fit
from .geometry import Camera, Intrinsics, Superquadric, back_project, look_at, project
from .views import Observation

__version__ = "0.1.0"

__all__ = ["Superquadric", "Camera", "Intrinsics", "Observation", "look_at", "project", "back_project",
           "fit", "FitOptions", "FitResult", "StageRecord", "PAPER_CHAINS", "DEFAULT_CHAIN", "STAGES"]
