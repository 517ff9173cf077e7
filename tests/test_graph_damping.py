"""The batch's iSAM2 start can damp its new landmarks' size/shape (GraphOptions.batch_landmark_damping_sigma,
off by default): a prior at the initial fit, in iSAM2 until the next rebuild, never in a rebuilt
iSAM2 nor in the batch's last solves, never in the graph-isam2 method."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from sqfit import graph  # noqa: E402
from sqfit.graph import growth  # noqa: E402
from sqfit.graph.testing import synthetic_sequence  # noqa: E402

from gtsam.symbol_shorthand import S  # noqa: E402

SIGMA = 0.07  # not the permanent shape prior's (shape_prior_sigma, 10), so the two can be told apart
REBUILDS = {"isam2_rescale_every": 6, "isam2_rescale_growth": 1.0, "isam2_rescale_parallax_deg": 0}


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(1, n_frames=16, n_objects=3)


def _damped(graph_):
    """The size/shape keys of ``graph_``'s damping priors."""
    out = []
    for k in range(graph_.size()):
        f = graph_.at(k)
        if isinstance(f, gtsam.PriorFactorVector) and np.allclose(f.noiseModel().sigmas(), SIGMA):
            out.append(f.keys()[0])
    return out


def _watch(monkeypatch):
    """Records, per call of Growth.add, the damping priors it made, and per call of
    Growth.undamped, the damping priors in its input and output."""
    added, undamped = [], []
    real_add, real_undamped = growth.Growth.add, growth.Growth.undamped

    def add(self, frames):
        out = real_add(self, frames)
        added.append((frames[0], _damped(out[0]), list(self.added)))
        return out

    def strip(self, graph_):
        out = real_undamped(self, graph_)
        undamped.append((sorted(self.damping.values()), _damped(graph_), _damped(out)))
        return out

    monkeypatch.setattr(growth.Growth, "add", add)
    monkeypatch.setattr(growth.Growth, "undamped", strip)
    return added, undamped


def test_new_landmarks_are_damped_until_the_next_rebuild(monkeypatch, seq):
    added, undamped = _watch(monkeypatch)
    result = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations,
                                      {"batch_landmark_damping_sigma": SIGMA, **REBUILDS})
    assert result.ok and sorted(result.objects) == sorted(seq.objects)
    # one damping prior per landmark, on its size/shape, in the frame it enters the graph
    before = []
    for frame, damped, landmarks in added:
        new = [oid for oid in landmarks if oid not in before]
        assert sorted(damped) == sorted(S(oid) for oid in new), frame
        before = landmarks
    assert sum(len(d) for _, d, _ in added) == len(seq.objects)
    # every call (the rebuilds after 6 and 12 frames, the batch's end) drops all it has, and only them
    assert len(undamped) == 3
    for indices, into, out in undamped:
        assert len(into) == len(indices) and out == []
    assert len(undamped[0][1]) > 0  # the first landmarks were damped until the first rebuild


def test_the_isam2_method_and_the_default_add_none(monkeypatch, seq):
    added, undamped = _watch(monkeypatch)
    assert graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations,
                                    {"batch_landmark_damping_sigma": SIGMA, **REBUILDS}).ok
    assert graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations, REBUILDS).ok
    assert all(d == [] for _, d, _ in added)
    assert all(into == [] and out == [] for _, into, out in undamped)


def test_damping_changes_the_batch_only(seq):
    """The iSAM2 method is the same run to the last bit whatever the batch's damping."""
    runs = [graph.superquadric_isam2(seq.intrinsics, seq.odometry_poses, seq.observations,
                                     {"batch_landmark_damping_sigma": sigma}) for sigma in (0.0, 0.1)]
    np.testing.assert_array_equal(runs[0].poses, runs[1].poses)


def test_damping_sigma_is_checked():
    with pytest.raises(ValueError, match="batch_landmark_damping_sigma"):
        graph.GraphOptions(batch_landmark_damping_sigma=-0.1)
