"""Inputs and results of the factor graph (numpy only; its options: :mod:`sqfit.graph.options`).

Input interface (what a sequence reader provides):

- ``intrinsics``: one :class:`sqfit.Intrinsics` for the whole sequence;
- ``odometry_poses``: ``(n, 4, 4)`` ``T_world_camera`` (camera -> world) per frame; frame 0 is the
  anchor of the graph (its prior), so the result lives in the odometry's world frame;
- ``observations``: ``{(frame, object_id): sqfit.Observation}``. Only an observation's pixels are
  used (its contour, and its box for the quadric baseline); where its camera was placed does not
  matter, the graph puts it at the frame's pose. Data association comes from the instance ids: the
  same ``object_id`` in two frames is the same object. :func:`observations_from_instances` makes
  them from per-frame instance-id images.

Bad input: a non-finite or improper pose (a frame without a pose), an observation in a frame the
poses do not cover, other intrinsics, or a key that is not ``(int, int)`` raise ``ValueError`` /
``TypeError`` naming the frame or key. An object seen in fewer than 2 frames cannot be fitted and is
skipped with a warning in the result (:attr:`SlamResult.skipped`). A mask touching the image border
is used, with a warning (as :func:`sqfit.fit` does): its outline is not all silhouette; outline points
labelled ``border`` or ``instance`` (:mod:`sqfit.views.visibility`, as :func:`observations_from_instances`
makes them) give one-sided ray residuals.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .. import constants as C
from .._checks import check_shape
from ..geometry.camera import Camera, Intrinsics, rigid_pose_fault
from ..views.observation import Observation
from .options import MIN_FRAMES

__all__ = ["SlamResult", "Problem", "check_inputs", "observations_from_instances",
           "observation_at", "error_line"]


def error_line(exc):
    """The first non-blank line of an optimiser error's message, stripped ("" if none): GTSAM's
    messages start with a blank line and go on with paragraphs of advice."""
    return next((line.strip() for line in str(exc).splitlines() if line.strip()), "")


@dataclass
class SlamResult:
    """What one method made of a sequence.

    Attributes
    ----------
    method : str
    poses : (n, 4, 4) float
        Estimated ``T_world_camera`` per frame.
    objects : dict of int -> Superquadric
        Fitted objects by id (ellipsoids, ``e = 1``, for the quadric baseline).
    seconds, cpu_seconds : float
        Wall and process CPU time of the whole method (initial fits included).
    frame_seconds, frame_cpu_seconds : (n,) float or None
        Incremental methods: wall and CPU time of each frame's update.
    skipped : dict of int -> str
        Objects left out, with the reason.
    warnings : list of str
    iterations : int
        Optimiser iterations (batch) or updates (incremental).
    error_initial, error_final : float or None
        Graph error (``0.5 * sum`` of whitened robust squared residuals) at the start and the end
        of the last solve (batch: of the last window; iSAM2: the end only).
    status : str
        ``"ok"``, or ``"failed"`` when the optimiser stopped on an error (``message`` says which);
        ``poses`` are then the odometry and ``objects`` empty.
    message : str
    outline_offsets : dict of int -> float
        Graph methods with ``GraphOptions.outline_offset_sigma_px > 0``: each object's estimated
        outline offset, px (> 0: its masks are too big).
    odometry_chi2 : float or None
        Graph methods: the mean chi-square per odometry step of the returned estimate
        (:func:`sqfit.graph.solve.odometry_chi2`; about 6, its degrees of freedom, when the estimate
        agrees with the odometry within its noise model). Above
        ``GraphOptions.batch_odometry_chi2`` a warning flags the result: the trajectory and map
        have run off, or the odometry noise model is tighter than the odometry. None for the other
        methods and for a failed result.
    """

    method: str
    poses: np.ndarray
    objects: dict = field(default_factory=dict)
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    frame_seconds: np.ndarray | None = None
    frame_cpu_seconds: np.ndarray | None = None
    skipped: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    iterations: int = 0
    error_initial: float | None = None
    error_final: float | None = None
    status: str = "ok"
    message: str = ""
    outline_offsets: dict = field(default_factory=dict)
    odometry_chi2: float | None = None

    @property
    def ok(self):
        return self.status == "ok"

    def fail(self, where, exc):
        """Flag the result as failed by ``exc`` (an optimiser error) at ``where``."""
        self.status, self.message = "failed", f"{where}: {type(exc).__name__}: {error_line(exc) or type(exc).__name__}"
        self.objects = {}
        self.warnings.append(self.message)

    def to_dict(self):
        """A JSON-serialisable dict (poses as nested lists, objects as parameter vectors)."""
        d = asdict(self)
        d["poses"] = self.poses.tolist()
        d["objects"] = {str(k): sq.to_vector().tolist() for k, sq in self.objects.items()}
        d["skipped"] = {str(k): v for k, v in self.skipped.items()}
        d["outline_offsets"] = {str(k): v for k, v in self.outline_offsets.items()}
        for key in ("frame_seconds", "frame_cpu_seconds"):
            d[key] = None if d[key] is None else np.asarray(d[key]).tolist()
        return d


@dataclass(frozen=True)
class Problem:
    """Checked inputs: poses, observations by object, and the objects left out."""

    intrinsics: Intrinsics
    odometry_poses: np.ndarray
    observations: dict
    frames: dict  # object id -> sorted frames that see it (only objects that can be fitted)
    skipped: dict
    warnings: tuple

    @property
    def n_frames(self):
        return len(self.odometry_poses)


def _check_pose(T, i):
    if not np.all(np.isfinite(T)):
        raise ValueError(f"frame {i} has no pose: odometry_poses[{i}] contains NaN or inf")
    if rigid_pose_fault(T):
        raise ValueError(f"odometry_poses[{i}] is not a rigid transform (proper rotation, last row [0, 0, 0, 1])")


def check_inputs(intrinsics, odometry_poses, observations):
    """Coerce and check the graph's inputs (module docstring); returns a :class:`Problem`."""
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError(f"intrinsics must be a sqfit.Intrinsics, got {type(intrinsics).__name__}")
    poses = check_shape(odometry_poses, (None, 4, 4), "odometry_poses", finite=False)
    if len(poses) == 0:
        raise ValueError("odometry_poses must have at least one frame")
    for i, T in enumerate(poses):
        _check_pose(T, i)
    if not isinstance(observations, dict):
        raise TypeError(f"observations must be a dict {{(frame, object_id): Observation}}, got "
                        f"{type(observations).__name__}")
    obs, by_object = {}, {}
    for key, o in observations.items():
        if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(k, (int, np.integer)) for k in key)):
            raise TypeError(f"observation key {key!r} must be a tuple (frame, object_id) of ints")
        frame, oid = int(key[0]), int(key[1])
        if not isinstance(o, Observation):
            raise TypeError(f"observation {key}: must be a sqfit.Observation, got {type(o).__name__}")
        if not 0 <= frame < len(poses):
            raise ValueError(f"observation (frame {frame}, object {oid}): frame {frame} has no pose "
                             f"(odometry_poses has {len(poses)} frames)")
        if o.camera.intrinsics != intrinsics:
            raise ValueError(f"observation (frame {frame}, object {oid}): its camera's intrinsics differ from "
                             f"the sequence's")
        obs[frame, oid] = o
        by_object.setdefault(oid, []).append(frame)
    frames, skipped = {}, {}
    warnings = [f"frame {f}, object {j}: mask touches the image border (truncated silhouette; its outline labelled "
                f"'border' counts one-sided)" if o.partial else
                f"frame {f}, object {j}: mask touches the image border (truncated silhouette)"
                for (f, j), o in sorted(obs.items()) if o.touches_border]
    for oid in sorted(by_object):
        seen = sorted(by_object[oid])
        if len(seen) < MIN_FRAMES:
            skipped[oid] = f"seen in {len(seen)} frame only (frame {seen[0]}); needs >= {MIN_FRAMES}"
            warnings.append(f"object {oid}: skipped, {skipped[oid]}")
        else:
            frames[oid] = seen
    return Problem(intrinsics, poses, obs, frames, skipped, tuple(warnings))


