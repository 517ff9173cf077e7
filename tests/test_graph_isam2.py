"""iSAM2's re-fit at its rebuilds (GraphOptions.isam2_refit): a landmark left in a poor minimum
mid-sequence is re-initialised on the frames so far; a re-fit not kept is not repeated in vain; the
batch starts from iSAM2 (GraphOptions.batch_start)."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit import graph  # noqa: E402
from sqfit.graph import landmark, refit, schedule, solve  # noqa: E402
from sqfit.graph import problem as gproblem  # noqa: E402
from sqfit.graph.testing import object_ious, position_rmse, synthetic_sequence  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402
from _helpers import graph_values  # noqa: E402

from gtsam.symbol_shorthand import L, S, X  # noqa: E402


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(1, n_frames=16, n_objects=3)


def test_refit_mid_sequence_uses_only_the_frames_so_far(seq):
    # values hold frames 0 .. n-1 only, as iSAM2's estimate at its rebuild after frame n-1
    n = 9
    prob = gproblem.check_inputs(seq.intrinsics, seq.true_poses, seq.observations)
    sq = seq.objects[2]  # moved 20 m up: 3G's far minimum, its silhouettes leave the masks
    far = sqfit.Superquadric(sq.size, sq.shape, np.array(sq.position) + (0.0, 0.0, 20.0), sq.rotation)
    values = graph_values(seq.true_poses[:n], {**seq.objects, 2: far})
    result = graph.SlamResult("graph-isam2", seq.true_poses)
    with pytest.raises(RuntimeError):  # all frames: the later poses are not there
        refit.refit_landmarks(prob, gtsam.Values(values), list(seq.objects), graph.GraphOptions(), result)
    assert refit.refit_landmarks(prob, values, list(seq.objects), graph.GraphOptions(), result, n=n)
    assert [w.split(":")[0] for w in result.warnings] == ["object 2"] and f"(at frame {n})" in result.warnings[0]
    refitted = landmark.landmark_to_superquadric(values.atPose3(L(2)).matrix(), values.atVector(S(2)))
    assert iou_3d(refitted, seq.objects[2]) > 0.8


def _isam2_refits(monkeypatch, seq, options):
    """``(result, frames)``: graph-isam2 on ``seq`` with ``options``, and the frame counts ``n`` of
    its re-fits, in order."""
    calls = []
    real = solve.refit_landmarks

    def refit(*args, **kw):
        calls.append(kw.get("n"))
        return real(*args, **kw)

    monkeypatch.setattr(solve, "refit_landmarks", refit)
    return graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph-isam2"], options)["graph-isam2"], calls


@pytest.mark.parametrize("on", [True, False])
def test_isam2_refits_at_its_rebuilds(monkeypatch, seq, on):
    result, calls = _isam2_refits(monkeypatch, seq, {"isam2_refit": on, "isam2_rescale_every": 5,
                                                     "isam2_rescale_parallax_deg": 0})
    assert result.status == "ok"
    assert calls == ([5, 10, 15] if on else [])


def test_isam2_refit_is_checked():
    with pytest.raises(ValueError, match="isam2_refit must be True or False"):
        graph.GraphOptions(isam2_refit=1)


def _poor_minimum_values(seq, n):
    """Frames 0 .. n-1 at the true poses, the landmarks at the truth but object 2 flat with its
    axes swapped (a high misfit)."""
    sq = seq.objects[2]
    poor = sqfit.Superquadric(np.array(sq.size)[[2, 0, 1]], (1.8, 0.2), np.array(sq.position) + 0.15, sq.rotation)
    return graph_values(seq.true_poses[:n], {**seq.objects, 2: poor})


def test_a_refit_not_kept_is_retried_only_when_misfit_or_frames_grew(monkeypatch, seq):
    prob = gproblem.check_inputs(seq.intrinsics, seq.true_poses, seq.observations)
    options, fits = graph.GraphOptions(), []
    real = refit.landmark_fit

    def worse(obs, opts, pose_noise_refit, where, n_contour=None):  # a fit further off than the landmark: not kept
        fits.append(where)
        fit = real(obs, opts, pose_noise_refit, where, n_contour)
        T, shape = fit.landmark
        T = T.copy()
        T[:3, 3] += 0.5
        return fit._replace(landmark=(T, shape))

    monkeypatch.setattr(refit, "landmark_fit", worse)
    n, rejected = 8, {}
    result = graph.SlamResult("graph-isam2", seq.true_poses)
    values = _poor_minimum_values(seq, n)
    misfit = refit.object_misfits(prob, values, [2], options, n=n, most=options.refit_max_frames)[2]
    assert misfit > options.refit_misfit
    assert not refit.refit_landmarks(prob, values, list(seq.objects), options, result, n=n, rejected=rejected)
    assert len(fits) == 1 and set(rejected) == {2} and rejected[2] == (pytest.approx(misfit), len(
        refit.frames_before(prob, 2, n)))
    # the same misfit, the same frames: not fitted again
    refit.refit_landmarks(prob, values, list(seq.objects), options, result, n=n, rejected=rejected)
    assert len(fits) == 1
    # without the memory it is
    refit.refit_landmarks(prob, values, list(seq.objects), options, result, n=n)
    assert len(fits) == 2
    # a misfit grown by RETRY_MISFIT since: fitted again
    rejected[2] = (misfit / refit.RETRY_MISFIT * 0.99, rejected[2][1])
    refit.refit_landmarks(prob, values, list(seq.objects), options, result, n=n, rejected=rejected)
    assert len(fits) == 3 and rejected[2][0] == pytest.approx(misfit)
    # as many frames again since: fitted again
    frames = len(refit.frames_before(prob, 2, n))
    rejected[2] = (rejected[2][0], int(np.floor(frames / refit.RETRY_FRAMES)))
    refit.refit_landmarks(prob, values, list(seq.objects), options, result, n=n, rejected=rejected)
    assert len(fits) == 4
    # a kept re-fit clears the memory
    monkeypatch.setattr(refit, "landmark_fit", real)
    rejected[2] = (misfit / 2, frames / 2)
    assert refit.refit_landmarks(prob, values, list(seq.objects), options, result, n=n, rejected=rejected)
    assert 2 not in rejected


@pytest.mark.parametrize("start", ["isam2", "windows"])
def test_the_batch_starts_from_isam2_or_from_windows(monkeypatch, seq, start):
    calls = []
    real = solve._incremental

    def incremental(*args, **kw):
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(solve, "_incremental", incremental)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph", "odometry"],
                    {"batch_start": start})
    assert res["graph"].ok and len(calls) == (start == "isam2")
    assert res["graph"].frame_seconds is None  # iSAM2's per-frame times are the graph-isam2 method's
    ate = {m: position_rmse(r.poses, seq.true_poses) for m, r in res.items()}
    assert ate["graph"] < 0.5 * ate["odometry"], ate
    assert np.median(list(object_ious(res["graph"].objects, seq.objects).values())) > 0.8


def test_an_isam2_error_in_the_batch_names_the_frame(monkeypatch, seq):
    def fail(self, *args):
        raise RuntimeError("Indeterminate linear system detected while working near variable x3")

    monkeypatch.setattr(gtsam.ISAM2, "update", fail)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph-isam2"])["graph-isam2"]
    assert res.status == "failed" and res.message.startswith("iSAM2 update at frame 0: RuntimeError"), res.message
    np.testing.assert_array_equal(res.poses, seq.odometry_poses)
    # the batch solves again from windows, and its warning names the frame
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"])["graph"]
    assert res.ok
    assert any(w.startswith("batch from iSAM2 failed (iSAM2 update at frame 0: RuntimeError") for w in res.warnings)


def test_batch_start_is_checked():
    with pytest.raises(ValueError, match="batch_start must be one of isam2, windows, got 'lm'"):
        graph.GraphOptions(batch_start="lm")


@pytest.mark.parametrize("n, options, expected", [
    (50, {}, [10, 20, 30, 40, 50]),  # the evaluation scenes' lengths: every 10 frames
    (160, {}, [10, 20, 30, 40, 50, 63, 79, 99, 124, 155]),  # then 25 % of the frames so far later
    (45, {"isam2_rescale_growth": 0}, [10, 20, 30, 40]),
    (300, {"isam2_rescale_every": 0}, []),
])
def test_isam2_rebuilds_come_later_as_the_sequence_grows(n, options, expected):
    options = graph.GraphOptions(**options, isam2_rescale_parallax_deg=0)
    assert sorted(schedule.rebuild_frames(n, options)) == expected
    # the frame-by-frame schedule in frame units says the same
    sched = schedule.RebuildSchedule(None, options)
    assert [i + 1 for i in range(n) if sched.due(None, i)] == expected == sched.frames


def test_isam2_rebuilds_follow_the_schedule(monkeypatch, seq):
    _, calls = _isam2_refits(monkeypatch, seq, {"isam2_rescale_every": 3, "isam2_rescale_growth": 1.0,
                                                "isam2_rescale_parallax_deg": 0})
    assert calls == [6, 12]  # of 16 frames; at 3 no landmark is in the graph yet, nothing to rebuild


def _schedule_at_truth(seq, options):
    """The :class:`schedule.RebuildSchedule` of ``seq`` run over its true poses, and its problem."""
    prob = gproblem.check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    values = gtsam.Values()
    for i, T in enumerate(seq.true_poses):
        values.insert(X(i), gtsam.Pose3(T))
    sched = schedule.RebuildSchedule(prob, graph.GraphOptions(**options))
    for i in range(len(seq.true_poses)):
        sched.due(values, i)
    return sched, prob, values


def test_step_parallax_is_the_angle_a_step_subtends_at_the_objects():
    seq = synthetic_sequence(2, n_frames=21, n_objects=3, arc_deg=100.0)  # 5 degrees of orbit per step
    _, prob, values = _schedule_at_truth(seq, {})
    steps = [schedule.step_parallax_deg(prob, values, i) for i in range(1, 21)]
    # objects within 1.6 m of the orbit's centre, cameras 5 m out: about the orbit's 5 degrees
    assert 3.0 < np.median(steps) < 8.0
    assert schedule.step_parallax_deg(prob, values, 0) == 0.0
    alone = gproblem.check_inputs(seq.intrinsics, seq.odometry_poses,
                                  {k: o for k, o in seq.observations.items() if k[0] != 4})
    assert schedule.step_parallax_deg(alone, values, 4) == 0.0  # no object seen in both frames


def test_parallax_schedule_rebuilds_where_the_viewpoint_has_moved_whatever_the_frame_rate():
    def sequence(n):  # the same 240-degree orbit, 240 / (n - 1) degrees per step
        return synthetic_sequence(4, n_frames=n, n_objects=3, arc_deg=240.0, min_area_px=20, n_samples=40)

    options = {"isam2_rescale_every": 4, "isam2_rescale_parallax_deg": 30.0}
    where, frames = {}, {}
    for n in (17, 33, 65):  # 15, 7.5 and 3.75 degrees per step
        seq = sequence(n)
        sched, _, _ = _schedule_at_truth(seq, options)
        where[n] = np.array([(f - 1) * 240.0 / (n - 1) for f in sched.frames])  # the orbit angle of each rebuild
        frames[n] = sorted(schedule.rebuild_frames(n, graph.GraphOptions(**options)))
        assert sched.frames == sorted(set(sched.frames))
        # never before the frame floor: each rebuild at least as far apart as by frames alone
        gaps, floor = np.diff([0] + sched.frames), np.diff([0] + frames[n][:len(sched.frames)])
        assert np.all(gaps >= floor[:len(gaps)])
    # 15 degrees per step: 30 degrees come within the 4 frames, the frames set the pace
    assert sched_frames(sequence(17), options) == frames[17]
    # finer: the parallax sets it, the rebuilds fall at the same places of the orbit
    k = min(len(where[33]), len(where[65]))
    assert k >= 4 and abs(len(where[65]) - len(where[33])) <= 1  # one more or less at the orbit's end
    # each rebuild overshoots its mark by up to a step, and the next mark counts from it
    assert np.abs(where[65][:k] - where[33][:k]).max() <= 15.0
    assert len(where[65]) < len(frames[65])


def sched_frames(seq, options):
    return _schedule_at_truth(seq, options)[0].frames


def test_isam2_rebuilds_follow_the_parallax_schedule(monkeypatch, seq):
    real, made = schedule.RebuildSchedule, []

    def recording(problem, options):
        made.append(real(problem, options))
        return made[-1]

    monkeypatch.setattr(solve, "RebuildSchedule", recording)
    result, calls = _isam2_refits(monkeypatch, seq, {"isam2_rescale_every": 1, "isam2_rescale_parallax_deg": 20.0})
    # every rebuild the schedule called for once a landmark was in the graph (none before: nothing to rebuild)
    assert result.ok and len(calls) >= 3 and calls == made[0].frames[-len(calls):]
    assert calls != [10]  # not the frame schedule's


def test_isam2_rescale_growth_is_checked():
    with pytest.raises(ValueError, match="isam2_rescale_growth"):
        graph.GraphOptions(isam2_rescale_growth=-0.1)
    with pytest.raises(ValueError, match="isam2_rescale_parallax_deg"):
        graph.GraphOptions(isam2_rescale_parallax_deg=-1.0)


def test_odometry_chi2_is_about_its_degrees_of_freedom_at_the_truth():
    # synthetic odometry drifts by the default noise model: chi-square ~6 per step at the true poses
    seq = synthetic_sequence(3, n_frames=40, n_objects=1)
    prob = gproblem.check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    from sqfit.graph.growth import noise_models, pose_factors

    g = pose_factors(prob, noise_models(graph.GraphOptions()), range(40))
    truth = gtsam.Values()
    for i, T in enumerate(seq.true_poses):
        truth.insert(X(i), gtsam.Pose3(T))
    assert 3.0 < solve.odometry_chi2(g, truth) < 10.0
    odo = gtsam.Values()
    for i, T in enumerate(seq.odometry_poses):
        odo.insert(X(i), gtsam.Pose3(T))
    assert solve.odometry_chi2(g, odo) < 1e-12  # the odometry agrees with itself
    assert solve.odometry_chi2(gtsam.NonlinearFactorGraph(), odo) == 0.0


@pytest.mark.parametrize("chi2, fallback", [(1e3, True), (1.0, False)])
def test_a_batch_from_isam2_far_from_the_odometry_is_solved_again_from_windows(monkeypatch, seq, chi2, fallback):
    starts = []
    real = solve._batch_from

    def batch_from(problem, options, start, scales=None):
        starts.append(start)
        result, asked = real(problem, options, start, scales)
        if start == "isam2":
            result.odometry_chi2 = chi2
        return result, asked

    monkeypatch.setattr(solve, "_batch_from", batch_from)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {"floor_z": 0.0})["graph"]
    assert res.ok and starts == (["isam2", "windows"] if fallback else ["isam2"])
    notes = [w for w in res.warnings if "inconsistent with the odometry" in w]
    assert len(notes) == fallback
    starts.clear()  # without a floor no test
    graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"])
    assert starts == ["isam2"]


@pytest.mark.parametrize("misfit_sigma, cap, axes", [(1.5, 1.5, 0), (0.0, np.inf, 0), (1.5, 1.5, 6)])
def test_the_batch_tests_its_landmarks_again_after_its_last_solve(monkeypatch, seq, misfit_sigma, cap, axes):
    # the check after the last solve re-fits by overlap, and by misfit (up to misfit_sigma) unless it
    # tests every landmark's axes (axis_check_frames), without the memory of the re-fits not kept
    # at iSAM2's rebuilds (the last solve moved the poses)
    calls, real = [], solve.refit_landmarks
    tested, real_axes = [], solve.reorient_landmarks

    def refit_landmarks(*args, **kw):
        calls.append(kw)
        return real(*args, **kw)

    def reorient_landmarks(*args, **kw):
        tested.append(args[3].axis_check_frames)
        return real_axes(*args, **kw)

    monkeypatch.setattr(solve, "refit_landmarks", refit_landmarks)
    monkeypatch.setattr(solve, "reorient_landmarks", reorient_landmarks)
    options = graph.GraphOptions(misfit_sigma=misfit_sigma, axis_check_frames=axes)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], options)["graph"]
    assert res.ok
    last = calls[-1]
    assert last.get("overlap_only") == (axes > 0) and last.get("rejected") is None and last.get("n") is None
    assert last["misfit_cap"] == cap  # misfit_sigma 0: no landmark's outline is taken for the model's
    assert tested and set(tested) == {axes}  # called at the check (and a no-op with 0)
    # at the rebuilds, the memory and no cap
    assert all(kw.get("rejected") is not None and "misfit_cap" not in kw for kw in calls if kw.get("n") is not None)


@pytest.mark.parametrize("value, expected", [(None, 0.75), (0.0, None), (0.6, 0.6)])
def test_the_batch_rebuilds_refit_above_their_own_misfit_threshold(monkeypatch, seq, value, expected):
    # the batch's iSAM2 start tests the misfit against batch_rebuild_refit_misfit at its rebuilds
    # (0: refit_misfit); its check after the last solve, and the graph-isam2 method's rebuilds,
    # against refit_misfit
    calls, real = [], solve.refit_landmarks

    def refit_landmarks(*args, **kw):
        calls.append((method, kw.get("n"), kw.get("misfit_threshold")))
        return real(*args, **kw)

    monkeypatch.setattr(solve, "refit_landmarks", refit_landmarks)
    options = {"isam2_rescale_every": 5, "isam2_rescale_parallax_deg": 0}
    if value is not None:
        options["batch_rebuild_refit_misfit"] = value
    for method in ("graph", "graph-isam2"):
        assert graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method], options)[method].ok
    assert [(m, n, t) for m, n, t in calls if n is not None] == \
        [("graph", n, expected) for n in (5, 10, 15)] + [("graph-isam2", n, None) for n in (5, 10, 15)]
    assert all(t is None for m, n, t in calls if n is None)


def test_batch_rebuild_refit_misfit_is_checked():
    with pytest.raises(ValueError, match="batch_rebuild_refit_misfit"):
        graph.GraphOptions(batch_rebuild_refit_misfit=-0.1)


class _FailingISAM2:
    """A gtsam.ISAM2 whose updates (counted over every instance) raise GTSAM's indeterminate-system
    error from the ``fail_at``-th on (only that one with ``once``), as iSAM2's undamped step did
    where a landmark had drifted into 3G's far, huge minimum."""

    real, fail_at, once, updates, made = None, 4, True, 0, 0

    def __init__(self, params):
        self._isam = type(self).real(params)
        type(self).made += 1

    def update(self, *args):
        cls = type(self)
        cls.updates += 1
        if cls.updates == cls.fail_at or (not cls.once and cls.updates > cls.fail_at):
            raise RuntimeError("\nIndeterminate linear system detected while working near variable\n42 (Symbol: s1).")
        return self._isam.update(*args)

    def __getattr__(self, name):
        return getattr(self._isam, name)


