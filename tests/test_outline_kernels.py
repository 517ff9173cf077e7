"""The outline samples behind every view's rays (sqfit.kernels.outline_kernels): the compiled loop gives
:func:`sqfit.views.rays.contour_rays` the same rays as the numpy code, bit for bit, on every option."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from sqfit.kernels import backend
from sqfit.testing import paper_trial
from sqfit.views import Observation
from sqfit.views.rays import CONTOUR, contour_rays
from sqfit.views.visibility import BACKGROUND, BORDER, INSTANCE

pytest.importorskip("numba")

#: (n_contour, band_px, n_inside, smooth_px): the graph's and the fits' options, bands, interior
#: samples, an odd count, and a smoothing arc longer than the outline (it wraps round).
OPTIONS = [(64, 0.0, 0, 0.0), (32, 0.0, 0, 0.0), (16, 0.0, 0, 2.0), (64, 0.0, 0, 2.0), (7, 0.0, 5, 3.5),
           (12, 1.5, 3, 0.0), (3, 0.0, 0, 5000.0)]
FIELDS = ("origins", "directions", "modes", "weights", "view", "two_sided", "offsets", "radii")


def _rays(observations, options, name):
    previous = backend.set_kernels(name)
    try:
        assert backend.kernels_name() == name
        # copies of the observations: each path computes its own outline samples (no shared memo)
        return contour_rays([replace(o) for o in observations], *options)
    finally:
        backend.set_kernels(previous)


def _labelled(observations, seed):
    """The observations with random outline labels (occluded and cut stretches), and one whose
    outline repeats a vertex (an edge of length 0)."""
    rng = np.random.default_rng(seed)
    out = [replace(o, contour_labels=rng.choice([BACKGROUND, INSTANCE, BORDER], size=len(o.contour), p=[0.6, 0.3, 0.1]))
           for o in observations]
    o = observations[0]
    contour = np.insert(o.contour, 5, o.contour[5], axis=0)
    out.append(Observation(o.camera, o.samples, contour, o.centroid, o.area_px, o.touches_border))
    return out


@pytest.mark.parametrize("options", OPTIONS)
@pytest.mark.parametrize("seed", range(3))
def test_compiled_outline_samples_give_the_same_rays_bit_for_bit(seed, options):
    observations = _labelled(paper_trial(seed).observations, seed)
    compiled, plain = _rays(observations, options, "numba"), _rays(observations, options, "numpy")
    for field in FIELDS:
        a, b = getattr(compiled, field), getattr(plain, field)
        assert a.dtype == b.dtype and a.shape == b.shape, field
        assert a.tobytes() == b.tobytes(), field
    # the labels reach the rays: some one-sided, some two-sided
    assert compiled.two_sided.any() and not compiled.two_sided.all()


@pytest.mark.parametrize("name", ["numba", "numpy"])
def test_outline_samples_of_a_square(name):
    """A 40 px square outline: the points evenly spaced along it, their normals the sides' outward
    normals, two-sided where both ends of their edge are background."""
    trial = paper_trial(0).observations[0]
    square = np.array([[100.0, 100.0], [140.0, 100.0], [140.0, 140.0], [100.0, 140.0]])
    if _cross(square[1] - square[0], square[2] - square[1]) < 0:  # counter-clockwise as the masks' outlines
        square = square[::-1].copy()
    labels = np.array([BACKGROUND, BACKGROUND, INSTANCE, INSTANCE])
    o = Observation(trial.camera, square, square, square.mean(axis=0), 1600, False, contour_labels=labels)
    previous = backend.set_kernels(name)
    try:
        rays = contour_rays([o], 8)
    finally:
        backend.set_kernels(previous)
    assert (rays.modes == CONTOUR).all() and len(rays) == 8
    # back to pixels: the rays' directions through the camera
    K, R = o.camera.intrinsics.K, o.camera.rotation
    d = rays.directions @ R
    uv = (d @ K.T)[:, :2] / d[:, 2:3]
    steps = np.diff(np.unwrap(np.arctan2(uv[:, 1] - 120.0, uv[:, 0] - 120.0)))
    assert np.allclose(np.abs(steps), np.pi / 4, atol=0.35)  # 20 px apart on a 160 px outline
    on_side = np.isclose(uv, 100.0, atol=1e-6) | np.isclose(uv, 140.0, atol=1e-6)
    assert on_side.any(axis=1).all()
    # the outward normal in the image is minus the offsets' direction, scaled by the focal lengths
    normal = -(rays.offsets @ R)[:, :2] * [K[0, 0], K[1, 1]]
    outward = np.sign(uv - 120.0) * on_side
    assert np.allclose(normal, outward, atol=1e-9)
    # the edges from vertex 0 and 1 have background at both ends (labels B, B, I, I)
    both = np.array([labels[e] == BACKGROUND and labels[(e + 1) % 4] == BACKGROUND
                     for e in _edges(square, uv)])
    assert (rays.two_sided == both).all()


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


def _edges(square, points):
    """The edge of the square each point lies on (edge k from vertex k to k + 1)."""
    out = []
    for p in points:
        for k in range(4):
            a, b = square[k], square[(k + 1) % 4]
            if abs(_cross(b - a, p - a)) < 1e-6 * np.linalg.norm(b - a) and np.dot(p - a, b - a) >= -1e-9 \
                    and np.dot(p - b, a - b) >= -1e-9:
                out.append(k)
                break
    return out


def test_rays_load_the_outline_kernels_lazily():
    code = ("import sys, sqfit; from sqfit.testing import paper_trial; from sqfit.views.rays import contour_rays; "
            "obs = paper_trial(0).observations; print('sqfit.kernels.outline_kernels' in sys.modules); "
            "contour_rays(obs); print('sqfit.kernels.outline_kernels' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True"]
