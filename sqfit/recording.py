"""3D recordings for the rerun viewer: cameras, masks, ground truth and every stage of every fit.

``rerun-sdk`` is optional (extra ``viz``) and imported only here, when a :class:`Recorder` is
created: ``import sqfit`` never imports it. A recording is written to an ``.rrd`` file (no viewer
is started); open it with ``rerun FILE.rrd``.

Layout of a recording (entity paths; ``T`` = trial name, ``VV`` = view, ``C`` = chain, ``K`` = id):

- ``trials/T/cameras/view_VV``: ``Transform3D`` (the pose the fitter used, camera -> world) and
  ``Pinhole`` (intrinsics, OpenCV camera frame: x right, y down, z forward, ``camera_xyz=RDF``);
  ``.../view_VV/mask``: the instance-id image as a ``SegmentationImage`` (0 = background, ``K`` =
  object ``K``; the datasets hold instance masks, so this is the camera's image);
- ``trials/T/true_cameras/view_VV``: the noise-free pose and pinhole, when recorded;
- ``trials/T/ground_truth/object_K``: ``Mesh3D`` of a superquadric (or ``Boxes3D`` of the
  half-extents for the other object kinds);
- ``trials/T/fits/C/object_K``: ``Mesh3D`` of the estimate after each stage, on the ``stage``
  timeline (sequence ``0 .. len(chain) - 1``; ``AnyValues`` ``stage_name``, ``stage_status``, ``chain``);
  a stage that produced no superquadric clears the entity;
- ``trials/T/cameras/view_VV/fits/C/object_K``: the estimate's silhouette in that view
  (``LineStrips2D``, pixel coordinates), also per stage.

Cameras, masks and ground truth are static; scrubbing the ``stage`` timeline steps every fit
through its chain. The default blueprint has one 3D view per trial (tabs).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["Recorder", "check_recording_path", "DEFAULT_MAX_TRIALS", "STAGE_TIMELINE", "MESH_RESOLUTION"]

#: Name of the timeline holding the per-stage estimates.
STAGE_TIMELINE = "stage"
#: Cube-sphere subdivisions of the recorded superquadric meshes (``6 * 24**2`` quads).
MESH_RESOLUTION = 24
#: Silhouette vertices of the recorded 2D outlines.
SILHOUETTE_DIRECTIONS = 64
#: Trials beyond this number are recorded but get no tab of their own in the default blueprint.
MAX_TABS = 50
#: Trials recorded by default (a paper trial with one fit takes ~0.4 MB; 100 000 would take 40 GB).
DEFAULT_MAX_TRIALS = 100

_GT_COLOR = (40, 200, 90, 110)
_CHAIN_COLORS = [(230, 80, 60, 200), (60, 120, 230, 200), (230, 170, 40, 200), (170, 70, 200, 200),
                 (40, 190, 200, 200), (120, 120, 120, 200)]


def _superquadric_mesh(sq):
    from .geometry.superquadric import to_mesh

    mesh = to_mesh(sq, MESH_RESOLUTION)
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.uint32)


def add_arguments(parser, contents):
    """``--rerun FILE.rrd`` and ``--rerun-trials N`` for a command line; ``contents`` for the help."""
    parser.add_argument("--rerun", metavar="FILE.rrd", default=None,
                        help=f"also write a rerun recording: {contents} (open it with 'rerun FILE.rrd')")
    parser.add_argument("--rerun-trials", metavar="N", type=int, default=DEFAULT_MAX_TRIALS,
                        help="record at most the first N trials")


def check_recording_path(path, max_trials=None):
    """Fail early, before hours of work, if a recording cannot be written to ``path``.

    Returns
    -------
    path : pathlib.Path

    Raises
    ------
    ValueError
        ``path`` does not end in ``.rrd``, or ``max_trials`` is neither None nor an integer >= 1.
    ImportError
        rerun-sdk is not installed (with the command that installs it).
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ValueError(f"rerun recording path must end in .rrd, got {str(path)!r}")
    if max_trials is not None and (isinstance(max_trials, bool) or int(max_trials) != max_trials or max_trials < 1):
        raise ValueError(f"the number of trials to record (--rerun-trials) must be an integer >= 1, got {max_trials!r}")
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise ImportError("recording needs rerun-sdk: pip install 'sqkit[viz]' (./run.sh main installs it)") from None
    return path


