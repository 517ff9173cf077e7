"""Views of an object: what the fitter is given, per camera.

Above :mod:`sqfit.geometry`, :mod:`sqfit.formats` and :mod:`sqfit.kernels`, below :mod:`sqfit.fitting`.

- :mod:`.observation` — :class:`Observation`: one camera and one binary mask, with samples,
  outline, hull and visibility labels;
- :mod:`.visibility` — the labels of outline points (background, another instance, image border);
- :mod:`.rays` — camera rays through outline points, the grazing-ray stages' data;
- :mod:`.carving` — the visual hull: voxel carving of the masks, honouring the labels;
- :mod:`.opening` — a mask's outline with its thin parts (legs, a stand) opened away (stage 3V's bulk fit);
- :mod:`.consistency` — whether the masks agree under the cameras: their epipolar tangents (stage 3W's gate);
- :mod:`.dataset` — reading (and writing masks of) datasets in the ``sqsim generate`` format, and
  observations from instance-id images;
- :mod:`.sequence` — image sequences with odometry (TUM trajectories, lazily read frames);
- :mod:`.imported` — a user's COCO masks joined with COLMAP, JSON or TUM poses.
"""

from .dataset import load_trial, observations_from_images, observe_views, trial_dirs
from .imported import load_import, observe_track, read_poses
from .observation import Observation
from .sequence import Sequence, load_sequence

__all__ = ["Observation", "load_trial", "trial_dirs", "observations_from_images", "observe_views", "Sequence",
           "load_sequence", "load_import", "observe_track", "read_poses"]
