"""The batch's last solves can use more rays per silhouette factor than its iSAM2 start
(GraphOptions.final_n_contour) on the landmarks that fit their masks: Growth.resampled swaps
those silhouette factors and nothing else."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from sqfit import graph  # noqa: E402
from sqfit.graph import growth, solve  # noqa: E402
from sqfit.graph.testing import object_ious, synthetic_sequence  # noqa: E402


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(3, n_frames=14, n_objects=3)


def _last_solves(monkeypatch):
    """Records the graph of every whole-graph Levenberg-Marquardt solve (solve._lm)."""
    seen, real = [], solve._lm

    def lm(graph_, values, options, max_lambda=None):
        seen.append(graph_)
        return real(graph_, values, options, max_lambda)

    monkeypatch.setattr(solve, "_lm", lm)
    return seen


def _silhouette_dims(graph_):
    """Row counts of ``graph_``'s factors on a camera, a landmark pose and a size/shape (the
    silhouette factors), sorted."""
    out = []
    for k in range(graph_.size()):
        f = graph_.at(k)
        if len(f.keys()) >= 3 and all(chr(gtsam.Symbol(key).chr()) in "xlso" for key in f.keys()):
            out.append(f.dim())
    return sorted(out)


def test_the_last_solves_use_final_n_contour_rays(monkeypatch, seq):
    seen = _last_solves(monkeypatch)
    result = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations, {"final_n_contour": 48})
    assert result.ok and sorted(result.objects) == sorted(seq.objects)
    dims = _silhouette_dims(seen[-1])
    assert dims and set(dims) == {48}
    assert min(object_ious(result.objects, seq.objects).values()) > 0.9


def test_resampling_swaps_the_silhouette_factors_only(seq):
    problem = graph.check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    options = graph.GraphOptions()
    result = graph.SlamResult("graph", problem.odometry_poses.copy())
    grown = growth.Growth(problem, options, result)
    g, values = grown.add(list(range(problem.n_frames)))
    out, batch = grown.resampled(g, 40)
    assert out.size() == g.size()
    assert _silhouette_dims(g) and set(_silhouette_dims(g)) == {32}
    assert set(_silhouette_dims(out)) == {40} and len(_silhouette_dims(out)) == len(batch)
    # the same views, and every other factor the same object
    kept = [tuple(g.at(k).keys()) for k in range(g.size()) if not grown.batch.holds(g.at(k))]
    assert sorted(kept) == sorted(tuple(out.at(k).keys()) for k in range(out.size()) if not batch.holds(out.at(k)))
    assert sorted(tuple(g.at(k).keys()) for k in range(g.size())) == sorted(tuple(out.at(k).keys()) for k in range(out.size()))
    # at the same values, more rays of the same outlines: about the same error per ray
    e32 = sum(g.at(k).error(values) for k in range(g.size()) if grown.batch.holds(g.at(k))) / 32
    e40 = sum(out.at(k).error(values) for k in range(out.size()) if batch.holds(out.at(k))) / 40
    assert e40 == pytest.approx(e32, rel=0.5)


def test_landmarks_that_do_not_fit_their_masks_keep_their_rays(seq):
    # bounded (the initial fit left the grazing cost) or noise scaled by the misfit: the outline's
    # misfit is the model's, so those landmarks' factors are made again as they were
    problem = graph.check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    oids = sorted(seq.objects)
    grown = growth.Growth(problem, graph.GraphOptions(), graph.SlamResult("graph", problem.odometry_poses.copy()),
                          scales={oids[0]: 1.7})
    grown.bounded.add(oids[1])
    g, values = grown.add(list(range(problem.n_frames)))
    out, batch = grown.resampled(g, 48)
    rays = {}
    for k in range(out.size()):
        f = out.at(k)
        if batch.holds(f):
            rays.setdefault(gtsam.Symbol(f.keys()[1]).index(), set()).add(f.dim())
    assert rays == {oids[0]: {32}, oids[1]: {32}, oids[2]: {48}}
    # the scaled landmark's factors are the same rows as before (the bounded one's were made
    # unbounded in its first frames here: in a run, a landmark is bounded from its initial fit on)
    before = {tuple(g.at(k).keys()): g.at(k).error(values) for k in range(g.size()) if grown.batch.holds(g.at(k))}
    after = {tuple(out.at(k).keys()): out.at(k).error(values) for k in range(out.size()) if batch.holds(out.at(k))}
    kept = [keys for keys in before if gtsam.Symbol(keys[1]).index() == oids[0]]
    assert kept and all(after[keys] == before[keys] for keys in kept)


def test_final_n_contour_0_or_n_contour_keeps_the_rays(monkeypatch, seq):
    seen = _last_solves(monkeypatch)
    runs = [graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations, options)
            for options in ({"final_n_contour": 0}, {"final_n_contour": 32})]
    np.testing.assert_array_equal(runs[0].poses, runs[1].poses)
    assert set(_silhouette_dims(seen[-1])) == {32}


def test_the_default_last_solves_use_64_rays(monkeypatch, seq):
    seen = _last_solves(monkeypatch)
    assert graph.GraphOptions().final_n_contour == 64
    result = graph.superquadric_graph(seq.intrinsics, seq.odometry_poses, seq.observations)
    assert result.ok and set(_silhouette_dims(seen[-1])) == {64}


@pytest.mark.parametrize("value", [-1, 1, 2, 3.5])
def test_final_n_contour_is_0_or_at_least_3(value):
    with pytest.raises(ValueError, match="final_n_contour"):
        graph.GraphOptions(final_n_contour=value)
