"""The landmark's size/shape variable (sqfit.graph.shapevar, GraphOptions.shape_variable): ``plain``
stores [a, e] as they are; ``log`` stores log sizes and logistic exponents, so every value is a valid
superquadric, and the factors chain their Jacobians through the map."""

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

import sqfit  # noqa: E402
from sqfit import graph  # noqa: E402
from sqfit.graph import factors, landmark, scale, shapevar  # noqa: E402
from sqfit.graph.testing import object_ious, synthetic_sequence  # noqa: E402
from sqfit.testing import polygon_mask  # noqa: E402
from _numeric import central_difference  # noqa: E402

from gtsam.symbol_shorthand import L, S, X  # noqa: E402

LOG = shapevar.ShapeVariable("log")
K_INTR = sqfit.Intrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
SQ = sqfit.Superquadric((0.5, 0.3, 0.4), (0.6, 1.3), (0.2, -0.1, 0.4), (0.3, -0.2, 0.5))
CAMERA = sqfit.look_at([4.0, 0.5, 1.5], [0.0, 0.0, 0.4])


@pytest.mark.parametrize("shape", [(0.3, 0.5, 1.2, 0.1, 1.9), (0.02, 4.0, 0.11, 1.0, 0.5)])
def test_log_variable_round_trips_and_its_jacobian_is_the_maps_derivative(shape):
    z = LOG.value(shape)
    s, d = LOG.shape_and_jacobian(z)
    np.testing.assert_allclose(s, shape, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.diag(d), central_difference(LOG.shape, z), rtol=1e-6, atol=1e-9)


def test_every_log_value_is_a_valid_superquadric():
    z = np.array([[-1e3, -50.0, 0.0, -1e3, 1e3], [1e3, 50.0, 3.0, 40.0, -40.0]])
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        s, d = LOG.shape_and_jacobian(z)
    assert np.isfinite(s).all() and np.isfinite(d).all()
    assert (s[:, :3] >= shapevar.A_MIN).all() and (s[:, :3] <= shapevar.A_MIN + 1000.0 + 1e-9).all()
    assert (s[:, 3:] >= shapevar.E_MIN).all() and (s[:, 3:] <= shapevar.E_MAX).all()
    assert d[1, 0] == 0.0  # sizes stop growing at 1 km
    # a shape outside the range maps just inside it
    np.testing.assert_allclose(LOG.shape(LOG.value([0.0, -1.0, 0.5, 0.0, 3.0])), [shapevar.A_MIN] * 2 + [0.5, 0.05, 2.0],
                               atol=1e-6)


def test_plain_is_the_identity():
    s = np.array([0.3, 0.5, 1.2, 0.1, 1.9])
    z = shapevar.PLAIN.value(s)
    np.testing.assert_array_equal(z, s)
    out, d = shapevar.PLAIN.shape_and_jacobian(z)
    np.testing.assert_array_equal(out, s)
    np.testing.assert_array_equal(d, np.ones(5))
    np.testing.assert_array_equal(shapevar.PLAIN.prior_sigmas(s, 10.0), np.full(5, 10.0))


@pytest.mark.parametrize("variable", [shapevar.PLAIN, LOG])
def test_scaling_moves_the_sizes_only(variable):
    s = np.array([0.3, 0.5, 1.2, 0.6, 1.3])
    np.testing.assert_allclose(variable.shape(variable.scaled(variable.value(s), 1.07)), np.r_[1.07 * s[:3], s[3:]],
                               rtol=1e-12)


def test_log_prior_has_the_plain_sigma_to_first_order():
    s = np.array([0.3, 0.5, 1.2, 0.6, 1.3])
    d = LOG.shape_and_jacobian(LOG.value(s))[1]
    np.testing.assert_allclose(LOG.prior_sigmas(s, 0.2) * d, 0.2)


def _values(variable, sq=SQ):
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(CAMERA))
    T, s = landmark.superquadric_to_landmark(sq)
    values.insert(L(0), gtsam.Pose3(T))
    values.insert(S(0), variable.value(s))
    return values


def _linearised(factor, values):
    return factor.unwhitenedError(values), factor.linearize(values).jacobian()[0]


def test_factors_on_the_log_variable_chain_their_jacobians():
    cam = sqfit.Camera(K_INTR, CAMERA)
    rays = landmark.camera_rays(sqfit.Observation.from_mask(cam, polygon_mask(SQ, cam), rng=0), 24)
    # off the mask's outline, on the floor's tilt and outside the size bound: every factor has rows
    moved = sqfit.Superquadric((0.55, 0.05, 0.4), (0.6, 1.3), (0.25, -0.1, 0.4), (0.3, -0.2, 0.5))
    noise = gtsam.noiseModel.Unit.Create(len(rays))
    d = LOG.shape_and_jacobian(LOG.value(landmark.superquadric_to_landmark(moved)[1]))[1]
    made = [
        lambda v: factors.silhouette_factor(noise, X(0), L(0), S(0), rays, factors.SilhouetteFactors(v)),
        lambda v: factors.bounds_factor(S(0), 100.0, v),
        lambda v: factors.floor_factor(gtsam.noiseModel.Unit.Create(1), L(0), S(0), -0.5, v),
    ]
    for make in made:
        r_plain, A_plain = _linearised(make(shapevar.PLAIN), _values(shapevar.PLAIN, moved))
        r_log, A_log = _linearised(make(LOG), _values(LOG, moved))
        assert np.abs(r_plain).max() > 1e-3
        np.testing.assert_allclose(r_log, r_plain, atol=1e-9)
        # the pose columns are the same; the size/shape columns scaled by the map's derivative
        np.testing.assert_allclose(A_log[:, :-5], A_plain[:, :-5], atol=1e-8)
        np.testing.assert_allclose(A_log[:, -5:], A_plain[:, -5:] * d, atol=1e-8)


def test_rescaled_values_keep_their_variable():
    values = _values(LOG)
    moved = scale.rescaled(values, np.zeros(3), 1.1, [X(0)], [L(0)], [S(0)], LOG)
    np.testing.assert_allclose(LOG.shape(moved.atVector(S(0))), np.r_[1.1 * np.array(SQ.size), SQ.shape], rtol=1e-12)


@pytest.mark.parametrize("method", ["graph", "graph-isam2"])
def test_a_graph_on_the_log_variable_solves_a_sequence(method):
    seq = synthetic_sequence(2, n_frames=14, n_objects=3)
    result = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method],
                       {"shape_variable": "log"})[method]
    assert result.ok and sorted(result.objects) == sorted(seq.objects)
    assert min(object_ious(result.objects, seq.objects).values()) > 0.85


def test_an_unknown_shape_variable_is_refused():
    with pytest.raises(ValueError, match="shape_variable must be one of plain, log, got 'exp'"):
        graph.GraphOptions(shape_variable="exp")
    with pytest.raises(ValueError, match="shape variable must be one of"):
        shapevar.ShapeVariable("exp")