class Recorder:
    """Writes a rerun recording (``.rrd``) of trials and fits; use as a context manager.

    Parameters
    ----------
    path : str or os.PathLike
        Output file, must end in ``.rrd``; its directory is created.
    application_id : str
        Shown by the viewer.
    max_trials : int or None
        Record only the first ``max_trials`` distinct trials logged (``None``: all); later ones
        are counted in :attr:`skipped` and named in a note on stderr at :meth:`close`.

    Raises
    ------
    ValueError
        ``path`` does not end in ``.rrd``, or ``max_trials`` is not an integer >= 1.
    ImportError
        rerun-sdk is not installed (with the command that installs it).
    """

    def __init__(self, path, application_id="sqkit", max_trials=None):
        path = check_recording_path(path, max_trials)
        import rerun as rr

        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._rr = rr
        self._stream = rr.RecordingStream(application_id)
        self._stream.save(str(path))
        self._trials = []
        self._chains = {}
        self.max_trials = max_trials
        #: Trials not recorded because of ``max_trials``.
        self.skipped = set()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Send the default blueprint and finish writing the file."""
        if self._stream is None:
            return
        import rerun.blueprint as rrb

        views = [rrb.Spatial3DView(origin=f"trials/{t}", name=f"trial {t}") for t in self._trials[:MAX_TABS]]
        if views:
            self._stream.send_blueprint(rrb.Blueprint(rrb.Tabs(*views), collapse_panels=False))
        self._stream.flush()
        self._stream.disconnect()
        self._stream = None
        if self.skipped:
            import sys

            print(f"rerun: recorded {len(self._trials)} trial(s) in {self.path}; {len(self.skipped)} more not "
                  f"recorded (limit max_trials / --rerun-trials = {self.max_trials})", file=sys.stderr)

    def admits(self, trial):
        """Whether ``trial`` is (or can still be) recorded under ``max_trials``."""
        return trial in self._trials or self.max_trials is None or len(self._trials) < self.max_trials

    def _admit(self, trial):
        if not self.admits(trial):
            self.skipped.add(trial)
            return False
        if trial not in self._trials:
            self._trials.append(trial)
        return True

    # --- trials ------------------------------------------------------------------------------

    def log_trial(self, name, cameras, images=None, true_cameras=None, ground_truth=()):
        """Record a trial's cameras, instance masks and ground truth (static).

        Parameters
        ----------
        name : str
            Trial name (``"000007"``).
        cameras : list of Camera
            Poses the fitter uses.
        images : (v, h, w) int, optional
            Instance ids per view.
        true_cameras : list of Camera, optional
            Noise-free poses.
        ground_truth : list of dict
            ``gt.json`` object records (``id``, ``kind``, ``params`` for superquadrics, ``size``,
            ``position``, ``rotation``).

        Returns
        -------
        recorded : bool
            False when ``max_trials`` other trials are already recorded.
        """
        if not self._admit(name):
            return False
        rr, log = self._rr, self._stream.log
        root = f"trials/{name}"
        ids = sorted({int(o["id"]) for o in ground_truth}
                     | ({int(i) for i in np.unique(images)} - {0} if images is not None else set()))
        log(root, rr.AnnotationContext([(0, "background", (0, 0, 0))]
                                       + [(k, f"object {k}") for k in ids]), static=True)
        for group, cams in (("cameras", cameras), ("true_cameras", true_cameras)):
            for v, cam in enumerate(cams or []):
                self._log_camera(f"{root}/{group}/view_{v:02d}", cam)
        if images is not None:
            images = np.asarray(images)
            if images.ndim != 3 or len(images) != len(cameras):
                raise ValueError(f"images must have shape (v, h, w) with v = {len(cameras)}, got {images.shape}")
            for v, image in enumerate(images):
                log(f"{root}/cameras/view_{v:02d}/mask", rr.SegmentationImage(image), static=True)
        for obj in ground_truth:
            self._log_ground_truth(f"{root}/ground_truth/object_{int(obj['id'])}", obj)
        return True

    def log_loaded_trial(self, trial):
        """Record a :class:`sqfit.views.dataset.Trial` (cameras, masks, true cameras, ``gt.json`` objects)."""
        return self.log_trial(trial.name, trial.cameras, trial.images, trial.true_cameras, trial.objects)

    def _log_camera(self, entity, cam):
        rr = self._rr
        k = cam.intrinsics
        K = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
        self._stream.log(entity, rr.Transform3D(translation=cam.pose[:3, 3], mat3x3=cam.pose[:3, :3]),
                         rr.Pinhole(image_from_camera=K, resolution=[k.width, k.height],
                                    camera_xyz=rr.ViewCoordinates.RDF), static=True)

    def _log_ground_truth(self, entity, obj):
        from .geometry.superquadric import Superquadric, euler_to_matrix

        rr = self._rr
        if obj.get("params") is not None:
            vertices, faces = _superquadric_mesh(Superquadric.from_vector(np.asarray(obj["params"], dtype=np.float64)))
            self._stream.log(entity, rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces,
                                               albedo_factor=_GT_COLOR), static=True)
            return
        R = euler_to_matrix(np.asarray(obj["rotation"], dtype=np.float64))
        self._stream.log(entity, rr.Transform3D(translation=obj["position"], mat3x3=R),
                         rr.Boxes3D(half_sizes=[obj["size"]], colors=[_GT_COLOR[:3]],
                                    labels=[obj.get("kind", "object")]), static=True)

    # --- fits ----------------------------------------------------------------------------------

    def log_fit(self, trial, object_id, chain, stages, cameras=()):
        """Record the estimate after each stage of one fit on the ``stage`` timeline.

        Parameters
        ----------
        trial : str
        object_id : int
        chain : str
        stages : list of sqfit.fitting.pipeline.StageRecord or dict
            Each with ``name``, ``status`` and ``superquadric`` (a record) or ``params``
            (``(11,)`` list or None, a ``trials.jsonl`` stage dict).
        cameras : list of Camera
            The trial's cameras (view ``VV`` = position in the list); each stage's silhouette is
            drawn in each of them.

        Returns
        -------
        recorded : bool
            False when the trial is beyond ``max_trials``.
        """
        if not self._admit(trial):
            return False
        from .geometry.silhouette import silhouette
        from .geometry.superquadric import Superquadric

        rr, stream = self._rr, self._stream
        color = _CHAIN_COLORS[self._chains.setdefault(chain, len(self._chains)) % len(_CHAIN_COLORS)]
        entity = f"trials/{trial}/fits/{chain}/object_{int(object_id)}"
        outlines = [f"trials/{trial}/cameras/view_{v:02d}/fits/{chain}/object_{int(object_id)}"
                    for v in range(len(cameras))]
        for k, stage in enumerate(stages):
            if isinstance(stage, dict):
                name, status, params = stage["name"], stage.get("status", ""), stage.get("params")
                sq = None if params is None else Superquadric.from_vector(np.asarray(params, dtype=np.float64))
            else:
                name, status, sq = stage.name, stage.status, stage.superquadric
            stream.set_time(STAGE_TIMELINE, sequence=k)
            info = rr.AnyValues(stage_name=str(name), stage_status=str(status), chain=str(chain))
            if sq is None:
                stream.log(entity, rr.Clear(recursive=False), info)
                for path in outlines:
                    stream.log(path, rr.Clear(recursive=False))
                continue
            vertices, faces = _superquadric_mesh(sq)
            stream.log(entity, rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces, albedo_factor=color),
                       info)
            for path, cam in zip(outlines, cameras):
                polygon = silhouette(sq, cam, SILHOUETTE_DIRECTIONS)
                if len(polygon):
                    stream.log(path, rr.LineStrips2D([np.vstack([polygon, polygon[:1]])], colors=[color[:3]],
                                                     labels=[f"{chain}: {name}"]))
                else:  # part of the estimate is behind the camera: no outline in this view
                    stream.log(path, rr.Clear(recursive=False))
        stream.reset_time()
        return True
