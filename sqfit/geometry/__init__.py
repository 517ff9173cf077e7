"""Geometry: the superquadric, the pinhole camera, and what one looks like in the other.

The lowest layer of sqfit: pure functions over arrays, importing only :mod:`sqfit.constants` and
:mod:`sqfit._checks`.

- :mod:`.superquadric` — the 11 parameters, inside-outside function, volume, sampling, mesh;
- :mod:`.camera` — intrinsics, ``T_world_camera`` poses, projection and back-projection;
- :mod:`.polygon` — polygon area, convexity and IoU (convex, with its Jacobian; shapely otherwise);
- :mod:`.raster` — exact scanline filling of convex polygons into masks, even-odd filling of any;
- :mod:`.outline` — objects given as outline polygons (a COCO file's): the region they bound (pixel-centre
  polygons grown half a pixel step), its outline, pixels and uniform samples;
- :mod:`.silhouette` — the projected outline of a superquadric, batched and warm-started;
- :mod:`.visible_iou` — IoU of outlines restricted to what a view can show;
- :mod:`.slab` — superquadrics thin along one axis, and the exponent of the section across it.
"""

from .camera import Camera, Intrinsics, back_project, look_at, project
from .superquadric import Superquadric

__all__ = ["Superquadric", "Camera", "Intrinsics", "look_at", "project", "back_project"]