def observations_from_instances(intrinsics, poses, instance_images, min_area_px=50, n_samples=C.DEFAULT_SAMPLES,
                                rng=None):
    """The graph's observations from per-frame instance-id images (what a sequence reader gives).

    Parameters
    ----------
    intrinsics : Intrinsics
    poses : (n, 4, 4) float
        ``T_world_camera`` per frame, given to the observations' cameras (the graph uses only their
        pixels; the odometry is the natural choice).
    instance_images : (n, h, w) int or sequence of (h, w) int
        Object id per pixel, 0 for background (e.g. uint16).
    min_area_px : int
        Instances with fewer pixels are left out (too small to say anything), >= 1.
    n_samples : int
    rng : None, int or numpy.random.Generator

    Returns
    -------
    observations : dict of (int, int) -> Observation
        ``(frame, object_id) ->`` that instance's labelled observation
        (:func:`sqfit.views.dataset.observations_from_images`: outline points next to another instance are
        labelled ``instance``, those on the image border ``border``; the silhouette factors treat
        them as one-sided, :mod:`sqfit.fitting.raycost`).
    """
    if not isinstance(intrinsics, Intrinsics):
        raise TypeError(f"intrinsics must be a sqfit.Intrinsics, got {type(intrinsics).__name__}")
    poses = check_shape(poses, (None, 4, 4), "poses")
    if len(instance_images) != len(poses):
        raise ValueError(f"instance_images has {len(instance_images)} frames, poses {len(poses)}")
    if int(min_area_px) != min_area_px or min_area_px < 1:
        raise ValueError(f"min_area_px must be an integer >= 1, got {min_area_px}")
    from ..views.dataset import observations_from_images

    rng = np.random.default_rng(rng)
    shape = (intrinsics.height, intrinsics.width)
    checked, frames_of = [], {}
    for frame, image in enumerate(instance_images):
        image = np.asarray(image)
        if image.shape != shape or image.dtype.kind not in "iu":
            raise ValueError(f"instance_images[{frame}] must be an integer (height, width) = {shape} image, got "
                             f"{image.dtype} {image.shape}")
        checked.append(image)
        ids, counts = np.unique(image[image != 0], return_counts=True)
        for oid in ids[counts >= min_area_px]:
            frames_of.setdefault(int(oid), []).append(frame)
    observations = {}
    for oid in sorted(frames_of):
        frames = frames_of[oid]
        cameras = [Camera(intrinsics, poses[f]) for f in frames]
        # labelled: the other instances may hide the object, the image border cuts it (sqfit.views.visibility)
        found = observations_from_images(cameras, np.stack([checked[f] for f in frames]), oid, n_samples, rng=rng)
        for view, o in zip(found.views, found):
            observations[frames[view], oid] = o
    return dict(sorted(observations.items()))


def observation_at(observation, T_world_camera):
    """The observation with its camera moved to ``T_world_camera`` (pixels unchanged, and what was
    computed from them kept: ``Observation.with_camera``)."""
    return observation.with_camera(Camera(observation.camera.intrinsics, T_world_camera))
