"""When iSAM2 is rebuilt at the best scale, with its landmarks re-fitted (:mod:`sqfit.graph.solve`).

A rebuild costs about as much as the graph so far (a fresh iSAM2 on every factor, the re-fits of
the landmarks in poor minima), so rebuilds are spaced, in two units at once: one comes once both
``isam2_rescale_every`` frames and ``isam2_rescale_parallax_deg`` degrees of parallax have passed
since the last (each spacing, once it is less than ``isam2_rescale_growth`` times the frames or the
parallax so far, that much instead: the total cost then grows with the length, not with its square).
A frame's parallax is the median, over the objects it and the previous frame both see, of the angle
their camera centres subtend at the object's mask centroid triangulated
(:func:`sqfit.graph.parallax.parallax_deg`, at the current pose estimates: from the data, whether or
not the object's landmark is in the graph yet).

Why both. What a rebuild corrects (a scale the first frames set, a landmark stuck in a minimum its
first views allowed) comes with new viewpoints, not with new frames: by frames alone, the same path
filmed at twice the rate is rebuilt twice as often (``scenes/sequence.toml``, 80 frames against 40:
7 rebuilds and 21 re-fits against 4 and 9). By parallax alone (measured with 50 degrees), sequences
whose first steps see much parallax were rebuilt from frame 7-8 on, re-fitting landmarks on a few
frames, and iSAM2 then ran off the odometry in 4 of 30 household batches (0 of 30 by frames), two of
which lost the map (docs/slam-history.md, "Issue 23, eighth pass"). So the frames are the floor and
the parallax the pace when frames come faster than the viewpoint changes: on the evaluation scenes
(about 5.5 degrees per frame) the rebuilds come after 10-12, 20-23, 30-33 and 40-43 frames.

``isam2_rescale_parallax_deg = 0``: by frames alone; ``isam2_rescale_every = 0``: no rebuilds.
"""

from __future__ import annotations

import numpy as np
from gtsam.symbol_shorthand import X

from .parallax import centroid_bearing, rays_parallax_deg

__all__ = ["RebuildSchedule", "rebuild_frames", "next_mark", "step_parallax_deg"]


def next_mark(mark, every, growth):
    """The progress of the rebuild after one at ``mark``: ``every`` later or, once that is less,
    ``growth`` times ``mark`` later."""
    return max(mark + every, mark * (1.0 + growth))


def rebuild_frames(n, options):
    """The schedule by frames alone (``isam2_rescale_parallax_deg = 0``): the frame counts (<= ``n``)
    after which iSAM2 is rebuilt (at 10, 20, 30, 40, 50, 63, 79, 99 .. with the default
    ``isam2_rescale_every`` and ``isam2_rescale_growth``); the frame floor of :class:`RebuildSchedule`.
    Empty when ``isam2_rescale_every`` is 0."""
    every, frames, out = options.isam2_rescale_every, options.isam2_rescale_every, set()
    while every and frames <= n:
        out.add(frames)
        frames = int(np.ceil(next_mark(frames, every, options.isam2_rescale_growth)))
    return out


def step_parallax_deg(problem, estimate, frame, bearings=None):
    """Median over the objects seen in both ``frame - 1`` and ``frame`` of the parallax between the
    two frames (:func:`sqfit.graph.parallax.parallax_deg`, the poses from ``estimate``), degrees;
    0 for frame 0 or when no object is seen in both. ``bearings``: a dict kept between calls, the
    mask centroids' camera-frame bearings by ``(frame, object)``."""
    if frame == 0:
        return 0.0
    obs = problem.observations
    shared = [oid for oid in problem.frames if (frame - 1, oid) in obs and (frame, oid) in obs]
    if not shared:
        return 0.0
    bearings = {} if bearings is None else bearings
    for key in [(f, oid) for f in (frame - 1, frame) for oid in shared]:
        if key not in bearings:
            bearings[key] = centroid_bearing(obs[key])
    a, b = estimate.atPose3(X(frame - 1)).matrix(), estimate.atPose3(X(frame)).matrix()
    d0 = np.array([bearings[frame - 1, oid] for oid in shared]) @ a[:3, :3].T
    d1 = np.array([bearings[frame, oid] for oid in shared]) @ b[:3, :3].T
    return float(np.median(rays_parallax_deg(a[:3, 3], b[:3, 3], d0, d1)))


class RebuildSchedule:
    """Says after which frames iSAM2 is rebuilt (module docstring), frame by frame; ``problem``: the
    :class:`sqfit.graph.problem.Problem` whose observations give the parallax (unused by frames alone)."""

    def __init__(self, problem, options):
        self.problem = problem
        self.every, self.degrees = options.isam2_rescale_every, options.isam2_rescale_parallax_deg
        self.growth = options.isam2_rescale_growth
        self.parallax = 0.0  # degrees so far
        self.frame_mark, self.parallax_mark = float(self.every), float(self.degrees)
        self.frames = []  # the frame counts after which a rebuild was due
        self.bearings = {}  # step_parallax_deg's

    def due(self, estimate, frame):
        """Whether iSAM2 is rebuilt after ``frame`` (0-based; ``estimate`` holds frames ``0 .. frame``)."""
        if self.degrees > 0:
            self.parallax += step_parallax_deg(self.problem, estimate, frame, self.bearings)
        n = frame + 1
        if not self.every or n < self.frame_mark or self.parallax < self.parallax_mark - 1e-9:
            return False
        self.frame_mark = float(np.ceil(next_mark(n, self.every, self.growth)))
        if self.degrees > 0:
            self.parallax_mark = next_mark(self.parallax, self.degrees, self.growth)
        self.frames.append(n)
        return True
