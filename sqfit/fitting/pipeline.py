"""Chains of stages: :func:`fit`, its options and its result.

A chain is a dash-joined list of stage names (``"1-2-3D-3A"``, see :mod:`sqfit.fitting.stages`). Each stage
refines the previous state; after every stage a snapshot of the superquadric is recorded with its
wall time, cost, optimiser status and R-IOU-M (mean over views of the IoU of the projected
superquadric with the observation polygon, :mod:`sqfit.geometry.silhouette`).

Failures never raise out of :func:`fit`: fewer than 2 observations, a singular triangulation, a
diverging or non-finite optimiser, or any ``LinAlgError`` / floating-point error inside a stage end
the chain with a failure ``status`` and ``message``; ``superquadric`` is then the last good
snapshot (None if there was none). Wrong argument *types* or an unknown stage / option name are
programming errors and raise ``TypeError`` / ``ValueError`` immediately.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import constants as C
from .._checks import Options, check_fields
from .costs import ObservationSet
from ..views.observation import POLYGON_KINDS, Observation
from .grazing import N_CONTOUR
from .hull import HULL_CHAIN
from .stages import (NUMERICAL_ERRORS, STAGES, FitState, StageError, default_state, ellipsoid_depths, r_iou_m,
                     to_superquadric)
from ..geometry.superquadric import Superquadric
from ..views.visibility import BORDER

__all__ = ["fit", "FitOptions", "FitResult", "StageRecord", "PAPER_CHAINS", "DEFAULT_CHAIN",
           "INITIAL_CHAIN", "HULL_CHAIN", "TOLERANT_CHAIN", "WHOLE_CHAIN", "CHAIN_ALIASES", "parse_chain"]

#: The 13 chains of the paper's Table II, in its row order.
PAPER_CHAINS = ("3A", "3B", "1-3A", "1-2-3A", "1-2-3B", "3E", "1-3E", "1-2-3C", "1-2-3D", "1-2-3E",
                "1-2-3D-3E", "1-2-3D-3A", "1-2-3D-3F")
#: 2M: :mod:`sqfit.fitting.moments`; 3H: :mod:`sqfit.fitting.axis_screen` (README "Beyond the paper"); 3R:
#: :mod:`sqfit.fitting.trimmed`, 3G without a stretch of outline rays that sticks out of the fit (a handle, a
#: bottle's neck), acting only where 3H's cost is moderate and the misfit is such a stretch (from the visual
#: hull's fit too where 3H's fit is pinched and its own starts keep nothing: a mug turned to its handle); 3TP:
#: :mod:`sqfit.fitting.parts`, G2 on the mask contours where 3G's cost is high (stage 3T), kept only where
#: what it lets go is such a stretch in several views (a table's legs, a monitor's stand); 3V:
#: :mod:`sqfit.fitting.least_volume`, 3TP, then, where 3T's trigger holds, of 3TP's fit and fits of the masks
#: with their thin parts opened away that match the contours alike, the one of least volume (docs/real-objects.md);
#: 3W: :mod:`sqfit.fitting.weighted_overlap`, where the silhouettes do not match the mask contours (and the
#: masks agree under the cameras, their outlines not offset), the fit of the highest overlap with silhouette pixels
#: outside the mask weighted twice, from the input and cylinder-like starts, then a slab's thickness by the same
#: overlap with the masks' thin parts opened away (a table's legs). :data:`WHOLE_CHAIN` (``whole``): one
#: superquadric for the whole object, the default until 2026-12-02.
WHOLE_CHAIN = "1-2M-3H-3R-3V-3W"
#: The default: :data:`WHOLE_CHAIN` with stage 3U (:mod:`sqfit.fitting.two_parts`) in place of 3V and 3W: 3V, then
#: where its trigger holds (3T's, at half its cost floor) and the masks show two slabs at an angle (chairs,
#: laptops, monitors), one of two superquadrics fitted together to the opened masks, where their union matches
#: them much better; elsewhere 3W as in :data:`WHOLE_CHAIN`, whose fits it keeps bit for bit where it keeps no
#: part. Costs about 1.3-1.5 s of CPU per object where it fits the union (furniture, lamps, toys);
#: docs/real-objects.md, "Stage 3U" and after it.
DEFAULT_CHAIN = WHOLE_CHAIN.removesuffix("-3V-3W") + "-3U"
#: Chain of :func:`fit` when a starting superquadric is given (``initial=``) and no chain is: a
#: local refinement from it.
INITIAL_CHAIN = "3G"
#: The default with stage 3RH in place of 3R (3R, then where none of its re-fits is kept the same from
#: the visual hull's superquadric, pinched input or not) and stage 3T without 3TP's gate
#: (G2 on the mask contours wherever 3G's cost is high: monitors, chairs and laptops gain a little more,
#: noisy masks of true superquadrics can lose); opt-in (the carving runs wherever 3R keeps nothing),
#: measured in docs/real-objects.md.
TOLERANT_CHAIN = WHOLE_CHAIN.replace("-3R-", "-3RH-").removesuffix("-3V-3W") + "-3T"
#: Stage 3U's chain, the default since 2026-12-02 (``two-parts``, its name while it was opt-in).
TWO_PART_CHAIN = DEFAULT_CHAIN
#: Names that stand for a whole chain wherever a chain is given (:func:`parse_chain`); ``hull`` is the
#: visual-hull baseline (:data:`sqfit.fitting.hull.HULL_CHAIN`), ``tolerant`` :data:`TOLERANT_CHAIN`,
#: ``whole`` :data:`WHOLE_CHAIN`, ``two-parts`` :data:`TWO_PART_CHAIN`.
CHAIN_ALIASES = {"default": DEFAULT_CHAIN, "hull": HULL_CHAIN, "tolerant": TOLERANT_CHAIN,
                 "whole": WHOLE_CHAIN, "two-parts": TWO_PART_CHAIN}
#: Values of ``FitOptions.outline_offset``: one outline offset per object, or one per view.
OUTLINE_OFFSETS = ("object", "view")
#: Stages that compute their start from the masks alone and would discard ``initial``.
_SELF_STARTING = ("1", "2", "HULL")


@dataclass(frozen=True)
class FitOptions(Options):
    """Options of :func:`fit` (a dict of these fields is accepted too).

    Attributes
    ----------
    polygon : {"hull", "contour"}
        Observation polygon of the R-IOU costs and R-IOU-M: convex hull of the samples (paper)
        or the full mask contour (slower: shapely).
    penalty_riou : float
        ``c_p`` of the G2 penalty (paper: 1).
    penalty_analytic : float
        ``c_p`` of the G3-G5 penalty (paper: 100).
    max_iterations_numeric, max_iterations_analytic : int
        Levenberg-Marquardt step limits of the R-IOU (3A, 3B, 3F) and G5 (3C-3E) stages.
    ftol_numeric, ftol_analytic : float
        Relative cost-reduction tolerances (per step).
    window_numeric, window_ftol_numeric : int, float
        The R-IOU stages also stop when their cost fell by less than the fraction
        ``window_ftol_numeric`` over the last ``window_numeric`` accepted steps (0 disables):
        G2 tends to end in a long crawl of ~1 % per step that no longer improves the 3D fit
        (README, "Fitter speed").
    atol_analytic : float
        Absolute cost tolerance of the G5 stages (their minimum is 0: every sample on the surface).
    xtol, gtol : float
        Relative step and absolute gradient tolerances.
    fd_step : float
        Forward-difference step of the R-IOU stages, relative to ``max(1, |x_i|)``; well above
        the silhouette solver's precision (1e-7 px).
    damping_numeric : {"identity", "marquardt"}
        Damping matrix of the R-IOU stages' Levenberg-Marquardt (see :mod:`sqfit.fitting.lm`).
    hessian_numeric : {"secant", "gauss-newton"}
        Model Hessian of the R-IOU stages: ``J^T J`` plus a structured secant estimate of the
        second-order term (default; :class:`sqfit.fitting.lm.SecantTerm`), or plain ``J^T J``. G2 has 3
        view residuals for up to 11 unknowns, so ``J^T J`` alone has rank 3 and plain LM crawls.
    riou_jacobian : {"analytic", "numeric"}
        Jacobian of the R-IOU stages (3A, 3B, 3F): analytic (:func:`sqfit.fitting.costs.riou_residuals`,
        hull polygons; contour polygons always use differences), or forward differences of step
        ``fd_step`` as in the paper. Measured in the README ("Fitter speed").
    silhouette_directions : int
        Vertices of the silhouette polygons inside the R-IOU costs (R-IOU-M always uses
        :data:`sqfit.geometry.silhouette.DEFAULT_DIRECTIONS`).
    pose_sigma_deg : float
        Stage 3G: > 0 estimates a small rotation correction per camera with the superquadric,
        held near zero by prior rows ``delta / pose_sigma_deg`` (degrees, relative to 3G's
        per-view-normalised residuals: a stiffness, not a calibrated noise level); 0 trusts the
        poses (see :mod:`sqfit.fitting.grazing`). Default 50: measured with the default chain 1-2-3H
        (2 px jitter + 1 deg rotation, 100 trials: median IoU 0.744 at 20, 0.771 at 50, 0.774 at
        80; clean masks unchanged), README "Robustness". When the corrections estimated under it say
        that the cameras disagree (RMS above ``sqfit.fitting.grazing.POSE_NOISE_TRIGGER_DEG``), 3G and
        3H fit again under a prior scaled to the residual noise at the estimated rotation noise
        (:func:`sqfit.fitting.grazing.silhouette_fit`); this value then only decides that.
    pose_noise_refit : bool
        Whether cameras that disagree (above) make 3G fit again under the noise-scaled prior and
        3H refine every axis candidate under it (default True); False keeps the fit under the fixed
        prior and 3H's refinement of the screen's best candidate (for callers that estimate the
        poses themselves and only need a start: :mod:`sqfit.graph`).
    idle_nuisances_plain : bool
        Stage 3H: where its refinement's pose corrections and outline offset are idle (the cameras
        agree, the offset is within ``sqfit.fitting.axis_screen.IDLE_OFFSET_PX``) and its fit
        grazes the outline (cost at most ``sqfit.fitting.outline.TRIGGER_COST``), take plain 3G
        from its result (default True; :mod:`sqfit.fitting.axis_screen`, step 3: clean masks of
        thin slabs and boxes no longer come out too thick). :mod:`sqfit.graph`'s landmark fits
        keep False: at odometry poses it moved its results without improving them
        (:func:`sqfit.graph.growth.landmark_fit`).
    score_stages : bool
        Score every stage's snapshot by R-IOU-M (:attr:`StageRecord.r_iou_m`; default True), or
        only the result (False: the other stages' ``r_iou_m`` None, for callers that only need the
        result, :mod:`sqfit.graph`'s landmark fits: on a factor graph's fits of 10-12 views the two
        early snapshots cost ~0.8 ms of ~32).
    occlusion_aware : bool
        Use the observations' boundary labels (:mod:`sqfit.views.visibility`): occluded and truncated
        outline stretches are one-sided in 3G (and 3S), stages 1 and 2 down-weight or leave out
        views whose outline is mostly not true silhouette, and the R-IOU costs (3A, 3B, 3F) and
        R-IOU-M count only the visible part of each view. The G5 stages (3C-3E) ignore the labels.
        False treats every outline as a silhouette (as before the labels existed; the "not
        aware" rows of README "Partial visibility").
    outline_offset_sigma_px : float
        Stages 3G and 3H: > 0 estimates the masks' outline offset (px; > 0: the outline lies
        outside the silhouette, a segmenter's over-segmentation) with the superquadric, under a
        Gaussian prior of this standard deviation, px, relative to the noise of the fit's residuals
        (:func:`sqfit.fitting.grazing.offset_prior`); 0 trusts the outlines. The estimate is in
        3G's (3H's) stage record and message and in :attr:`FitResult.outline_offset_px`. Default 0.5 (100
        paper trials, default chain, median / 10th percentile of IoU, seeds 0; 1, README "Real
        masks"): 1 px over-segmentation 0.989 / 0.836; 0.989 / 0.901 (no offset 0.928 / 0.761;
        0.944 / 0.788), 1 px under-segmentation 0.989 / 0.804; 0.991 / 0.850, clean 0.995 / 0.904;
        0.996 / 0.928. Chosen against 1 px (measured while the radius factor of
        :mod:`sqfit.fitting.raycost` was still two-sided): the same on 1 px bias (0.991 / 0.992
        either way) and clean masks, and random outline noise moved the offset less (2 px jitter,
        seed 0: 0.886 against 0.878; 2 px jitter + 1 deg pose noise: 0.768 against 0.757).
    outline_offset : {"object", "view"}
        One outline offset per object (default), or one per view about the object's (prior
        spread ``outline_offset_view_sigma_px``). Per view follows a segmenter whose bias differs
        between views and underestimates a common one (100 paper trials, seeds 0 / 1, median IoU
        per view against per object): bias drawn per object and view with 1 px standard
        deviation, mean 0, 0.979 / 0.980 against 0.905 / 0.929 (no offset 0.911 / 0.937); 1 px
        over-segmentation 0.977 / 0.976 against 0.989 / 0.989; clean 0.995 / 0.994 against
        0.995 / 0.996 (10th percentile 0.892 / 0.920 against 0.904 / 0.928).
    outline_offset_view_sigma_px : float
        With ``outline_offset = "view"``: the standard deviation of each view's offset about the
        object's, px, > 0 (on the 1 px spread above, seed 0, object prior 1 px, two-sided radius
        factor: 0.25 / 0.5 / 1 px gave 0.968 / 0.979 / 0.982, 10th percentile 0.786 / 0.822 / 0.768).
    size_min_m : float
        Lower bound (metres, > 0) of the half-axes in the penalty rows of the silhouette stages
        (3G, 3H's screen and refinement, 3R, 3S; :func:`sqfit.fitting.raycost.ray_bounds`). Default the
        paper's ``constants.SIZE_MIN`` (0.1 m), a prior of its scene (no half-axis below 0.1 m): with
        its three level views the silhouettes leave thin shapes ambiguous, and there a lower bound
        lets fits collapse to slabs that graze every outline as well (``scenes/paper.toml``, seed 0,
        at 0.01 m: 6 of 100 fits changed, 5 worse, one 0.818 -> 0.088). Objects thinner than 0.2 m
        need a lower bound, or the penalty holds the fit thick and rounds its shape to make up for it
        (household books, four elevated views, seed 0: half-thickness 0.061-0.09 m fitted as
        0.100-0.106 m; at 0.01 m 0.067-0.097 m, 3D IoU of those four 0.61-0.86 -> 0.75-0.89; README
        "Real objects").
    n_contour : int
        Outline rays per view of the silhouette stages' grazing cost (3G, 3H's refinement, 3R, 3RH,
        3TP's test; >= 3): points evenly spaced by arc length along each mask's outline
        (:func:`sqfit.views.rays.contour_rays`). Default 64 (:data:`sqfit.fitting.grazing.N_CONTOUR`).
        Fewer rays make a fit with many views faster: on the factor graph's landmark fits (3-12
        views; ``GraphOptions.fit_n_contour``) 32 took about a fifth less CPU than 64.
    """

    polygon: str = "hull"
    penalty_riou: float = C.PENALTY_RIOU
    penalty_analytic: float = C.PENALTY_ANALYTIC
    max_iterations_numeric: int = 60
    max_iterations_analytic: int = 100
    ftol_numeric: float = 1e-5
    window_numeric: int = 5
    window_ftol_numeric: float = 0.02
    ftol_analytic: float = 1e-6
    atol_analytic: float = 1e-12
    xtol: float = 1e-8
    gtol: float = 1e-10
    fd_step: float = 1e-4
    damping_numeric: str = "marquardt"
    hessian_numeric: str = "secant"
    riou_jacobian: str = "analytic"
    silhouette_directions: int = 48
    pose_sigma_deg: float = 50.0
    pose_noise_refit: bool = True
    idle_nuisances_plain: bool = True
    score_stages: bool = True
    occlusion_aware: bool = True
    outline_offset_sigma_px: float = 0.5
    outline_offset: str = "object"
    outline_offset_view_sigma_px: float = 0.5
    size_min_m: float = C.SIZE_MIN
    n_contour: int = N_CONTOUR

    WHAT = "fit"

    def __post_init__(self):
        if self.polygon not in POLYGON_KINDS:
            raise ValueError(f"polygon must be one of {list(POLYGON_KINDS)}, got {self.polygon!r}")
        check_fields(self, integers={"max_iterations_numeric": 1, "max_iterations_analytic": 1, "window_numeric": 0,
                                     "silhouette_directions": 8, "n_contour": 3},
                     nonnegative=("penalty_riou", "penalty_analytic", "ftol_numeric", "ftol_analytic", "atol_analytic",
                                  "xtol", "gtol", "fd_step", "pose_sigma_deg", "outline_offset_sigma_px"))
        if not (np.isfinite(self.size_min_m) and self.size_min_m > 0):
            raise ValueError(f"size_min_m must be a finite number > 0 (metres), got {self.size_min_m}")
        if not (np.isfinite(self.outline_offset_view_sigma_px) and self.outline_offset_view_sigma_px > 0):
            raise ValueError(f"outline_offset_view_sigma_px must be a finite number > 0, got "
                             f"{self.outline_offset_view_sigma_px}")
        if self.outline_offset not in OUTLINE_OFFSETS:
            raise ValueError(f"outline_offset must be one of {list(OUTLINE_OFFSETS)}, got {self.outline_offset!r}")
        if self.damping_numeric not in ("identity", "marquardt"):
            raise ValueError(f"damping_numeric must be 'identity' or 'marquardt', got {self.damping_numeric!r}")
        if self.hessian_numeric not in ("secant", "gauss-newton"):
            raise ValueError(f"hessian_numeric must be 'secant' or 'gauss-newton', got {self.hessian_numeric!r}")
        if not 0 <= self.window_ftol_numeric < 1:
            raise ValueError(f"window_ftol_numeric must be in [0, 1), got {self.window_ftol_numeric}")
        if self.riou_jacobian not in ("analytic", "numeric"):
            raise ValueError(f"riou_jacobian must be 'analytic' or 'numeric', got {self.riou_jacobian!r}")
        if self.fd_step <= 0:
            raise ValueError(f"fd_step must be > 0, got {self.fd_step}")
        for name in ("occlusion_aware", "pose_noise_refit", "idle_nuisances_plain", "score_stages"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")


@dataclass
class StageRecord:
    """One stage of a fitted chain.

    Attributes
    ----------
    name : str
    superquadric : Superquadric or None
        Snapshot after the stage (None if the stage failed).
    seconds : float
        Wall time of the stage.
    cost : float or None
        Final ``0.5 * sum r**2`` of the stage's optimiser; None for closed-form stages (1, 2).
    status : str
        ``"ok"`` for closed-form stages, an optimiser status (:data:`sqfit.fitting.lm.STATUS`), or a
        failure code.
    message : str
    r_iou_m : float or None
        R-IOU-M of the snapshot (None but for the last stage's with ``FitOptions.score_stages`` False).
    nfev : int
        Cost evaluations (finite-difference columns included).
    outline_offset_px : list of float or None
        The outline offset that goes with the snapshot (px, as :attr:`FitResult.outline_offset_px`):
        the stage's estimate (3G, 3H), the input's where the stage passed its input on unchanged,
        None otherwise.
    """

    name: str
    superquadric: Superquadric | None
    seconds: float
    cost: float | None
    status: str
    message: str
    r_iou_m: float | None = None
    nfev: int = 0
    outline_offset_px: list | None = None

    def to_dict(self):
        d = asdict(self)
        d["superquadric"] = None if self.superquadric is None else self.superquadric.to_vector().tolist()
        return d


@dataclass
class FitResult:
    """Result of :func:`fit`.

    Attributes
    ----------
    superquadric : Superquadric or None
        Final (or last good) superquadric.
    stages : list of StageRecord
    status : str
        ``"ok"`` or the failure code of the stage that ended the chain (``too_few_views``,
        ``singular_triangulation``, ``triangulation_behind_camera``, ``diverged``, ``nonfinite``,
        ``numerical_error``).
    message : str
    cost : float or None
        Final cost of the last optimising stage.
    r_iou_m : float or None
        R-IOU-M of ``superquadric``.
    seconds : float
        Wall time of the whole call, R-IOU-M evaluation included.
    chain : str
    warnings : list of str
    outline_offset_px : list of float or None
        The masks' outline offset estimated with the final superquadric (3G, 3H; px, > 0: the
        outlines lie outside the silhouettes; one value per object or per view,
        ``FitOptions.outline_offset``): the last stage's ``outline_offset_px``. None if no stage
        estimated one, or if a later stage changed the fit without estimating one (stage 3R's
        trimmed re-fit keeps no offset).
    """

    superquadric: Superquadric | None
    stages: list = field(default_factory=list)
    status: str = "ok"
    message: str = ""
    cost: float | None = None
    r_iou_m: float | None = None
    seconds: float = 0.0
    chain: str = ""
    warnings: list = field(default_factory=list)
    outline_offset_px: list | None = None

    @property
    def ok(self):
        return self.status == "ok"

    def to_dict(self):
        """A JSON-serialisable dict (parameter vectors as lists)."""
        return {
            "chain": self.chain,
            "status": self.status,
            "message": self.message,
            "params": None if self.superquadric is None else self.superquadric.to_vector().tolist(),
            "cost": self.cost,
            "r_iou_m": self.r_iou_m,
            "seconds": self.seconds,
            "warnings": list(self.warnings),
            "outline_offset_px": None if self.outline_offset_px is None else list(self.outline_offset_px),
            "stages": [s.to_dict() for s in self.stages],
        }


def parse_chain(chain):
    """``"1-2-3D-3A"`` -> ``["1", "2", "3D", "3A"]``; a name of :data:`CHAIN_ALIASES` stands for its chain
    (``"hull"`` -> ``["HULL"]``); unknown names raise ValueError listing valid ones."""
    if isinstance(chain, str) and chain.strip() in CHAIN_ALIASES:
        chain = CHAIN_ALIASES[chain.strip()]
    if isinstance(chain, (list, tuple)):
        names = [str(s) for s in chain]
    elif isinstance(chain, str):
        names = [s.strip() for s in chain.split("-")]
    else:
        raise TypeError(f"chain must be a string like '1-2-3D-3A', got {type(chain).__name__}")
    bad = [s for s in names if s not in STAGES]
    if not names or bad:
        raise ValueError(f"unknown stage(s) {bad} in chain {chain!r}; valid stages: {sorted(STAGES)}")
    return names


def _check_observations(observations):
    """A list of Observation (TypeError otherwise); an ObservationSet passes through."""
    if isinstance(observations, ObservationSet):
        return observations.observations
    if isinstance(observations, (Observation, str, bytes)) or not hasattr(observations, "__iter__"):
        raise TypeError(f"observations must be a list of sqfit.Observation, got {type(observations).__name__}")
    obs = list(observations)
    for i, o in enumerate(obs):
        if not isinstance(o, Observation):
            raise TypeError(f"observations[{i}] must be a sqfit.Observation, got {type(o).__name__}")
    return obs


def _check_initial(initial, names):
    """``initial`` as an ``(11,)`` vector (None passes through); see :func:`fit`."""
    if initial is None:
        return None
    if isinstance(initial, (str, bytes, dict)) or not (isinstance(initial, Superquadric)
                                                       or hasattr(initial, "__len__")):
        raise TypeError(f"initial must be a sqfit.Superquadric or an (11,) parameter vector, "
                        f"got {type(initial).__name__}")
    if not isinstance(initial, Superquadric):
        try:
            initial = Superquadric.from_vector(initial)
        except ValueError as exc:
            raise ValueError(f"initial: {exc}") from None
    if names[0] in _SELF_STARTING:
        raise ValueError(f"initial is given but chain {'-'.join(names)!r} starts with stage {names[0]!r}, which "
                         f"computes its own start from the masks and would discard it; use a chain of "
                         f"refining stages such as {INITIAL_CHAIN!r}")
    return initial.to_vector()


def _start(obs, initial):
    """The first stage's input: the default guess, or ``initial`` with depths on its quadric."""
    if initial is None:
        return default_state(obs)
    return FitState(initial.copy(), sample_depths=ellipsoid_depths(initial, obs))