def _failing_isam2(monkeypatch, once):
    monkeypatch.setattr(_FailingISAM2, "real", gtsam.ISAM2)
    monkeypatch.setattr(_FailingISAM2, "once", once)
    monkeypatch.setattr(_FailingISAM2, "updates", 0)
    monkeypatch.setattr(_FailingISAM2, "made", 0)
    monkeypatch.setattr(solve.gtsam, "ISAM2", _FailingISAM2)


@pytest.mark.parametrize("method", ["graph", "graph-isam2"])
def test_a_failed_isam2_update_is_followed_by_a_restart_from_levenberg_marquardt(monkeypatch, seq, method):
    _failing_isam2(monkeypatch, once=True)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method])[method]
    assert res.ok and _FailingISAM2.made >= 2
    notes = [w for w in res.warnings if "failed" in w]
    assert notes == ["iSAM2 update at frame 3 failed (RuntimeError: Indeterminate linear system detected while working "
                     "near variable); started again from Levenberg-Marquardt on the graph so far"]
    assert position_rmse(res.poses, seq.true_poses) < 0.5 * position_rmse(seq.odometry_poses, seq.true_poses)
    assert min(object_ious(res.objects, seq.objects).values()) > 0.8


@pytest.mark.parametrize("windows_fail", [False, True])
def test_a_batch_whose_isam2_start_fails_is_solved_again_from_windows(monkeypatch, seq, windows_fail):
    # every update from the fourth on fails: the restart's too
    starts, real = [], solve._batch_from

    def batch_from(problem, options, start, scales=None):
        starts.append(start)
        result, asked = real(problem, options, start, scales)
        if start == "windows" and windows_fail:
            result.fail("Levenberg-Marquardt", RuntimeError("also indeterminate"))
        return result, asked

    _failing_isam2(monkeypatch, once=False)
    monkeypatch.setattr(solve, "_batch_from", batch_from)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"])["graph"]
    assert starts[:2] == ["isam2", "windows"]
    notes = [w for w in res.warnings if w.startswith("batch from iSAM2 failed")]
    assert len(notes) == 1 and "(iSAM2 update at frame 3: RuntimeError: Indeterminate linear system" in notes[0]
    if windows_fail:
        assert not res.ok and notes[0].endswith("which failed too (Levenberg-Marquardt: RuntimeError: also indeterminate)")
    else:
        assert res.ok and notes[0].endswith("solved again from windows")
        monkeypatch.setattr(solve, "_batch_from", real)
        windows = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"],
                            {"batch_start": "windows"})["graph"]
        np.testing.assert_array_equal(res.poses, windows.poses)
        assert all(np.array_equal(res.objects[k].to_vector(), windows.objects[k].to_vector()) for k in windows.objects)
    # the graph-isam2 method has no windows to fall back on: its failure is flagged
    monkeypatch.setattr(solve, "_batch_from", real)
    monkeypatch.setattr(_FailingISAM2, "updates", 0)
    incremental = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph-isam2"])["graph-isam2"]
    assert not incremental.ok
    assert incremental.message.startswith("iSAM2 update at frame 3: RuntimeError: Indeterminate linear system")


