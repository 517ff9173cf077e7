"""Imaging: from a world to the instance masks and poses a fitter gets.

Above :mod:`sqsim.world`.

- :mod:`.render` — exact instance-id images (OpenGL over OSMesa/EGL, or polygons);
- :mod:`.noise` — mask and pose noise models;
- :mod:`.visibility` — visible and cut fractions of each object per view;
- :mod:`.trial` — one simulated multi-view trial (objects, cameras, noisy images, observations);
- :mod:`.sequence` — one simulated image sequence with odometry.
"""