def visibility_warnings(observations, views=None):
    """Warnings about truncated or occluded views (list of str, one per affected view).

    ``views`` names the view of each observation (default: its position in the list)."""
    out = []
    views = range(len(observations)) if views is None else views
    for i, o in zip(views, observations):
        if o.touches_border:
            out.append(f"view {i}: mask touches the image border (truncated silhouette; "
                       f"{np.mean(o.contour_labels == BORDER):.0%} of the outline labelled border)")
        if o.partial and o.silhouette_fraction == 0.0:
            out.append(f"view {i}: all of the outline is labelled occluded or truncated (no true silhouette "
                       "edge): the view says where the object is, not where it ends")
    return out


def fit(observations, chain=None, *, initial=None, rng=None, options=None):
    """Fit a superquadric to multi-view observations of one object with a chain of stages.

    Parameters
    ----------
    observations : list of Observation
        One per view, >= 2 (fewer gives status ``too_few_views``).
    chain : str or list of str, optional
        Stage names joined by ``-`` (see :mod:`sqfit.fitting.stages`), e.g. ``"1-2-3D-3A"``, or a name of
        :data:`CHAIN_ALIASES` (``"default"``, ``"hull"``: the visual-hull baseline, ``"tolerant"``: the
        default with stage 3RH in place of 3R and 3T in place of 3V). Default
        :data:`DEFAULT_CHAIN`, or :data:`INITIAL_CHAIN` when ``initial`` is given.
    initial : Superquadric or (11,) float, optional
        Start of the first stage instead of the default guess (a unit sphere at the origin): e.g.
        a SLAM back-end's current estimate, or the ground truth to measure what a chain's search
        loses. Stages that need depths get the closed-form depths on its quadric
        (:func:`sqfit.fitting.stages.ellipsoid_depths`). A vector is validated as
        :meth:`Superquadric.from_vector`. The chain must not start with stage ``1`` or ``2``,
        which compute their own start from the masks.
    rng : None, int or numpy.random.Generator
        Accepted for interface stability; every stage is deterministic today.
    options : FitOptions or dict, optional

    Returns
    -------
    result : FitResult

    Raises
    ------
    TypeError
        If ``observations`` is not a list of Observation, ``initial`` is neither a Superquadric nor
        a vector, or ``options`` has the wrong type.
    ValueError
        For an unknown stage or option name, an invalid option value, an invalid ``initial``, or
        ``initial`` with a chain that starts with stage 1 or 2.
    """
    t0 = time.perf_counter()
    if chain is None:
        chain = DEFAULT_CHAIN if initial is None else INITIAL_CHAIN
    names = parse_chain(chain)
    initial = _check_initial(initial, names)
    options = FitOptions.coerce(options)
    np.random.default_rng(rng)  # validates rng
    obs_list = _check_observations(observations)
    chain_str = "-".join(names)
    warnings = list(getattr(observations, "warnings", ()))
    views = getattr(observations, "views", None)
    warnings += visibility_warnings(obs_list, views if views is not None and len(views) == len(obs_list) else None)
    result = FitResult(None, chain=chain_str, warnings=warnings)
    if len(obs_list) < 2:
        result.status, result.message = "too_few_views", f"need >= 2 observations, got {len(obs_list)}"
        result.seconds = time.perf_counter() - t0
        return result
    if not options.occlusion_aware and any(o.partial for o in obs_list):
        obs = ObservationSet([o.without_labels() for o in obs_list])
    else:
        obs = observations if isinstance(observations, ObservationSet) else ObservationSet(obs_list)
    state = None
    snapshots = []
    for name in names:
        ts = time.perf_counter()
        start = state if state is not None else _start(obs, initial)
        try:
            with np.errstate(all="ignore"):
                new = STAGES[name](start, obs, options)
            sq = to_superquadric(new.xi)
        except StageError as exc:
            status, message, new, sq = exc.status, exc.message, None, None
        except NUMERICAL_ERRORS as exc:
            status, message, new, sq = "numerical_error", f"stage {name}: {type(exc).__name__}: {exc}", None, None
        else:
            status, message = new.status, new.message
        seconds = time.perf_counter() - ts
        offsets = None if new is None or new.outline_offsets is None else np.asarray(new.outline_offsets).tolist()
        result.stages.append(StageRecord(name, sq, seconds, None if new is None else new.cost, status,
                                         message, None, 0 if new is None else new.nfev, offsets))
        if new is None:
            result.status, result.message = status, message
            break
        state = new
        snapshots.append(sq)
        result.superquadric, result.cost = sq, new.cost
        result.outline_offset_px = None if offsets is None else list(offsets)
    if snapshots:
        scored = [r for r in result.stages if r.superquadric is not None]
        if not options.score_stages:
            snapshots, scored = snapshots[-1:], scored[-1:]
        scores = r_iou_m(snapshots, obs, options.polygon)
        for rec, s in zip(scored, scores):
            rec.r_iou_m = float(s)
        result.r_iou_m = float(scores[-1])
        if result.r_iou_m < C.POOR_FIT_R_IOU_M:
            result.warnings.append(f"poor fit: its silhouettes match the masks with R-IOU-M {result.r_iou_m:.3f} "
                                   f"(< {C.POOR_FIT_R_IOU_M}); the superquadric is very likely wrong")
    if result.status == "ok":
        result.message = f"chain {chain_str} finished: last stage {result.stages[-1].status}"
    result.seconds = time.perf_counter() - t0
    return result