@pytest.mark.parametrize("windows_kept", [True, False])
def test_the_second_run_starts_from_isam2_and_names_the_first_runs_fallback(monkeypatch, seq, windows_kept):
    # the first run's iSAM2 is far from the odometry and one landmark asks for scaled noise: the
    # second run starts from iSAM2 again, whichever solution the first kept (from windows where the
    # first kept the windows' was measured worse: docs/slam-history.md, thirteenth pass), and its
    # warning carries the first run's fallback note, which the second run's result would lose
    starts = []
    real = solve._batch_from

    def batch_from(problem, options, start, scales=None):
        starts.append((start, bool(scales)))
        result, asked = real(problem, options, start, scales)
        if start == "isam2":
            result.odometry_chi2 = 1e3
        if (start == "isam2") == windows_kept:
            result.error_final = np.inf
        return result, ({} if scales else {sorted(result.objects)[0]: 2.0})

    monkeypatch.setattr(solve, "_batch_from", batch_from)
    res = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {"floor_z": 0.0})["graph"]
    assert res.ok
    assert starts == [("isam2", False), ("windows", False), ("isam2", True), ("windows", True)]
    again = [w for w in res.warnings if w.startswith("solved again with the silhouette noise")]
    kept = "windows" if windows_kept else "iSAM2"
    assert len(again) == 1 and "(the first run: batch from iSAM2 inconsistent with the odometry" in again[0]
    assert again[0].endswith(f"kept the {kept} solution)")


