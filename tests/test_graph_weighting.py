"""Per-landmark silhouette noise (sqfit.graph.weighting): landmarks that fit their masks poorly count
by the spread their rays show, estimated from a first batch solve and used in a second."""

import numpy as np
import pytest

pytest.importorskip("gtsam")

from sqfit import graph  # noqa: E402
from sqfit.graph import growth, weighting  # noqa: E402
from sqfit.graph.options import GraphOptions  # noqa: E402
from sqfit.graph.problem import check_inputs  # noqa: E402
from sqfit.graph.testing import synthetic_sequence  # noqa: E402


def test_noise_scales_follow_the_misfit(monkeypatch):
    misfits = {1: 0.5, 2: 3.0, 3: 1.05, 4: float("nan"), 5: 2.0}
    monkeypatch.setattr(weighting, "object_misfits", lambda *a, **k: dict(misfits))
    options = GraphOptions()
    oids = list(misfits)
    # above misfit_sigma (1) by more than RESCALE_STEP: scaled by the misfit; a NaN misfit keeps its scale
    assert weighting.noise_scales(None, None, oids, options, {}) == {2: 3.0, 5: 2.0}
    # a scale moves only by more than RESCALE_STEP, and back to 1 once the misfit is low
    assert weighting.noise_scales(None, None, oids, options, {2: 2.9, 1: 2.0, 5: 2.0}) == {1: 1.0}
    half = GraphOptions(misfit_sigma=0.5)
    assert weighting.noise_scales(None, None, oids, half, {}) == {2: 6.0, 3: 2.1, 5: 4.0}
    assert weighting.noise_scales(None, None, oids, GraphOptions(misfit_sigma=0.0), {}) == {}
    with pytest.raises(ValueError, match="misfit_sigma"):
        GraphOptions(misfit_sigma=-1.0)


def test_a_landmarks_scale_widens_its_silhouette_noise():
    seq = synthetic_sequence(2, n_frames=4, n_objects=2)
    problem = check_inputs(seq.intrinsics, seq.odometry_poses, seq.observations)
    frame, oid = next(iter(seq.observations))
    options = GraphOptions()
    plain = growth.view_factor(problem, frame, oid, options, None)
    wide = growth.view_factor(problem, frame, oid, options, None, scale=3.0)
    sigma = options.silhouette_sigma / np.sqrt(options.n_contour)
    np.testing.assert_allclose(plain.noiseModel().noise().sigmas(), sigma)
    np.testing.assert_allclose(wide.noiseModel().noise().sigmas(), 3.0 * sigma)


def test_the_batch_solves_again_only_where_landmarks_misfit():
    seq = synthetic_sequence(1, n_frames=16, n_objects=3)
    args = (seq.intrinsics, seq.odometry_poses, seq.observations)
    off = graph.superquadric_graph(*args, {"misfit_sigma": 0.0})
    default = graph.superquadric_graph(*args)
    # superquadrics that fit their masks: no second solve, the same result as without weighting
    assert not any("solved again" in w for w in default.warnings + off.warnings)
    np.testing.assert_array_equal(default.poses, off.poses)
    # every landmark above a tiny misfit_sigma: the batch runs again with their noise scaled
    strict = graph.superquadric_graph(*args, {"misfit_sigma": 0.01})
    notes = [w for w in strict.warnings if "solved again" in w]
    assert strict.ok and len(notes) == 1 and "object" in notes[0] and " x" in notes[0]
    assert not np.array_equal(strict.poses, off.poses)
