"""iSAM2's re-fit at its rebuilds (GraphOptions.isam2_refit): a landmark left in a poor minimum
mid-sequence is re-initialised on the frames so far."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit import graph  # noqa: E402
from sqfit.graph import landmark, refit, solve  # noqa: E402
from sqfit.graph import problem as gproblem  # noqa: E402
from sqfit.graph.testing import synthetic_sequence  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402

from gtsam.symbol_shorthand import L, S, X  # noqa: E402


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(1, n_frames=16, n_objects=3)


def test_refit_mid_sequence_uses_only_the_frames_so_far(seq):
    # values hold frames 0 .. n-1 only, as iSAM2's estimate at its rebuild after frame n-1
    n = 9
    prob = gproblem.check_inputs(seq.intrinsics, seq.true_poses, seq.observations)
    values = gtsam.Values()
    for i in range(n):
        values.insert(X(i), gtsam.Pose3(seq.true_poses[i]))
    for oid, sq in seq.objects.items():
        if oid == 2:  # moved 20 m up: 3G's far minimum, its silhouettes leave the masks
            sq = sqfit.Superquadric(sq.size, sq.shape, np.array(sq.position) + (0.0, 0.0, 20.0), sq.rotation)
        T, s = landmark.superquadric_to_landmark(sq)
        values.insert(L(oid), gtsam.Pose3(T))
        values.insert(S(oid), s)
    result = graph.SlamResult("graph-isam2", seq.true_poses)
    with pytest.raises(RuntimeError):  # all frames: the later poses are not there
        refit.refit_landmarks(prob, gtsam.Values(values), list(seq.objects), graph.GraphOptions(), result)
    assert refit.refit_landmarks(prob, values, list(seq.objects), graph.GraphOptions(), result, n=n)
    assert [w.split(":")[0] for w in result.warnings] == ["object 2"] and f"(at frame {n})" in result.warnings[0]
    refitted = landmark.landmark_to_superquadric(values.atPose3(L(2)).matrix(), values.atVector(S(2)))
    assert iou_3d(refitted, seq.objects[2]) > 0.8


@pytest.mark.parametrize("on", [True, False])
def test_isam2_refits_at_its_rebuilds(monkeypatch, seq, on):
    calls = []
    real = solve.refit_landmarks

    def refit(*args, **kw):
        calls.append(kw.get("n"))
        return real(*args, **kw)

    monkeypatch.setattr(solve, "refit_landmarks", refit)
    result = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph-isam2"],
                       {"isam2_refit": on, "isam2_rescale_every": 5})["graph-isam2"]
    assert result.status == "ok"
    assert calls == ([5, 10, 15] if on else [])


def test_isam2_refit_is_checked():
    with pytest.raises(ValueError, match="isam2_refit must be True or False"):
        graph.GraphOptions(isam2_refit=1)
