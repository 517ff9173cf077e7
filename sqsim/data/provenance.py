"""Which install made a run: the versions of Python, sqkit and the libraries its numbers depend on.

Fits move with the numeric libraries' rounding where a stage chooses between near-equal fits (stage 3U's
part choice on household furniture: a fresh install moved tables, monitors, chairs and laptops by up to
0.04 median 3D IoU of 20; README, "Reproducing the numbers"). So every experiment (sweep points included)
and SLAM run directory records the installs that ran it (:func:`sqsim.data.files.check_or_write_run_config`),
and ``./run.sh`` installs the versions pinned in ``constraints.txt``.
"""

from __future__ import annotations

import platform
from importlib import metadata

__all__ = ["LIBRARIES", "library_versions"]

#: The distributions whose versions a run records: the fitter's and the simulator's numeric stack.
LIBRARIES = ("sqkit", "numpy", "scipy", "numba", "shapely", "scikit-image", "opencv-python-headless", "trimesh",
             "manifold3d", "pyrender2", "PyOpenGL", "gtsam")


def library_versions():
    """``{"python": "3.11.7", "sqkit": "0.1.0", "numpy": "2.4.6", ...}``: the running Python and each of
    :data:`LIBRARIES`, None where it is not installed (gtsam is optional). Read from the installed
    distributions' metadata, without importing them."""
    out = {"python": platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
