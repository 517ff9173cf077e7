"""Deferred landmark initialisation (sqfit.graph.growth, GraphOptions.init_retries): an initial fit
whose silhouettes barely overlap its masks (3G's far, huge minimum) is not put in the graph; the
landmark waits for its next frame."""

import pytest

gtsam = pytest.importorskip("gtsam")

from sqfit.graph import GraphOptions, growth, solve  # noqa: E402
from sqfit.graph.testing import synthetic_sequence  # noqa: E402


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(0, n_frames=12, n_objects=2)


def _poor_first_fits(monkeypatch, poor):
    """Every object's first ``poor`` initial fits report an overlap of 0.01 (a far, huge fit), the
    later ones the truth; records (object frames, reported overlap) per call."""
    calls, counts, real_initial = [], {}, growth.initial_fit

    def initial_fit(problem, oid, frames, poses, options, pose_noise_refit=True):
        out = real_initial(problem, oid, frames, poses, options, pose_noise_refit)
        counts[oid] = counts.get(oid, 0) + 1
        if counts[oid] <= poor:
            out = out._replace(overlap=0.01)
        calls.append((oid, list(frames), out.overlap))
        return out

    monkeypatch.setattr(growth, "initial_fit", initial_fit)
    return calls


@pytest.mark.parametrize("method", ["graph", "graph-isam2"])
def test_a_poor_initial_fit_waits_for_the_next_frame(monkeypatch, seq, method):
    calls = _poor_first_fits(monkeypatch, poor=2)
    result = solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method], {})[method]
    assert result.status == "ok" and sorted(result.objects) == sorted(seq.objects)
    for oid in seq.objects:
        mine = [c for c in calls if c[0] == oid]
        # two poor fits, each on one frame more than the last, then the good one
        assert [c[2] for c in mine] == [0.01, 0.01, mine[2][2]] and mine[2][2] >= GraphOptions().init_min_overlap
        assert [len(c[1]) for c in mine] == [len(mine[0][1]) + k for k in range(3)]
        assert any(w.startswith(f"object {oid}: initial fit deferred 2 time(s)") for w in result.warnings)


def test_without_retries_the_first_fit_starts_the_landmark(monkeypatch, seq):
    calls = _poor_first_fits(monkeypatch, poor=2)
    result = solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {"init_retries": 0, "init_min_overlap": 0.5})["graph"]
    assert result.status == "ok"
    assert [c[2] for c in calls] == [0.01] * len(seq.objects)
    assert not any("deferred" in w for w in result.warnings)


def test_after_its_retries_a_landmark_starts_from_its_best_fit(monkeypatch, seq):
    # every fit of object 1 poor (the first far, huge): after init_retries waits it starts anyway,
    # from the fit that overlapped most (here the second of four)
    overlaps = iter([0.05, 0.3, 0.2, 0.1])
    real_initial = growth.initial_fit
    made = []

    def initial_fit(problem, oid, frames, poses, options, pose_noise_refit=True):
        out = real_initial(problem, oid, frames, poses, options, pose_noise_refit)
        if oid == 1:
            out = out._replace(overlap=next(overlaps))
        made.append((oid, out))
        return out

    added = []
    real_add = growth.add_landmark

    def add_landmark(graph, values, problem, oid, frames, landmark, *args, **kw):
        added.append((oid, landmark))
        return real_add(graph, values, problem, oid, frames, landmark, *args, **kw)

    monkeypatch.setattr(growth, "initial_fit", initial_fit)
    monkeypatch.setattr(growth, "add_landmark", add_landmark)
    result = solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {"init_retries": 3})["graph"]
    assert result.status == "ok"
    mine = [fit for oid, fit in made if oid == 1]
    assert len(mine) == 4  # the first fit and 3 retries
    start = dict(added)[1]
    best = max(mine, key=lambda fit: fit.overlap)
    assert best is mine[1] and start is best.landmark
    assert any(w.startswith("object 1: initial fit deferred 3 time(s)") for w in result.warnings)


def test_a_landmark_still_far_huge_after_its_retries_waits_on(monkeypatch, seq):
    # every fit of object 1 far, huge (0.01): after its init_retries it is not put in the graph
    # either, but fitted again each time its frames have doubled, and at its last frame it starts
    # from the best of its fits
    from sqfit.graph.problem import check_inputs

    real_initial, calls, reported = growth.initial_fit, [], []

    def initial_fit(problem, oid, frames, poses, options, pose_noise_refit=True):
        out = real_initial(problem, oid, frames, poses, options, pose_noise_refit)
        if oid == 1:
            out = out._replace(overlap=reported[min(len(calls), len(reported) - 1)])
            calls.append(len(frames))
        return out

    monkeypatch.setattr(growth, "initial_fit", initial_fit)
    reported[:] = [0.01]
    result = solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {"init_retries": 2})["graph"]
    assert result.status == "ok" and sorted(result.objects) == sorted(seq.objects)
    first, last = calls[0], len(check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations).frames[1])
    assert calls[:3] == [first, first + 1, first + 2]  # the first fit and its two retries
    for before, after in zip(calls[2:], calls[3:]):  # then only at double the frames, and at the last
        assert after >= 2 * before or after == last
    assert calls[-1] == last and len(calls) < last - first + 1
    assert any(w.startswith(f"object 1: initial fit deferred {len(calls) - 1} time(s)") for w in result.warnings)
    # far, huge first, then poor but not far, huge (0.3): after its retries it starts from its best
    calls.clear()
    reported[:] = [0.01, 0.3]
    solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {"init_retries": 2})
    assert calls == [first, first + 1, first + 2]


def test_init_options_are_checked():
    with pytest.raises(ValueError, match="init_retries"):
        GraphOptions(init_retries=-1)
    with pytest.raises(ValueError, match="init_min_overlap"):
        GraphOptions(init_min_overlap=-0.1)


def test_once_put_off_a_landmark_waits_for_a_fit_that_is_not_poor(monkeypatch, seq):
    # the first fit far, huge (0.01), the second poor but above init_min_overlap (0.3): a landmark
    # put off once waits on until the fitter no longer flags its fit (R-IOU-M >= POOR_FIT_R_IOU_M)
    from sqfit import constants as C

    real_initial, calls, counts = growth.initial_fit, [], {}
    reported = {1: 0.01, 2: 0.3}

    def initial_fit(problem, oid, frames, poses, options, pose_noise_refit=True):
        out = real_initial(problem, oid, frames, poses, options, pose_noise_refit)
        counts[oid] = counts.get(oid, 0) + 1
        if counts[oid] in reported:
            out = out._replace(overlap=reported[counts[oid]])
        calls.append((oid, out.overlap))
        return out

    monkeypatch.setattr(growth, "initial_fit", initial_fit)
    result = solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {})["graph"]
    assert result.status == "ok" and sorted(result.objects) == sorted(seq.objects)
    for oid in seq.objects:
        mine = [overlap for o, overlap in calls if o == oid]
        assert mine[:2] == [0.01, 0.3] and len(mine) == 3 and mine[2] >= C.POOR_FIT_R_IOU_M
    # a first fit at 0.3 is not put off at all
    calls.clear(), counts.clear()
    reported.clear()
    reported[1] = 0.3
    solve.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"], {})
    assert [overlap for _, overlap in calls] == [0.3] * len(seq.objects)
