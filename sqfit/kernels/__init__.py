"""Compiled kernels: the hot loops of the layers above, as numba loops beside their numpy code.

The lowest layer with :mod:`sqfit.geometry` (imports only numpy, and numba lazily): the formulas
are those of the modules that use them, which keep the numpy code as the reference and the path
for ``SQFIT_KERNELS=numpy``. :mod:`.backend` chooses between the two; importing this package (or
``sqfit``) never imports numba.

- :mod:`.backend` — which implementation runs (``SQFIT_KERNELS``, :func:`set_kernels`) and each
  part's kernel module, imported at first use (:func:`compiled`);
- :mod:`.ray_kernels` — the ray minimisers, 3G's ray residuals and the radial terms (for
  :mod:`sqfit.fitting.line_gauge`, :mod:`sqfit.fitting.raycost`, :mod:`sqfit.fitting.costs`);
- :mod:`.screen_kernels` — stage 3H's axis screen (:mod:`sqfit.fitting.axis_screen`);
- :mod:`.silhouette_kernels` — R-IOU-M's silhouettes, convex IoUs and hulls (:mod:`sqfit.fitting.costs`);
- :mod:`.view_kernels` — the factor graph's silhouette residuals (:mod:`sqfit.graph.landmark`);
- :mod:`.outline_kernels` — the outline samples behind every view's rays (:mod:`sqfit.views.rays`);
- :mod:`.hull_kernels` — the visual hull's carving and EMS residuals (:mod:`sqfit.fitting.hull`);
- :mod:`.union_kernels` — stage 3U's two silhouettes against a mask contour (:mod:`sqfit.fitting.two_parts`);
- :mod:`.velocity_kernels` — the silhouette vertices' velocities of 3U's gradient (:mod:`sqfit.fitting.two_parts`);
- :mod:`.kernel_cache` — numba's on-disk cache, cleared when any kernel source changed.
"""

from .backend import ENV_VAR, KERNELS, PARTS, compiled, kernels_name, set_kernels

__all__ = ["compiled", "set_kernels", "kernels_name", "KERNELS", "ENV_VAR", "PARTS"]
