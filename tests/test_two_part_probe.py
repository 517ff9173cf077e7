"""scripts/two_part_probe.py: its L-shaped starts, the union's silhouette IoU and the union's sample."""

import importlib.util
from pathlib import Path

import numpy as np
import shapely

import sqfit
from sqfit.geometry.silhouette import camera_arrays, silhouette
from sqfit.geometry.superquadric import contains, euler_to_matrix
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
    obs, truth = trial.observations, trial.gt
    cameras = camera_arrays([o.camera for o in obs])
    contours = [shapely.Polygon(o.contour).buffer(0) for o in obs]
    xi = truth.to_vector()
    one = probe.union_ious(xi[None, None], cameras, contours)[0]
    twice = probe.union_ious(np.stack([xi, xi])[None], cameras, contours)[0]
    assert np.allclose(one, twice)
    for v, (o, contour) in enumerate(zip(obs, contours)):
        sil = shapely.Polygon(silhouette(truth, o.camera, probe.VERTICES))
        inter = sil.intersection(contour).area
        assert np.isclose(one[v], inter / (sil.area + contour.area - inter))
    assert one.min() > 0.95  # the truth's silhouettes match its masks


def test_the_union_sample_lies_in_the_parts_and_its_volume_is_theirs():
    probe = _probe()
    a = sqfit.Superquadric((1.0, 1.0, 1.0), (1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    b = sqfit.Superquadric((0.5, 0.5, 0.5), (1.0, 1.0), (5.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # apart from a
    points, vol = probe.union_sample([a, b], 5000, np.random.default_rng(0))
    assert len(points) == 5000 and np.all(contains(a, points) | contains(b, points))
    exact = 4.0 / 3.0 * np.pi * (1.0 + 0.5**3)
    assert abs(vol / exact - 1.0) < 0.05
