"""Readers and writers of the field's exchange formats, one module per format.

- :mod:`.coco` — COCO instance masks (RLE or polygons, a ``track_id`` per annotation);
- :mod:`.coco_polygons` — COCO polygons of a mask in the OpenCV (detectron2) or skimage convention;
- :mod:`.colmap` — COLMAP models (pinhole cameras, ``cam_from_world`` poses);
- :mod:`.posejson` — plain JSON pose files;
- :mod:`.tum` — TUM RGB-D trajectories (``t tx ty tz qx qy qz qw``, camera -> world);
- :mod:`.trajectory` — a trajectory as a pose source: user intrinsics, image timestamps, nearest-time match.

Each converts its own conventions to sqfit's once and knows nothing of observations or fits: a
layer below :mod:`sqfit.views`, whose :mod:`sqfit.views.imported` joins a COCO file with a pose
source (named poses, or a TUM trajectory matched by time) into observations of every tracked
object (``sqfit fit --coco FILE --poses PATH``). Modules here import only numpy/scipy at top level;
pycocotools, pycolmap and evo are imported inside the functions that need them: ``import sqfit``
loads none of them.
"""

from .coco import TRACK_KEY, decode_segmentation, encode_mask, read_coco
from .coco_polygons import POLYGON_CONVENTIONS, encode_polygons, mask_to_polygons
from .colmap import read_colmap, write_colmap
from .posejson import read_pose_json, write_pose_json
from .trajectory import match_trajectory, read_image_times, read_intrinsics, write_image_times, write_intrinsics
from .tum import read_tum, write_tum

__all__ = ["TRACK_KEY", "read_coco", "decode_segmentation", "encode_mask", "POLYGON_CONVENTIONS",
           "mask_to_polygons", "encode_polygons", "read_colmap", "write_colmap", "read_pose_json",
           "write_pose_json", "read_tum", "write_tum", "read_intrinsics", "write_intrinsics", "read_image_times",
           "write_image_times", "match_trajectory"]
