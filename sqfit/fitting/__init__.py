"""Fitting: costs, stages and the chains that run them (:func:`fit`).

Above :mod:`sqfit.views`. Stages are registered by name in :data:`STAGES` (paper codes: ``1``,
``2``, ``3A``-``3F`` in :mod:`.stages`; ``3G`` in :mod:`.grazing`; ``3S`` in :mod:`.restarts`;
``3H`` in :mod:`.axis_screen`; ``2M`` in :mod:`.moments`; ``3T`` in :mod:`.outline`; ``3TP`` in :mod:`.parts`;
``3V`` in :mod:`.least_volume`; ``3U`` in :mod:`.two_parts`; ``3W`` in :mod:`.weighted_overlap`;
``3R`` in :mod:`.trimmed`; ``HULL`` in :mod:`.hull`),
and a chain is a dash-joined list of them (``"1-2M-3H"``).

- :mod:`.costs` — the paper's costs: R-IOU (G2), the analytic G3-G5, penalty, bounds;
- :mod:`.line_gauge` — where a ray comes closest to a superquadric: the gauge's minimum along lines;
- :mod:`.raycost` — the grazing-ray cost: ray residuals and their Jacobians;
- :mod:`.lm` — Levenberg-Marquardt (dense, Schur-complement and batched);
- :mod:`.stages` — the stage registry, the fit state, the paper's stages;
- :mod:`.moments` — stage 2M: stage 2's ellipsoid from the masks' exact moments;
- :mod:`.grazing` — stage 3G: the superquadric that grazes every outline ray;
- :mod:`.restarts` — stage 3S: symmetric restarts of 3G;
- :mod:`.axis_screen` — stage 3H: choose the axes, then 3G;
- :mod:`.plain_run` — 3H's plain run where its nuisances are idle: sharp edges, square slab sections, boxes below
  the size floor;
- :mod:`.outline` — stage 3T: G2 on the mask contours where 3G's cost is not met;
- :mod:`.parts` — stage 3TP: 3T, kept only where what it lets go is a part (legs, a stand);
- :mod:`.least_volume` — stage 3V: 3TP, then of the fits that match the contours alike
  (3TP's, one of the masks with thin parts opened away) the one of least volume;
- :mod:`.weighted_overlap` — stage 3W (chain ``whole``'s last stage, and the default's where 3U keeps no part):
  where no superquadric matches the masks, a silhouette pixel outside the mask costs twice a mask pixel the
  silhouette misses;
- :mod:`.two_parts` — stage 3U (the default's last stage): 3V, then one of two superquadrics fitted together to
  the opened masks where their union matches them much better (chairs, laptops, monitors), else 3W;
- :mod:`.trimmed` — stages 3R (default chain) and 3RH (chain ``tolerant``, which also ends in 3T without 3TP's
  gate: 3R, then from the visual hull's fit):
  3G without the outline rays no superquadric grazes;
- :mod:`.pointcloud` — an outlier-tolerant superquadric fit to a point cloud (EMS);
- :mod:`.hull` — stage HULL (the visual-hull baseline, chain ``hull``): carve, then the point fit;
- :mod:`.pipeline` — options, results and :func:`fit`.
"""

from . import (axis_screen, grazing, hull, least_volume, moments, outline, parts, restarts, trimmed,  # noqa: F401
               two_parts, weighted_overlap)
# (they register 3H, 3G, HULL, 3V, 2M, 3T, 3TP, 3S, 3R, 3RH, 3U, 3W)
from .pipeline import (CHAIN_ALIASES, DEFAULT_CHAIN, HULL_CHAIN, PAPER_CHAINS, FitOptions, FitResult, StageRecord, fit,
                       parse_chain)
from .stages import STAGES

__all__ = ["fit", "FitOptions", "FitResult", "StageRecord", "DEFAULT_CHAIN", "HULL_CHAIN", "CHAIN_ALIASES",
           "PAPER_CHAINS", "STAGES", "parse_chain"]
