"""Whether the masks agree with each other under the given cameras: their epipolar tangents.

Any plane through two cameras' centres cuts an object's silhouette cone in both views alike: the
planes of that pencil which touch the object touch both silhouettes (their images are the epipolar
lines tangent to each mask, through the epipoles). So where the cameras are right and the masks
exact, the two outermost planes that touch view ``i``'s outline are those that touch view ``j``'s,
to the outlines' pixel rounding, whatever the object's shape. A camera turned by 1 deg moves them by
several pixels (about 7 px at the paper's focal length of 400 px). The largest over a trial's pairs,
measured on ``sqsim``'s masks: clean household masks 0.17-1.44 px (100 objects: bottles, cans,
books, bowls, tables; seed 4), clean paper masks 0.10-2.38 px (100 trials, seed 1, 90 % below 0.5),
``scenes/paper-noisy.toml`` without its jitter (1 deg of pose noise) 2.83-31.5 px (100, seed 1), and
without its pose noise (2 px of smooth boundary jitter) above 2 px on 45 of 50 (seed 0). A mask
grown or shrunk evenly moves both views' tangents alike and is hardly seen (``paper-erode1``: 0.59
px median, above 2 px on 1 of 50).

:func:`tangent_disagreement` measures it per pair of views, in pixels: on each side, the distance
from view ``i``'s outermost outline vertex to the image in ``i`` of the plane that touches view
``j``'s outline there, and the same in ``j``, whichever is smaller (a view far from the object sees
the pencil coarser, and half a pixel there is many pixels in a view close to it). Pairs whose
baseline passes through or near the object (the pencil's planes then wrap around the silhouette, and
no plane is outermost) are left out. Stage 3W (:mod:`sqfit.fitting.weighted_overlap`) acts only on
masks that agree.
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import world_bearings

__all__ = ["WRAP", "tangent_disagreement"]

#: A pair is left out where one view's outline spans more than this angle (radians) of the pencil of
#: planes through the two centres: the baseline passes through or near the object.
WRAP = 0.8 * np.pi


def _angles(rays, baseline, u1, u2):
    """The pencil angle of the plane through the baseline and each of ``rays`` (world directions)."""
    normals = np.cross(baseline, rays)
    return np.arctan2(normals @ u2, normals @ u1)


def _line_distance(observation, normal, pixel):
    """Signed distance (px) of ``pixel`` from the image of the plane through the camera centre with
    world normal ``normal``."""
    camera, k = observation.camera, observation.camera.intrinsics
    n = camera.rotation.T @ normal
    a, b = n[0] / k.fx, n[1] / k.fy
    c = n[2] - a * k.cx - b * k.cy
    return (a * pixel[0] + b * pixel[1] + c) / np.hypot(a, b)


def tangent_disagreement(observations):
    """``(v, v)`` float, symmetric: for each pair of views, the larger over the two sides of the
    outline error (px) that explains the disagreement of their outermost tangent planes through both
    centres (module docstring): in view ``i``, the distance of its outermost outline vertex from the
    image of the plane that touches view ``j``'s outline, and the same in view ``j``; the smaller
    of the two (the error looks smallest in the view that sees the pencil coarsest). NaN on the
    diagonal and where the pair is left out (a baseline through the object, coincident centres)."""
    v = len(observations)
    out = np.full((v, v), np.nan)
    rays = [world_bearings(o.camera, o.contour) for o in observations]  # per view, not per pair
    centroid_rays = [world_bearings(o.camera, o.centroid[None])[0] for o in observations]
    for i in range(v):
        for j in range(i + 1, v):
            ci, cj = observations[i].camera.center, observations[j].camera.center
            baseline = cj - ci
            if np.linalg.norm(baseline) < 1e-9:
                continue
            # the pencil's angles, from the plane through view i's centroid ray
            u1 = np.cross(baseline, centroid_rays[i])
            if np.linalg.norm(u1) < 1e-12:
                continue
            u1 /= np.linalg.norm(u1)
            u2 = np.cross(baseline / np.linalg.norm(baseline), u1)
            angles = [_angles(rays[k], baseline, u1, u2) for k in (i, j)]
            if any(np.ptp(a) > WRAP or np.abs(a).max() > WRAP for a in angles):
                continue
            worst = 0.0
            for pick in (np.argmax, np.argmin):
                extreme = [pick(a) for a in angles]
                errors = []
                for own, other in ((0, 1), (1, 0)):
                    theta = angles[other][extreme[other]]
                    normal = np.cos(theta) * u1 + np.sin(theta) * u2
                    observation = observations[(i, j)[own]]
                    errors.append(abs(_line_distance(observation, normal, observation.contour[extreme[own]])))
                worst = max(worst, min(errors))
            out[i, j] = out[j, i] = worst
    return out
