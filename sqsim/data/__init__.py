"""Data on disk: datasets and sequence datasets, their exports, and atomic run files.

Above :mod:`sqsim.imaging`.

- :mod:`.files` — atomic writes, the records of an earlier run, run configurations that resume;
- :mod:`.provenance` — the library versions a run records (which install made its numbers);
- :mod:`.dataset` — trials in the dataset format of :mod:`sqfit.views.dataset`, COCO annotations;
- :mod:`.sequence_dataset` — sequences (frames, TUM trajectories, COCO with track ids);
- :mod:`.export` — COLMAP models and the names shared with COCO exports.
"""
