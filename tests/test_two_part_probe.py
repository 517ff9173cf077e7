"""scripts/two_part_probe.py: its L-shaped starts, the union's silhouette IoU and the union's sample."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import shapely

import sqfit
from sqfit.fitting.costs import ObservationSet
from sqfit.geometry.silhouette import silhouette
from sqfit.geometry.superquadric import contains, euler_to_matrix
from sqfit.kernels.backend import compiled, set_kernels
from sqfit.testing import paper_trial

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "two_part_probe.py"


def _probe():
    spec = importlib.util.spec_from_file_location("two_part_probe", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_starts_are_slabs_on_two_adjacent_faces_of_the_fits_box():
    probe = _probe()
    xi = np.r_[1.0, 2.0, 3.0, 1.0, 1.0, 0.5, -0.5, 2.0, 0.3, -0.2, 1.1]
    starts = probe.l_starts(xi)
    assert starts.shape == (12, 2, 11)
    R = euler_to_matrix(xi[8:11])
    faces = set()
    for pair in starts:
        thin_axes = []
        for part in pair:
            assert np.allclose(part[8:11], xi[8:11]) and np.allclose(part[3:5], 0.2)
            thin = int(np.argmax(np.abs(part[0:3] - xi[0:3])))
            assert np.isclose(part[thin], probe.THIN * xi[thin])
            offset = R.T @ (part[5:8] - xi[5:8])  # in the box's frame: on the face, inside the box
            assert np.isclose(abs(offset[thin]), xi[thin] * (1 - probe.THIN))
            assert np.allclose(np.delete(offset, thin), 0.0)
            thin_axes.append((thin, np.sign(offset[thin])))
        assert thin_axes[0][0] != thin_axes[1][0]  # two different faces, adjacent
        faces.add(tuple(sorted(thin_axes)))
    assert len(faces) == 12


def test_the_unions_silhouette_iou_is_the_single_ones_for_one_part_or_the_same_part_twice():
    probe = _probe()
    trial = paper_trial(0)
    obs, truth = ObservationSet(trial.observations), trial.gt
    xi = truth.to_vector()
    one = probe.union_ious(xi[None, None], obs)[0]
    twice = probe.union_ious(np.stack([xi, xi])[None], obs)[0]
    assert np.allclose(one, twice)
    for v, o in enumerate(trial.observations):
        sil = shapely.Polygon(silhouette(truth, o.camera, probe.VERTICES))
        contour = shapely.Polygon(o.contour).buffer(0)
        inter = sil.intersection(contour).area
        assert np.isclose(one[v], inter / (sil.area + contour.area - inter))
    assert one.min() > 0.95  # the truth's silhouettes match its masks


def test_the_compiled_union_overlap_agrees_with_shapely():
    probe = _probe()
    trial = paper_trial(3)
    obs, xi = ObservationSet(trial.observations), trial.gt.to_vector()
    rng = np.random.default_rng(0)
    X = []
    for _ in range(6):  # two parts about the truth: overlapping, nested or apart
        a, b = xi.copy(), xi.copy()
        a[0:3] *= rng.uniform(0.3, 1.0, 3)
        b[0:3] *= rng.uniform(0.3, 1.0, 3)
        a[5:8] += rng.normal(0.0, 0.5, 3)
        b[5:8] += rng.normal(0.0, 0.5, 3)
        b[8:11] += rng.normal(0.0, 0.5, 3)
        X.append([a, b])
    X = np.array(X)
    previous = set_kernels("numba")
    try:
        fast = probe.union_ious(X, obs)
        set_kernels("numpy")
        slow = probe.union_ious(X, obs)
    finally:
        set_kernels(previous)
    assert np.all(slow > 0) and np.all(slow < 1)
    assert np.allclose(fast, slow, atol=1e-9)


def test_the_union_sample_lies_in_the_parts_and_its_volume_is_theirs():
    probe = _probe()
    a = sqfit.Superquadric((1.0, 1.0, 1.0), (1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    b = sqfit.Superquadric((0.5, 0.5, 0.5), (1.0, 1.0), (5.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # apart from a
    points, vol = probe.union_sample([a, b], 5000, np.random.default_rng(0))
    assert len(points) == 5000 and np.all(contains(a, points) | contains(b, points))
    exact = 4.0 / 3.0 * np.pi * (1.0 + 0.5**3)
    assert abs(vol / exact - 1.0) < 0.05


def test_the_union_overlap_kernel_on_known_squares():
    previous = set_kernels("numba")
    try:
        k = compiled("silhouettes")
    finally:
        set_kernels(previous)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    pair = np.stack([square, square + [0.5, 0.0]])  # overlapping by half: the union is 1.5 x 1
    apart = np.stack([square, square + [3.0, 0.0]])
    polys = np.ascontiguousarray(np.stack([pair, apart])[:, :, None])  # (2, 2, 1 view, 4, 2)
    # two views: the contour the first square (view 0), a 6 x 2 box around both pairs (view 1)
    contours = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0],
                         [-1.0, -0.5], [5.0, -0.5], [5.0, 1.5], [-1.0, 1.5]])
    starts = np.array([0, 4, 8])
    polys = np.ascontiguousarray(np.repeat(polys, 2, axis=2))
    pairs = np.array([[0, 0], [0, 1], [1, 0], [1, 1]])
    inter, area, ok = k.union_overlaps(polys, pairs, contours, starts, 1e-9)
    assert ok.all()
    assert np.allclose(area, [1.5, 1.5, 2.0, 2.0])
    assert np.allclose(inter, [1.0, 1.5, 1.0, 2.0])


def test_the_unions_gradient_follows_its_finite_differences():
    probe = _probe()
    trial = paper_trial(3)
    obs, xi = ObservationSet(trial.observations), trial.gt.to_vector()
    rng = np.random.default_rng(2)
    for _ in range(3):  # two overlapping parts about the truth, as the fit meets them
        X = np.stack([xi, xi])
        X[:, 0:3] *= rng.uniform(0.5, 0.9, (2, 3))
        X[:, 5:8] += rng.normal(0.0, 0.3, (2, 3))
        X[1, 8:11] += rng.normal(0.0, 0.3, 3)
        iou, grad = probe.union_gradient(X, obs)
        assert np.allclose(iou, probe.union_ious(X[None], obs)[0])
        x, diff = X.ravel(), np.zeros_like(grad)
        for j in range(22):
            h = 1e-5 * max(abs(x[j]), 1.0)
            up, down = x.copy(), x.copy()
            up[j] += h
            down[j] -= h
            diff[:, j] = (probe.union_ious(up.reshape(1, 2, 11), obs)[0]
                          - probe.union_ious(down.reshape(1, 2, 11), obs)[0]) / (2 * h)
        # the midpoint sums and the polygon's vertex model: a few per cent, the same direction
        assert np.linalg.norm(grad - diff) < 0.15 * np.linalg.norm(diff)
        assert (grad * diff).sum() > 0.99 * np.linalg.norm(grad) * np.linalg.norm(diff)


def test_bad_arguments_are_refused_by_name(capsys):
    probe = _probe()
    for argv, message in ((["--trials", "0"], "--trials must be >= 1, got 0"), (["--mu", "-1"], "--mu must be >= 0")):
        with pytest.raises(SystemExit):
            probe.main(argv)
        assert message in capsys.readouterr().err
