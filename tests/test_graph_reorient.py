"""The batch's last check of every landmark's axes (sqfit.graph.refit.reorient_landmarks)."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit import graph  # noqa: E402
from sqfit.fitting.axis_screen import axis_candidates  # noqa: E402
from sqfit.graph import landmark, problem as gproblem, refit  # noqa: E402
from sqfit.graph.testing import synthetic_sequence  # noqa: E402
from sqfit.metrics import iou_3d  # noqa: E402

from gtsam.symbol_shorthand import L, S  # noqa: E402
from _helpers import graph_values  # noqa: E402


@pytest.fixture(scope="module")
def seq():
    return synthetic_sequence(1, n_frames=16, n_objects=3)


def _with_object_2_turned(seq):
    """The problem of ``seq`` at its true poses; every landmark at the truth but object 2's, whose
    section is turned by 45 degrees (3H's ``R45`` of the truth: ``e2`` -> ``2 - e2``, the xy sizes the
    section's diagonal radius), the kind of minimum of the graph no solve leaves."""
    prob = gproblem.check_inputs(seq.intrinsics, seq.true_poses, seq.observations)
    turned = sqfit.Superquadric.from_vector(axis_candidates(seq.objects[2].to_vector())[1])
    return prob, graph_values(seq.true_poses, {**seq.objects, 2: turned})


def _landmark(values, oid):
    return landmark.landmark_to_superquadric(values.atPose3(L(oid)).matrix(), values.atVector(S(oid)))


def test_a_landmark_on_other_axes_is_reoriented_whatever_its_misfit(seq):
    prob, values = _with_object_2_turned(seq)
    before = {oid: _landmark(values, oid) for oid in seq.objects}
    assert iou_3d(before[2], seq.objects[2]) < 0.8
    misfit = refit.object_misfits(prob, values, list(seq.objects), graph.GraphOptions())
    # no misfit threshold: with the re-fits' above object 2's misfit, its axes are still tested
    options = graph.GraphOptions(refit_misfit=2.0 * misfit[2])
    result = graph.SlamResult("graph", seq.true_poses)
    # off, or for a landmark whose factors are bounded (its fit left the grazing cost): untouched
    assert refit.reorient_landmarks(prob, values, list(seq.objects), graph.GraphOptions(axis_check_frames=0), result) == {}
    assert refit.reorient_landmarks(prob, values, [2], options, result, bounded=frozenset({2})) == {}
    # nor above the check's misfit cap (misfit_sigma: an outline taken for the model's)
    assert refit.reorient_landmarks(prob, values, [2], options, result, misfit_cap=0.99 * misfit[2]) == {}
    assert not result.warnings
    changed = refit.reorient_landmarks(prob, values, list(seq.objects), options, result)
    assert changed == {2: False}
    assert [w.split(":")[0] for w in result.warnings] == ["object 2"] and "axes re-chosen" in result.warnings[0]
    after = refit.object_misfits(prob, values, [2], options)[2]
    assert after < misfit[2]
    assert iou_3d(_landmark(values, 2), seq.objects[2]) > 0.9
    for oid in (1, 3):  # at the truth: their own axes screen lowest
        np.testing.assert_array_equal(_landmark(values, oid).to_vector(), before[oid].to_vector())
    # the re-oriented landmark is kept: a second call changes nothing
    assert refit.reorient_landmarks(prob, values, list(seq.objects), options, result) == {}


def test_axis_check_frames_is_checked():
    assert graph.GraphOptions(axis_check_frames=0).axis_check_frames == 0
    with pytest.raises(ValueError, match="axis_check_frames"):
        graph.GraphOptions(axis_check_frames=-1)
    with pytest.raises(ValueError, match="axis_check_frames"):
        graph.GraphOptions(axis_check_frames=2.5)
