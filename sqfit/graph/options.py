"""Options of the graph methods (:class:`GraphOptions`), their landmark chain and batch starts
(numpy only; the inputs and results: :mod:`sqfit.graph.problem`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import constants as C
from .._checks import Options, check_fields
from .shapevar import KINDS as SHAPE_VARIABLES

__all__ = ["INIT_CHAIN", "BATCH_STARTS", "MIN_FRAMES", "GraphOptions"]

#: The landmarks' fitting chain: the fitter's default without its stage 3R
#: (:mod:`sqfit.fitting.trimmed`; why 3R's gate lets odometry-pose misfits through was not
#: analysed; with 3R, the batch on the evaluation scenes (``scenes/sequence-eval*.toml``, 12
#: sequences, one run each) changed 2 sequences, both worse (median object IoU 0.853 -> 0.809,
#: 0.873 -> 0.837), object IoU 0.863 -> 0.850, CPU median 2.31 -> 2.63 s), then stage 3T
#: (:mod:`sqfit.fitting.outline`): where no superquadric grazes the outline (a table's legs, a
#: lamp's stand) the landmark starts from the fit that overlaps the mask contours best, and its
#: silhouette factors are bounded (``GraphOptions.mismatch_ray_k``). 3T acts only above its 3G
#: cost gate, which superquadric masks stay below.
INIT_CHAIN = "1-2M-3H-3T"

#: How the batch reaches the whole graph (``GraphOptions.batch_start``).
BATCH_STARTS = ("isam2", "windows")

#: Fewest frames an object must be seen in to be fitted (a single silhouette fixes no depth).
MIN_FRAMES = 2


@dataclass(frozen=True)
class GraphOptions(Options):
    """Options of the graph methods (:mod:`sqfit.graph.solve`).

    Attributes
    ----------
    n_contour : int
        Rays per (frame, object) silhouette factor, >= 3.
    final_n_contour : int
        The batch's last solves use this many rays per silhouette factor (0: ``n_contour``) on the
        landmarks that fit their masks (not bounded, ``mismatch_ray_k``, nor scaled by their
        misfit, ``misfit_sigma``: :meth:`sqfit.graph.growth.Growth.resampled`); the iSAM2 start, the
        re-fits' misfits and the ``graph-isam2`` method keep ``n_contour``. Default
        64: the last solves are a small part of the batch's time, and the iSAM2 start left the graph
        short of silhouette information, not of iterations (twice the rays sample each outline twice
        as densely and, each ray's residual weighted as one measurement, weigh twice as much against
        the odometry). On the evaluation scenes (docs/slam-history.md "Issue 23, twelfth pass", seeds
        0-5, 108 runs) the ATE median fell from 0.0071-0.0081 to 0.0056-0.0058 m, every run within
        0.015 m (largest 0.0121 against 0.0155 m), the object IoU's 10th percentile rose from
        0.957-0.958 to 0.967-0.974, at about the same CPU; 128 rays gained little more (seeds 0-1:
        ATE median 0.0054 m). A lower ``silhouette_sigma`` at 32 rays, the same weight without the
        extra rays, did not (ATE median 0.0069 m but 3 of 36 runs above 0.015 m). Household
        sequences: pooled object IoU as before (0.463 / 0.475 against 0.443 / 0.509), but one
        sequence of tables and chairs ran off (ATE 0.32-0.34 m against 0.107 m).
    silhouette_sigma : float
        Standard deviation of one ray residual ``phi`` of a good mask (unitless: about the contour
        error over the object's image radius), > 0. Default 0.03: ~4x the pixelisation error of the
        synthetic sequences' exact masks (0.008), for errors correlated along the outline. Compared
        during development with 0.02 and 0.05 on 3 seeds of 20-frame, 3-object sequences (batch):
        mean ATE 0.029 / 0.023 / 0.020 m, per-sequence median IoU 0.85-0.95 for all three.
    huber_k : float
        Huber threshold per row, > 0: a factor whose RMS whitened ray residual exceeds ``huber_k``
        is down-weighted as a whole (a bad mask), not ray by ray.
    odometry_sigma_deg, odometry_sigma_m : float
        Standard deviations of a ``BetweenFactorPose3`` (per frame step), degrees and metres.
    prior_sigma_deg, prior_sigma_m : float
        Prior on frame 0's pose, at the first odometry pose.
    final_prior_sigma_deg, final_prior_sigma_m : float or None
        Frame 0's prior in the batch's last solves (after the re-fit), > 0; None: ``prior_sigma_deg``,
        ``prior_sigma_m``. Frame 0's pose defines the world frame, in which the floor (``floor_z``)
        is given, and the floor measures the map's scale only through frame 0's height above it: at
        the prior's 1 mm and 0.01 deg the map could slide along its scale about a point on the floor,
        so a longer run's odometry leaked its scale error into the map (``scenes/sequence.toml``,
        laps over one path, seeds 5-24: the map's scale error grew from 3.2e-4 at 40 frames to
        4.5e-4 at 160, the ATE by 0.67 mm on average). With frame 0 at 0.1 mm and 0.001 deg in the
        last solves: 2.1e-4 to 3.1e-4, the ATE by 0.25 mm, and every length better than before (ATE
        medians 5.9 / 6.2 / 6.2 mm at 40 / 80 / 160 frames against 6.1 / 7.3 / 6.8; with
        ``final_first_view_sigma_scale`` too, 6.1 / 6.1 / 6.0 mm, no longer worse with length). Only
        in the last solves: throughout the graph it also tightened iSAM2's, and one evaluation
        sequence's iSAM2 runs 1e-9 apart then parted by 6 mm (docs/slam-history.md, thirty-second
        pass).
    final_first_view_sigma_scale : float
        The silhouette noise of frame 0's views, of the landmarks that fit their masks, in the batch's
        last solves, as a multiple of the others', > 0 (1: as the others). With the floor, frame 0's
        view is what ties the known first pose to the landmarks the floor holds, so it carries the
        map's scale against the odometry's; ``silhouette_sigma`` is set for errors correlated along
        an outline, four times the pixels' own, and at it the odometry still took a share of its scale
        error that grew with the run (``scenes/sequence.toml``, seeds 5-24: 0.05 / 0.09 / 0.17 at
        40 / 80 / 160 frames; at 0.5: 0.03 / 0.06 / 0.11, the ATE at 160 frames 0.03 mm from that at
        40 instead of 0.25 mm; docs/slam-history.md, thirty-second pass).
    init_frames, init_parallax_deg : int, float
        A landmark is initialised by :func:`sqfit.fit` (chain ``init_chain``) from the first frames
        that see it: at least ``init_frames`` (>= 2) and until the parallax of its mask centroid
        between the first and the last of them reaches ``init_parallax_deg`` (all its frames if it
        never does). Silhouettes from a short baseline fix the size and depth poorly.
    init_retries, init_min_overlap : int, float
        An initial fit whose silhouettes overlap its masks with R-IOU-M below ``init_min_overlap``
        (3G's far, huge minimum) is not put in the graph: the landmark waits for its next frame and
        is fitted again until a fit is no longer poor (``sqfit.constants.POOR_FIT_R_IOU_M``), at most
        ``init_retries`` times (>= 0), then starts from the best of its fits
        (:mod:`sqfit.graph.growth`), unless that is still below ``init_min_overlap``: it is then
        fitted again each time its frames have doubled (at its last frame it starts from the best);
        0: it starts from its first fit, however poor. Default 0.1:
        the far, huge fits on the evaluation scenes overlap 0.001-0.05, while the first fits of
        objects no superquadric follows (tables, chairs) overlap 0.3-0.6 and gain nothing from
        waiting (household sequences, seeds 0 / 1, graph median IoU over two 1e-9 perturbations:
        0.249 / 0.504 and 0.331 / 0.513 at 0.5, against 0.387 / 0.589 and 0.252 / 0.539 without
        waiting and 0.347 / 0.600 and 0.267 / 0.543 at 0.1; docs/slam-history.md "Issue 23, fourth pass").
    init_chain : str
        Default :data:`INIT_CHAIN`.
    fit_n_contour : int
        Outline rays per view of the landmarks' first fits and of the axis check's 3G
        (``FitOptions.n_contour``), and of every fit of the ``graph-isam2`` method, >= 3. Default
        64, the fitter's. Every fit on 32 made the batch 6-10 % faster than every fit on 64 at the
        same ATE and object IoU on the evaluation scenes, but a household sequence of the unseen
        seeds then ran off in one run of four, and iSAM2's runs spread more than the stability
        target allows: a first fit is taken as it is (docs/slam-history.md "Issue 23,
        twenty-second pass").
    batch_refit_n_contour : int
        The same for the batch's re-fits (:func:`sqfit.graph.refit.refit_landmarks`: at its iSAM2
        start's rebuilds, after that start and in its last check), >= 3; the ``graph-isam2``
        method's re-fits use ``fit_n_contour``. Default 32, as the graph's own factors: a re-fit
        replaces its landmark only where it fits the masks better, so coarser rays cost no map. On
        the evaluation scenes the batch took 1-5 % less CPU at the same accuracy (run for run: 0.951
        on seeds 0-3, 0.986 on seeds 4-7), and its household maps were as good; for iSAM2 the same
        made its runs spread beyond the stability target (docs/slam-history.md "Issue 23,
        twenty-second pass").
    mismatch_ray_k : float
        A landmark whose initial fit had to leave the grazing cost (stage 3T moved it:
        :func:`sqfit.graph.landmark.left_grazing`; tables, lamps, monitors) gets silhouette factors
        whose every ray's whitened residual is bounded by this
        (:func:`sqfit.graph.landmark.bounded_residuals`), so the rays along its legs or stand do
        not drag it back to the fit that grazes them (until a re-fit grazes: ``Growth.refitted``); 0: none.
    batch_pose_noise_refit : bool
        :attr:`sqfit.FitOptions.pose_noise_refit` of the batch's landmark fits (initial and
        re-fit; iSAM2's initial fits and the ``fixed`` baseline keep the fitter's default, True).
        Default False: at odometry poses the cameras disagree, and the fitter's answer to that (3G
        again under a noise-scaled pose prior, 3H refining all six axis candidates) cost a third
        of the batch's time, while the graph estimates the poses itself (evaluation scenes, 36
        runs: CPU median 3.89 -> 2.62 s, ATE median 0.041 -> 0.038 m, object IoU median / 10th
        percentile 0.863 / 0.701 -> 0.871 / 0.700). iSAM2, which never re-fits, lost with it
        (ATE median 0.046 -> 0.052 m, IoU 10th percentile 0.497 -> 0.475). docs/slam-history.md "Speed, issue 23".
    bounds_weight : float
        ``c_p`` of the size/shape bound penalty (eq. 7), >= 0.
    landmark_prior_sigma_deg, landmark_prior_sigma_m, shape_prior_sigma : float
        Weak priors on each landmark's pose and size/shape vector at its initial fit (degrees,
        metres, metres or unitless): they fix what a symmetric shape leaves unobserved.
    shape_variable : str
        How the graph stores a landmark's size/shape (:mod:`sqfit.graph.shapevar`): ``"plain"``
        the vector ``[ax, ay, az, e1, e2]`` itself, ``"log"`` log sizes and logistic exponents, so
        that every value of the variable is a valid superquadric (the priors, the relinearisation
        thresholds and iSAM2's steps then act on those units). Measured on the evaluation scenes
        (docs/slam-history.md "Issue 23, twelfth pass"): ``log`` did not steady the ``graph-isam2``
        method (7 sequences of 24 beyond a stability limit against 5) and slowed its updates
        (median 20-23 ms against 13-14), and the batch's gain on seeds 0-3 (72 of 72 runs at most
        0.015 m against 69) was lost on seeds 4-5 (34 of 36 against 36); the household maps were
        worse too (pooled object IoU 0.421 against 0.443 / 0.509), so the default is ``"plain"``.
    box_sigma_px : float
        Standard deviation of a box side, pixels (quadric baseline).
    batch_start : str
        How the batch reaches the whole graph before its re-fit and last solve. ``"isam2"`` (the
        default): iSAM2 frame by frame, as the ``graph-isam2`` method (with its rebuilds,
        ``isam2_rescale_parallax_deg``), the batch's own initial fits (``batch_pose_noise_refit``).
        ``"windows"``: Levenberg-Marquardt over growing windows (``batch_window``,
        ``batch_free_frames``, ``batch_past_views``, ``window_relative_tolerance``). Measured on the
        evaluation scenes (docs/slam-history.md "Issue 23, fifth pass"): the windows' result hinged on rounding
        in their first solves; from iSAM2 the spread between runs 1e-9 apart fell fourfold. With a
        floor, ``batch_odometry_chi2`` guards against iSAM2 running off; a start from iSAM2 that
        fails (a solver error) is solved again from windows.
    batch_odometry_chi2 : float
        With a floor (``floor_z``), a batch from iSAM2 whose solution disagrees with the odometry
        beyond this mean chi-square per step (:func:`sqfit.graph.solve.odometry_chi2`; about 6, its
        degrees of freedom, when the odometry noise model holds) is solved again from windows, and
        the lower-error solution kept. Measured with the scenes' true odometry noise as the model:
        evaluation sequences 4.6-5.1 (4 sequences, from iSAM2 and from windows alike); household
        sequences with the floor, from iSAM2 6.3-24 (at 24 and 10.4 iSAM2's undamped steps had run
        off: ATE 1.9 and 0.49 m, from windows 0.11 and 0.35 m), from windows 7.2-7.9. Only with a
        floor, where that failure was seen: an odometry noise model tighter than the truth (the
        defaults' 5 mm against the scenes' 2.5 cm) raises the chi-square of every solution, and the
        test would then solve twice.
    batch_window : int
        With ``batch_start = "windows"``, the batch solve adds this many frames at a time and solves the graph so far by
        Levenberg-Marquardt from the previous solution (0: all frames at once from the odometry).
        Measured: from dead-reckoned odometry, late frames' silhouettes miss their objects by more
        than the objects' size and one solve of the whole sequence can end in a wrong minimum.
    batch_free_frames : int
        The window solves before the last re-optimise only the poses of the last
        ``batch_free_frames`` frames (the new window's included) and the landmarks those frames see;
        the earlier poses and the other landmarks stay at their estimate, the older views of the
        re-optimised landmarks enter linearised (:func:`sqfit.graph.fixedlag.condition_on_past`), so
        a window's cost does not grow with the frames before it. The last window solves the whole
        graph. 0: every window solves the whole graph (the cost grows with the square of the length).
    batch_past_views : int
        In those window solves, each re-optimised landmark's older views (those of the fixed
        frames) enter as at most this many linearised views, evenly spread over them and weighted
        to count as all of them (:func:`sqfit.graph.fixedlag.condition_on_past`): without a bound,
        a window's cost grows with the landmark's history, so the batch's with the square of the
        length. 0: all of them. Default 20: on the evaluation scenes (45-50 frames) no window
        has more (their results unchanged); at 12 their 36 runs moved within their spread (scale-
        aligned IoU 10th percentile 0.949 -> 0.934) for the same CPU.
    window_relative_tolerance : float
        Relative error decrease at which the solves of the windows before the last stop: they only
        bring the new frames near (measured, 3 seeds of the benchmark: 0.03 instead of 1e-3 cut the
        batch time by a third at the same accuracy). So does the first solve of the whole graph
        (the last window), before the re-fit.
    final_relative_tolerance : float
        Relative error decrease at which the batch's last solve (after the re-fit) stops. The
        trajectory's scale and the map's place are fixed only by the odometry and the prior on
        frame 0 (silhouettes are scale-free), so the optimum sits at the end of a long, nearly
        flat valley that Levenberg-Marquardt descends in steps of far less than 0.1 % of the error:
        1e-3 stops part way, at a point that depends on rounding. Where speed matters more, 1e-4
        (evaluation scenes, 96 runs beside the default: about 5 % less batch CPU, the same pooled
        medians of object IoU and ATE, the largest spreads over 3 runs per sequence 0.0023 m / 0.012
        against 0.0015 m / 0.007; docs/slam-history.md, "Issue 23, twenty-third pass").
    final_max_lambda : float
        Largest Levenberg-Marquardt damping of those last solves, > 0. They start at a solution
        and take near Gauss-Newton steps (accepted at a damping of 1e-6 or less, each success
        dividing it by 10); once no step lowers the error, GTSAM raises the damping tenfold per
        trial, each trial an evaluation of the whole graph, and stops at this bound (GTSAM's
        default: 1e5): from 1e-9 that was 14 rejected evaluations per solve. At 0.1 they end
        after ~8, at the same result on 32 of the evaluation scenes' 36 runs (at 1e-3, 11 of 12
        unperturbed runs: a last solve needed a larger damping).
    refit_misfit : float
        After the batch solve, a landmark whose RMS whitened ray residual is above this (a poor
        local minimum: its silhouettes disagree) is re-initialised by :func:`sqfit.fit` on all its
        frames at the solved poses, kept if it fits better, and the graph solved again; so is a
        landmark whose silhouettes barely overlap its masks (R-IOU-M below
        ``sqfit.constants.POOR_FIT_R_IOU_M``: 3G's "far, huge" minimum, whose misfit is low), kept
        if it overlaps more; 0 disables both. The batch's check after its last solve re-fits for
        the misfit only with ``axis_check_frames`` 0.
    refit_max_frames : int
        The overlap test and the re-initialising fit of the re-fit use at most this many of the
        landmark's frames, evenly spread over them (their cost then does not grow with the
        sequence); 0: all its frames.
    axis_check_frames : int
        The batch's check after its last solve first tests every landmark's axes, whatever its
        misfit up to ``misfit_sigma`` (:func:`sqfit.graph.refit.reorient_landmarks`): stage 3H's
        screen from the landmark and its five symmetric re-parametrisations on up to this many of
        its frames; where another choice screens below 0.9 of its own, 3G from that choice on up
        to ``refit_max_frames`` frames replaces it if its misfit is lower. The check then re-fits
        no landmark for its misfit (only for its overlap): those re-fits from scratch had kept 1
        of 23 on eight sequences, at 0.13 s per sequence, about what the axis test costs. 0: no
        axis test, and the check re-fits above ``refit_misfit`` as before. Measured on the
        evaluation scenes (docs/slam-history.md "Issue 23, twenty-first pass"): batch ATE median
        0.0061 -> 0.0053 m (seeds 0-3), the largest spread of a sequence's ATE over 3 runs
        0.0049 -> 0.0010 m (seeds 4-7), CPU +2.5-5 %.
    batch_rebuild_refit_misfit : float
        In the batch's iSAM2 start, iSAM2's rebuilds (``isam2_refit``) re-fit a landmark for its
        misfit only above this (for its overlap as always); the batch's re-fit after the start (none
        when the last rebuild came at the last frame) and its check after the last solve keep
        ``refit_misfit``, and so does the ``graph-isam2`` method, which re-fits at its rebuilds
        only. 0: ``refit_misfit``. Those rebuilds come mid-sequence, at poses that are still moving,
        where a misfit of 0.5-0.75 is largely the poses' error: on 10 evaluation sequences (seeds
        0-1, one run each) the rebuilds re-fitted 80 landmarks at such misfits (~35 ms a fit, ~0.33
        s per sequence) and kept 22, 9 of them for less than 5 % of misfit. Default 0.75
        (docs/slam-history.md "Issue 23, seventeenth pass"; evaluation scenes, 3 runs per sequence,
        against 0.5): seeds 0-3 (72 runs) object IoU median / 10th percentile 0.988 / 0.970 either
        way, ATE median 0.0059 against 0.0058 m, largest 0.0097 against 0.0104 m; unseen seeds 4-7
        (72 runs) 0.987 / 0.965 against 0.989 / 0.968, ATE median 0.0063 against 0.0058 m, largest
        0.0111 against 0.0107 m; every sequence within the stability limits in both; the growth
        scene (``scenes/sequence.toml``, seeds 0-4 at 40 / 80 / 160 frames) a little worse, ATE
        median 0.3-0.4 mm higher and the object IoU's 10th percentile 0.006-0.013 lower; CPU per run
        x0.84-0.91 (the median per-run ratio, the two settings alternating on each sequence in one
        process: x0.91 alone on the machine, x0.84 / x0.87 with a second such process beside it).
        Measured and left: ``refit_misfit`` 0.75 everywhere (CPU x0.82, but object IoU 10th
        percentile 0.953 and the largest ATE 0.0136 m on seeds 0-3) and only in the check (unseen
        orbit 4/1 back at 0.0187 m in two of three runs: the check's misfit re-fit is what holds it
        at 0.009 m); 1.0 at the rebuilds saved no more than 0.75. Household sequences (15 of seeds
        0-4, 4 runs each): object IoU pooled over all runs 0.488 against 0.476, one run above 0.2 m
        against two; on the 6 of the unseen seeds 5-6 (8 runs each) 0.435 against 0.449, three runs
        above 0.2 m against none, 6 of 8 runs at the issue's target against 8.
    rescale : bool
        Before the batch's last solve, move the solution along the scale direction to the best
        scale (:mod:`sqfit.graph.scale`: the silhouettes are scale-free, so the error along it comes
        from the odometry alone and Levenberg-Marquardt descends that valley slowly).
    isam2_relinearize_threshold : float
        iSAM2 relinearises a camera pose when its update exceeds this (tangent-space norm: radians
        and metres).
    isam2_landmark_relinearize_threshold : float
        The same for the landmarks' variables (pose; size/shape in metres and exponent units;
        outline offset) in the ``graph-isam2`` method. A relinearised landmark re-evaluates every
        view that sees it, a camera only its own few, so the landmarks' threshold sets most of an
        update's cost: at 0.03 against 0.01 the update median on the evaluation scenes fell by a
        quarter, with no loss of accuracy or stability beyond the runs' chance (docs/slam-history.md,
        "Issue 23, ninth pass").
    batch_landmark_relinearize_threshold : float
        The landmarks' threshold in the batch's iSAM2 start. The batch runs offline and its
        household maps lost accuracy at 0.03 (pooled object IoU 0.40 against 0.44-0.51, the largest
        ATE 0.40 against 0.18 m; the evaluation scenes' batch 10 % faster, as accurate), so it
        keeps the cameras' 0.01.
    batch_landmark_damping_sigma : float
        > 0: in the batch's iSAM2 start, each new landmark's size/shape also gets a Gaussian prior
        of this standard deviation (metres and exponent units) at its initial fit, dropped at the
        next rebuild and before the batch's last solves; 0 (the default): none. iSAM2 takes one
        undamped Gauss-Newton step per frame, and a landmark seen in 2-5 frames has size/exponent
        directions its silhouettes barely fix, held only by ``shape_prior_sigma``: on an evaluation
        sequence one such step took a landmark's (a_y, e2) from (0.45, 1.66) to (-5.3, -4.4), off
        the bound penalty (zero inside the bounds, so invisible to a step taken from inside) and
        back, and runs 1e-9 apart parted there (``scripts/graph_divergence.py``). At 0.1 the
        evaluation scenes' batch was a little steadier (71 of 72 runs at most 0.015 m against 69,
        the same IoU and CPU) but the household sequences' maps were worse (pooled object IoU 0.461
        / 0.398 against 0.443 / 0.509 in two runs, one run's ATE 0.48 m against at most 0.18 m), so
        it is off (docs/slam-history.md, "Issue 23, eleventh pass"). Never in the ``graph-isam2``
        method, where it stays in the estimate of the landmarks added after the last rebuild and
        widened the spreads.
    isam2_rescale_every : int
        iSAM2 is rebuilt on the same factors at its estimate moved to the best scale
        (:mod:`sqfit.graph.scale`: its partial relinearisation never moves the whole map together,
        so the scale set by the first landmarks' first frames sticks) once at least this many frames
        and ``isam2_rescale_parallax_deg`` of parallax have passed since the last rebuild
        (:mod:`sqfit.graph.schedule`). 0: never.
    isam2_rescale_growth : float
        Once either spacing is less than this fraction of the frames or parallax so far, it becomes
        that fraction (by frames alone: after 10, 20, 30, 40, 50, 63, 79, 99 frames), so the
        rebuilds' total cost grows with the length, not with its square; 0: evenly.
    isam2_rescale_parallax_deg : float
        The rebuilds' spacing in degrees of parallax (the median angle each frame's step subtends
        at the mask centroids it shares with the previous frame, summed; about 5.5 per frame on the
        evaluation scenes): a path filmed at a higher frame rate is not rebuilt more often. 0: by
        frames alone.
    isam2_refit : bool
        At each rebuild, the landmarks left in a poor minimum are re-fitted first, as after
        the batch solve (``refit_misfit``, in the batch's start ``batch_rebuild_refit_misfit``; on
        the frames so far): without it iSAM2 never re-fits a landmark, and one in 3G's far, huge
        minimum drags the trajectory with it.
    isam2_dogleg : bool
        iSAM2 steps by Powell's dogleg (trust region; evaluates the whole graph's error at every
        update) instead of Gauss-Newton.
    outline_offset_sigma_px : float
        > 0: each landmark gets an outline offset δ (px, one per object, as stage 3G's: the masks
        grown or shrunk along their normal by δ, README "Real masks") estimated with it, with a
        Gaussian prior of this standard deviation at 0; 0 (the default): none. For segmenters that
        over- or under-segment; on exact masks it only adds a variable per landmark.
    floor_z : float or None
        The height (world ``z``, metres, +z up) of a floor every object stands on, when the caller
        knows it (:mod:`sqfit.graph.floor`: a metric cue the images and odometry do not carry;
        e.g. a camera at a known height in a gravity-aligned frame); None (the default): no floor.
        Each landmark then gets a Huber-robust factor putting its lowest point on it, but for those
        whose initial fit left the grazing cost (stage 3T moved it: a table fitted as its top, a
        lamp as its shade; ``mismatch_ray_k``), whose lowest point need not touch the floor.
    floor_sigma_m : float
        Standard deviation of a landmark's lowest point about the floor, metres, > 0.
    final_floor_sigma_m : float or None
        The floor factors' standard deviation in the batch's last solves (after the re-fit) and
        throughout the ``graph-isam2`` method, which has no last solve, > 0; None: ``floor_sigma_m``.
        The floor, the one metric cue besides the odometry, fixes the map's scale: at 10 mm the
        odometry still pulled it 0.1-0.3 % off. Batch, evaluation scenes (36 runs of seeds 0-1 / 2-3,
        docs/slam-history.md "Issue 23, fifth pass"): runs with ATE <= 0.015 m 28 / 31 at 10 mm, 31 / 33
        at 1 mm; largest ATE spread over 3 runs 1e-9 apart 0.021 / 0.010 and 0.005 / 0.005 m (a 3 mm
        floor throughout the batch was worse). ``graph-isam2`` (sixteenth pass): sequences beyond a
        stability limit 1 / 3 of 12 at 10 mm, 0 / 1 at 1 mm.
    final_floor_misfit : float
        In the batch only the landmarks that fit their masks get that tighter floor: misfit (RMS
        whitened ray residual, :func:`sqfit.graph.refit.object_misfits`) at most this before the
        last solves; the others keep ``floor_sigma_m``. A superquadric that does not follow its
        object (a chair, a plush toy) has no reliable lowest point, and a 1 mm floor under it pulled
        whole household maps down with it (docs/slam-history.md "Issue 23, sixth pass": household seed 0 with the
        floor and the scene's odometry noise, median object IoU 0.076 / 0.036 before, 0.184 / 0.125
        with this test). At the end of the batch the landmarks' misfits were 0.28-0.77 on the
        evaluation scenes, 2.0-6.8 on household sequences; 0: no landmark gets the tighter floor.
    misfit_sigma : float
        A landmark whose misfit (RMS whitened ray residual at ``silhouette_sigma``,
        :func:`sqfit.graph.refit.object_misfits`) exceeds this gets its silhouette factors' sigma
        scaled by misfit / ``misfit_sigma`` (:mod:`sqfit.graph.weighting`: a landmark no
        superquadric follows counts by the spread its rays show). Batch only: the misfits are
        measured at the batch's solution and, where any landmark's scale is needed, the whole batch
        runs again with the scales from the first frame (a warning names them); the incremental
        method keeps ``silhouette_sigma``. 0: every landmark keeps ``silhouette_sigma``. Above it,
        the batch's check after its last solve re-fits a landmark for its overlap only, not for its
        misfit (:func:`sqfit.graph.refit.refit_landmarks`, ``misfit_cap``; none with 0).
    max_iterations : int
        Levenberg-Marquardt iterations of the batch solves.
    relative_tolerance : float
        Levenberg-Marquardt relative error decrease to stop at (the quadric baseline).
    """

    n_contour: int = 32
    final_n_contour: int = 64
    silhouette_sigma: float = 0.03
    huber_k: float = 1.345
    odometry_sigma_deg: float = 0.5
    odometry_sigma_m: float = 0.005
    prior_sigma_deg: float = 0.01
    prior_sigma_m: float = 0.001
    final_prior_sigma_deg: float | None = 0.001
    final_prior_sigma_m: float | None = 0.0001
    final_first_view_sigma_scale: float = 0.5
    init_frames: int = 3
    init_parallax_deg: float = 20.0
    init_retries: int = 5
    init_min_overlap: float = 0.1
    init_chain: str = INIT_CHAIN
    fit_n_contour: int = 64
    batch_refit_n_contour: int = 32
    mismatch_ray_k: float = 6.0
    batch_pose_noise_refit: bool = False
    bounds_weight: float = C.PENALTY_ANALYTIC
    landmark_prior_sigma_deg: float = 90.0
    landmark_prior_sigma_m: float = 10.0
    shape_prior_sigma: float = 10.0
    shape_variable: str = "plain"
    box_sigma_px: float = 2.0
    batch_start: str = "isam2"
    batch_odometry_chi2: float = 8.0
    batch_window: int = 10
    batch_free_frames: int = 20
    batch_past_views: int = 20
    window_relative_tolerance: float = 0.03
    refit_misfit: float = 0.5
    refit_max_frames: int = 12
    axis_check_frames: int = 6
    batch_rebuild_refit_misfit: float = 0.75
    isam2_relinearize_threshold: float = 0.01
    isam2_landmark_relinearize_threshold: float = 0.03
    batch_landmark_relinearize_threshold: float = 0.01
    batch_landmark_damping_sigma: float = 0.0
    isam2_rescale_every: int = 10
    isam2_rescale_growth: float = 0.25
    isam2_rescale_parallax_deg: float = 50.0
    isam2_refit: bool = True
    isam2_dogleg: bool = False
    outline_offset_sigma_px: float = 0.0
    floor_z: float | None = None
    floor_sigma_m: float = 0.01
    final_floor_sigma_m: float | None = 0.001
    final_floor_misfit: float = 1.0
    misfit_sigma: float = 1.0
    max_iterations: int = 50
    relative_tolerance: float = 1e-3
    final_relative_tolerance: float = 1e-5
    final_max_lambda: float = 0.1
    rescale: bool = True

    WHAT = "graph"

    def __post_init__(self):
        check_fields(self, integers={"n_contour": 3, "final_n_contour": 0, "fit_n_contour": 3, "batch_refit_n_contour": 3,
                                         "init_frames": MIN_FRAMES, "init_retries": 0, "max_iterations": 1, "batch_window": 0,
                                         "batch_free_frames": 0, "batch_past_views": 0,
                                         "refit_max_frames": 0, "axis_check_frames": 0,
                                         "isam2_rescale_every": 0},
                     positive=("batch_odometry_chi2", "silhouette_sigma", "huber_k", "odometry_sigma_deg", "odometry_sigma_m",
                               "prior_sigma_deg", "prior_sigma_m", "landmark_prior_sigma_deg", "init_parallax_deg",
                               "isam2_relinearize_threshold", "isam2_landmark_relinearize_threshold",
                               "batch_landmark_relinearize_threshold", "window_relative_tolerance", "landmark_prior_sigma_m",
                               "shape_prior_sigma", "box_sigma_px", "relative_tolerance",
                               "final_relative_tolerance", "final_max_lambda", "floor_sigma_m",
                               "final_first_view_sigma_scale"),
                     nonnegative=("misfit_sigma", "final_floor_misfit", "isam2_rescale_growth", "isam2_rescale_parallax_deg", "bounds_weight", "init_min_overlap", "refit_misfit",
                                  "batch_rebuild_refit_misfit", "outline_offset_sigma_px", "mismatch_ray_k",
                                  "batch_landmark_damping_sigma"))
        if 0 < self.final_n_contour < 3:
            raise ValueError(f"final_n_contour must be 0 (n_contour) or at least 3, got {self.final_n_contour}")
        if self.shape_variable not in SHAPE_VARIABLES:
            raise ValueError(f"shape_variable must be one of {', '.join(SHAPE_VARIABLES)}, got {self.shape_variable!r}")
        if self.batch_start not in BATCH_STARTS:
            raise ValueError(f"batch_start must be one of {', '.join(BATCH_STARTS)}, got {self.batch_start!r}")
        for name in ("final_floor_sigma_m", "final_prior_sigma_deg", "final_prior_sigma_m"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not (isinstance(value, (int, float, np.number))
                                                                      and np.isfinite(value) and value > 0)):
                raise ValueError(f"{name} must be a positive number or None, got {value!r}")
        if self.floor_z is not None and not np.isfinite(self.floor_z):
            raise ValueError(f"floor_z must be a finite height or None, got {self.floor_z}")
        for name in ("batch_pose_noise_refit", "isam2_refit"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