@pytest.mark.parametrize("batch, landmark", [(False, "0.07"), (True, "0.04")])
def test_relinearisation_thresholds_cover_every_kind_of_variable(batch, landmark):
    import gtsam

    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(solve.relinearize_thresholds(graph.GraphOptions(
        isam2_relinearize_threshold=0.02, isam2_landmark_relinearize_threshold=0.07,
        batch_landmark_relinearize_threshold=0.04), batch))
    text = str(params)
    for kind, value in (("x", "0.02"), ("l", landmark), ("s", landmark), ("o", landmark)):
        assert f"'{kind}' -> [{value} " in text, text


def test_the_batch_starts_from_its_own_landmark_threshold(monkeypatch, seq):
    seen = []
    thresholds = solve.relinearize_thresholds
    monkeypatch.setattr(solve, "relinearize_thresholds", lambda o, batch=False: seen.append(batch) or thresholds(o, batch))
    graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations)
    graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations)
    assert seen == [True, False]


@pytest.mark.parametrize("offsets", [0.0, 0.5])
def test_equal_thresholds_per_kind_are_the_single_threshold(monkeypatch, seq, offsets):
    """The map with the landmarks' threshold equal to the cameras' is GTSAM's single threshold: the
    same run to the last bit, with and without outline-offset variables (a kind missing from the
    map would be looked up without a default)."""
    options = {"isam2_relinearize_threshold": 0.01, "isam2_landmark_relinearize_threshold": 0.01,
               "outline_offset_sigma_px": offsets}
    mapped = graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations, options)
    monkeypatch.setattr(solve, "relinearize_thresholds", lambda o, batch=False: float(o.isam2_relinearize_threshold))
    single = graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations, options)
    assert mapped.ok and single.ok
    np.testing.assert_array_equal(mapped.poses, single.poses)
    assert all(np.array_equal(mapped.objects[k].to_vector(), single.objects[k].to_vector()) for k in single.objects)


def test_a_coarser_landmark_threshold_evaluates_fewer_views(monkeypatch, seq):
    from sqfit.graph import growth
    from sqfit.graph.factors import SilhouetteFactors

    made = []

    class Counted(SilhouetteFactors):
        def __init__(self, *args):
            super().__init__(*args)
            made.append(self)

    monkeypatch.setattr(growth, "SilhouetteFactors", Counted)
    counts = []
    for threshold in (0.01, 0.1):
        made.clear()
        options = {"isam2_landmark_relinearize_threshold": threshold, "isam2_rescale_every": 0}
        assert graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations, options).ok
        counts.append(sum(b.factor_evaluations for b in made))
    assert counts[1] < 0.8 * counts[0], counts


@pytest.mark.parametrize("name", ["isam2_landmark_relinearize_threshold", "batch_landmark_relinearize_threshold"])
def test_landmark_relinearisation_threshold_is_checked(name):
    with pytest.raises(ValueError, match=name):
        graph.GraphOptions(**{name: 0.0})
