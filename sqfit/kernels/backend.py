"""Which implementation the hot loops run: compiled kernels or numpy.

The ray minimisers and the 3G residuals and Jacobians (:mod:`sqfit.fitting.raycost`, used by stages 3G,
3H, 3S and the factor graph) and the radial terms of G3-G5 (:mod:`sqfit.fitting.costs`) have two
implementations that compute the same numbers: vectorised numpy, and per-ray loops compiled with
numba (:mod:`sqfit.kernels.ray_kernels`; 3H's screen of them, :mod:`sqfit.kernels.screen_kernels`); so
do the silhouettes, convex IoUs and hulls of R-IOU-M (:mod:`sqfit.kernels.silhouette_kernels`), the
factor graph's silhouette residuals (:mod:`sqfit.kernels.view_kernels`) and the outline samples
behind every view's rays (:mod:`sqfit.kernels.outline_kernels`, for :mod:`sqfit.views.rays`) and
the visual hull's carving and point-cloud residuals (:mod:`sqfit.kernels.hull_kernels`) and stage 3U's
two silhouettes against a contour (:mod:`sqfit.kernels.union_kernels`) and the silhouette vertices'
velocities of its gradient (:mod:`sqfit.kernels.velocity_kernels`). Small
arrays make numpy pay its per-call overhead dozens of times per evaluation; the compiled loops do
not (README, "Fitter speed").

Choice, first match wins:

1. :func:`set_kernels` (``"numba"``, ``"numpy"`` or ``"auto"``), for the rest of the process;
2. the environment variable ``SQFIT_KERNELS`` (same values), read at the first fit;
3. ``"auto"``: numba when it imports, numpy otherwise.

numba is imported lazily, at the first evaluation that needs it, never by ``import sqfit``; its
kernels are cached on disk (``cache=True``) so only a process on an empty cache, or the first after
a kernel source changed (:mod:`sqfit.kernels.kernel_cache`), compiles them.
"""

from __future__ import annotations

import os

__all__ = ["KERNELS", "ENV_VAR", "PARTS", "set_kernels", "kernels_name", "compiled"]

#: Accepted names of an implementation.
KERNELS = ("auto", "numba", "numpy")
#: Environment variable read when :func:`set_kernels` was not called.
ENV_VAR = "SQFIT_KERNELS"

#: The kernel modules by part, imported at first use.
PARTS = ("rays", "screen", "silhouettes", "views", "outlines", "hull", "unions", "velocities")

_state = {"choice": None, "modules": {}, "resolved": None}


def set_kernels(name):
    """Choose the implementation of the hot loops for this process.

    Parameters
    ----------
    name : {"auto", "numba", "numpy"} or None
        ``"numba"`` fails at the next evaluation if numba does not import; None returns to the
        environment variable's choice.

    Returns
    -------
    previous : str or None
        The choice before this call (to restore it).
    """
    if name is not None and name not in KERNELS:
        raise ValueError(f"kernels must be one of {KERNELS} or None, got {name!r}")
    previous = _state["choice"]
    _state["choice"] = name
    _state["resolved"] = None
    return previous


def _requested():
    if _state["choice"] is not None:
        return _state["choice"]
    name = os.environ.get(ENV_VAR, "auto").strip().lower() or "auto"
    if name not in KERNELS:
        raise ValueError(f"environment variable {ENV_VAR} must be one of {KERNELS}, got {name!r}")
    return name


def compiled(part="rays"):
    """A compiled kernels module, or None for the numpy path.

    ``part``: ``"rays"`` (:mod:`sqfit.kernels.ray_kernels`), ``"screen"``
    (:mod:`sqfit.kernels.screen_kernels`, stage 3H's), ``"silhouettes"``
    (:mod:`sqfit.kernels.silhouette_kernels`), ``"views"`` (:mod:`sqfit.kernels.view_kernels`, the
    factor graph's), ``"outlines"`` (:mod:`sqfit.kernels.outline_kernels`, the rays' outline
    samples), ``"hull"`` (:mod:`sqfit.kernels.hull_kernels`, the visual hull's carving and EMS
    residuals), ``"unions"`` (:mod:`sqfit.kernels.union_kernels`, stage 3U's) or ``"velocities"``
    (:mod:`sqfit.kernels.velocity_kernels`, the silhouette vertices' velocities of 3U's gradient); each is
    imported (and its kernels loaded) at the first call that asks for it.
    """
    if _state["resolved"] is None:
        _state["resolved"] = _resolve(_requested())
    if _state["resolved"] != "numba":
        return None
    module = _state["modules"].get(part)
    if module is None:
        if part == "rays":
            from . import ray_kernels as module
        elif part == "screen":
            from . import screen_kernels as module
        elif part == "silhouettes":
            from . import silhouette_kernels as module
        elif part == "views":
            from . import view_kernels as module
        elif part == "outlines":
            from . import outline_kernels as module
        elif part == "hull":
            from . import hull_kernels as module
        elif part == "unions":
            from . import union_kernels as module
        elif part == "velocities":
            from . import velocity_kernels as module
        else:
            raise ValueError(f"part must be one of {PARTS}, got {part!r}")
        _state["modules"][part] = module
    return module


def kernels_name():
    """``"numba"`` or ``"numpy"``: the implementation the next evaluation runs."""
    compiled()
    return _state["resolved"]


def _resolve(name):
    if name == "numpy":
        return "numpy"
    if "rays" not in _state["modules"]:
        try:
            from . import ray_kernels
        except ImportError as exc:
            if name == "numba":
                raise ImportError(f"kernels 'numba' were requested ({ENV_VAR} or set_kernels) but numba "
                                  f"does not import: {exc}") from exc
            return "numpy"
        _state["modules"]["rays"] = ray_kernels
    return "numba"
