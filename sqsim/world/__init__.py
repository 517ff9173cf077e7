"""The simulated world: scene files, objects, their layout, camera trajectories, odometry.

The lowest layer of sqsim (it uses only sqfit).

- :mod:`.scene` — scene TOML files: keys, validation, defaults, seeds, camera poses;
- :mod:`.values` — the value checkers of scene keys;
- :mod:`.objects` — ground-truth objects (superquadrics, boxes, cylinders, mesh files), what a
  camera can see of them;
- :mod:`.layout` — placing several objects (free, or resting on the ground without overlap);
- :mod:`.trajectory` — camera rings, orbits and waypoint trajectories;
- :mod:`.odometry` — drifting odometry from true poses.
"""

from .scene import Scene, load_scene, parse_scene

__all__ = ["Scene", "load_scene", "parse_scene"]
