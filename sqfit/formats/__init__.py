"""Formats in and out: COCO instance masks, COLMAP models and JSON pose files.

One reader/writer module per format (:mod:`.coco`, :mod:`.colmap`, :mod:`.posejson`), each
converting its own conventions to sqfit's once; :mod:`.importer` joins a COCO file with a pose
source and fits every tracked object (``sqfit fit --coco FILE --poses PATH``). pycocotools and
pycolmap are imported inside the functions that need them: ``import sqfit`` loads neither.
"""

from .coco import TRACK_KEY, decode_segmentation, encode_mask, read_coco
from .colmap import read_colmap, write_colmap
from .importer import POSE_FORMATS, ImportedScene, fit_import, load_import, observe_track, read_poses
from .posejson import read_pose_json, write_pose_json

__all__ = ["TRACK_KEY", "read_coco", "decode_segmentation", "encode_mask", "read_colmap", "write_colmap",
           "read_pose_json", "write_pose_json", "POSE_FORMATS", "read_poses", "ImportedScene", "load_import",
           "observe_track", "fit_import"]
