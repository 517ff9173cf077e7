import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from sqfit import Superquadric
from sqfit import constants as C
from sqfit.metrics import bounding_box, intersection_volume, iou_3d, iou_3d_mesh, success
from sqfit.geometry.superquadric import contains, sample_surface_uniform, to_mesh, volume


def random_pair(rng):
    """A random paper-range superquadric and a perturbed copy (so the pair overlaps)."""
    a = Superquadric(rng.uniform(0.1, 5, 3), rng.uniform(0.1, 1.9, 2), rng.uniform(-5, 5, 3), rng.uniform(-np.pi, np.pi, 3))
    xi = a.to_vector()
    xi[:3] *= rng.uniform(0.7, 1.3, 3)
    xi[3:5] = np.clip(xi[3:5] + rng.uniform(-0.5, 0.5, 2), 0.1, 1.9)
    xi[5:8] += rng.normal(0, 0.2, 3) * np.min(a.size)
    xi[8:] += rng.normal(0, 0.2, 3)
    return a, Superquadric.from_vector(xi)


@pytest.mark.parametrize("seed", range(8))
def test_iou_3d_agrees_with_manifold_boolean_within_one_percent(seed):
    a, b = random_pair(np.random.default_rng(seed))
    exact = iou_3d_mesh(a, to_mesh(b, 96), resolution=96)
    assert exact > 0.05
    assert iou_3d(a, b) == pytest.approx(exact, rel=0.01)


@pytest.mark.parametrize("shape", [(0.1, 0.1), (1.9, 1.9), (0.1, 1.9), (C.SILHOUETTE_SHAPE_BOUNDS[0],) * 2,
                                   (C.SHAPE_DOMAIN[0], 1.0)])
def test_iou_3d_thin_and_edgy_shapes(shape):
    a = Superquadric((4.0, 0.15, 0.1), shape, (1.0, 0.0, 0.0), (0.3, -0.4, 0.5))
    b = Superquadric((4.0, 0.15, 0.12), shape, (1.05, 0.0, 0.0), (0.3, -0.4, 0.5))
    exact = iou_3d_mesh(a, to_mesh(b, 128), resolution=128)
    assert iou_3d(a, b) == pytest.approx(exact, rel=0.01)


def test_iou_3d_identity_disjoint_and_symmetry():
    a, b = random_pair(np.random.default_rng(42))
    assert iou_3d(a, a) == 1.0
    far = Superquadric(a.size, a.shape, np.asarray(a.position) + 100.0, a.rotation)
    assert iou_3d(a, far) == 0.0 and not success(0.0)
    assert iou_3d(a, b) == pytest.approx(iou_3d(b, a), rel=0.01)


@pytest.mark.parametrize("shape", [(0.1, 0.1), (0.1, 1.9), (1.9, 0.1), (1.9, 1.9), (1.0, 1.0), (0.5, 1.5),
                                   (C.SILHOUETTE_SHAPE_BOUNDS[0],) * 2, (C.SHAPE_DOMAIN[0],) * 2])
@pytest.mark.parametrize("size", [(1.0, 1.0, 1.0), (4.0, 0.15, 0.1), (0.1, 5.0, 2.0)])
def test_iou_3d_of_a_superquadric_with_itself_is_exactly_one(shape, size):
    # Box-like shapes were 0.989 when the intersection came from a grid and the volumes from
    # the closed form; both now come from the same cells.
    sq = Superquadric(size, shape, (1.0, -2.0, 0.5), (0.3, -1.2, 2.5))
    assert iou_3d(sq, sq) == 1.0
    assert iou_3d(sq, Superquadric.from_vector(sq.to_vector())) == 1.0


@settings(max_examples=60, deadline=None)
@given(size=st.tuples(*[st.floats(0.1, 5.0)] * 3), shape=st.tuples(*[st.floats(0.1, 1.9)] * 2),
       position=st.tuples(*[st.floats(-5.0, 5.0)] * 3), rotation=st.tuples(*[st.floats(-np.pi, np.pi)] * 3),
       cells=st.sampled_from([512, 2**12, 2**16, 2**18]))
def test_iou_3d_with_itself_is_one_for_every_shape(size, shape, position, rotation, cells):
    sq = Superquadric(size, shape, position, rotation)
    assert iou_3d(sq, sq, cells) == 1.0


def test_intersection_volume_of_nested_superquadrics_is_the_inner_volume():
    inner = Superquadric((0.5, 0.3, 0.2), (0.4, 1.2), (0.1, 0.0, 0.0), (0.2, 0.1, -0.3))
    outer = Superquadric((3.0, 3.0, 3.0), (1.0, 1.0))
    assert intersection_volume(inner, outer) == pytest.approx(volume(inner), rel=1e-12)
    assert iou_3d(inner, outer) == pytest.approx(volume(inner) / volume(outer), rel=1e-12)


def test_iou_3d_rejects_a_grid_too_coarse():
    sq = Superquadric((1, 1, 1))
    with pytest.raises(ValueError, match="cells must be an integer >= 512"):
        iou_3d(sq, sq, cells=100)
    with pytest.raises(ValueError, match="cells must be an integer >= 512"):
        iou_3d(sq, sq, cells=1000.5)


def test_iou_3d_rejects_non_superquadrics():
    with pytest.raises(ValueError, match="b must be a Superquadric"):
        iou_3d(Superquadric((1, 1, 1)), np.ones(11))


def test_iou_3d_mesh_ground_truth_box():
    # A near-box superquadric against the box it approximates.
    sq = Superquadric((1.0, 2.0, 0.5), (0.1, 0.1))
    box = trimesh.creation.box(extents=(2.0, 4.0, 1.0))
    assert iou_3d_mesh(sq, box) == pytest.approx(1.0, abs=0.02)
    with pytest.raises(ValueError, match="watertight"):
        iou_3d_mesh(sq, trimesh.Trimesh(box.vertices, box.faces[:-1]))


def test_bounding_box_contains_the_surface():
    a, _ = random_pair(np.random.default_rng(3))
    pts = sample_surface_uniform(a, 2000, 0)
    lo, hi = bounding_box(a)
    assert np.all(pts >= lo - 1e-9) and np.all(pts <= hi + 1e-9)
    assert np.all(contains(a, (lo + hi)[None] / 2))


def test_r_iou_of_the_truth_is_one_and_drops_with_error():
    from sqfit.metrics import r_iou
    from sqfit.geometry.silhouette import silhouette
    from sqfit.testing import paper_trial

    trial = paper_trial(5)
    truth = [silhouette(trial.gt, cam, 256) for cam in trial.cameras]
    assert r_iou(trial.gt, trial.cameras, truth) == pytest.approx(1.0, abs=1e-9)
    xi = trial.gt.to_vector()
    xi[:3] *= 1.2  # 20 % larger in every axis: projected areas grow ~1.44x
    worse = r_iou(Superquadric.from_vector(xi), trial.cameras, truth)
    assert 1 / 1.44 - 0.05 < worse < 0.95
    with pytest.raises(ValueError, match="need one polygon per camera"):
        r_iou(trial.gt, trial.cameras, truth[:2])
