"""Outline rays per view of the silhouette stages: ``FitOptions.n_contour`` (default 64), the scene key
``fit.n_contour``, and the factor graph's first landmark fits on ``GraphOptions.fit_n_contour``
(default the fitter's 64), the batch's re-fits on ``batch_refit_n_contour``
(default 32)."""
from pathlib import Path

import numpy as np
import pytest

import sqfit
from sqfit.fitting import grazing
from sqfit.fitting.costs import ObservationSet
from sqfit.metrics import iou_3d
from sqfit.testing import paper_trial

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def trial():
    return paper_trial(0)


def _count_rays(monkeypatch):
    """The rays per view of every outline ray set the silhouette stages make (appended to the list
    returned) while ``monkeypatch`` holds."""
    counts, real = [], grazing.contour_rays

    def rays(observations, n_contour=64, *args, **kwargs):
        counts.append(n_contour)
        return real(observations, n_contour, *args, **kwargs)

    monkeypatch.setattr(grazing, "contour_rays", rays)
    return counts


def test_the_default_is_64_rays_per_view():
    assert sqfit.FitOptions().n_contour == grazing.N_CONTOUR == 64


@pytest.mark.parametrize("value", [2, 0, -1, 32.5])
def test_n_contour_must_be_an_integer_of_at_least_3(value):
    with pytest.raises(ValueError, match="n_contour must be an integer >= 3"):
        sqfit.FitOptions(n_contour=value)


def test_outline_rays_has_n_contour_rays_per_view_and_caches_each_count(trial):
    obs = ObservationSet(trial.observations)
    views = len(trial.observations)
    assert len(grazing.outline_rays(obs, 32)) == 32 * views
    assert len(grazing.outline_rays(obs)) == 64 * views
    assert len(grazing.outline_rays(obs, 32)) == 32 * views


def test_a_fit_grazes_n_contour_rays_per_view(monkeypatch, trial):
    counts = _count_rays(monkeypatch)
    fits = {}
    for n in (24, 64):
        counts.clear()
        fits[n] = sqfit.fit(trial.observations, "default", options={"n_contour": n})
        assert counts and set(counts) == {n}
    # fewer rays, another fit of the same object, still a good one
    assert not np.array_equal(fits[24].superquadric.to_vector(), fits[64].superquadric.to_vector())
    assert iou_3d(fits[24].superquadric, trial.gt) > 0.95


def test_the_scene_key_reaches_the_fits(monkeypatch):
    from sqsim.runs.experiment import fit_trial
    from sqsim.world.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "paper.toml")
    assert scene.fit.n_contour == 64
    with pytest.raises(ValueError, match=r"fit.n_contour"):
        scene.with_overrides({"fit.n_contour": 2})
    counts = _count_rays(monkeypatch)
    fit_trial(scene.with_overrides({"fit.n_contour": 20, "objects.count": 1}).to_dict(), 0, ["default"])
    assert counts and set(counts) == {20}


def test_the_graphs_first_fits_use_fit_n_contour_and_the_batchs_refits_batch_refit_n_contour(monkeypatch):
    pytest.importorskip("gtsam")
    from sqfit import graph
    from sqfit.fitting import pipeline
    from sqfit.graph import refit
    from sqfit.graph.testing import synthetic_sequence

    defaults = graph.GraphOptions()
    assert defaults.fit_n_contour == sqfit.FitOptions().n_contour == 64 and defaults.batch_refit_n_contour == 32
    for name in ("fit_n_contour", "batch_refit_n_contour"):
        with pytest.raises(ValueError, match=f"{name} must be an integer >= 3"):
            graph.GraphOptions(**{name: 2})
    seq, seen, inside = synthetic_sequence(0, n_frames=6, n_objects=2), [], []
    real_fit, real_refit = pipeline.fit, refit.landmark_fit

    def fit(observations, chain=None, **kw):
        seen.append((bool(inside), sqfit.FitOptions.coerce(kw.get("options")).n_contour))
        return real_fit(observations, chain, **kw)

    def landmark_refit(*args, **kw):
        inside.append(True)
        try:
            return real_refit(*args, **kw)
        finally:
            inside.pop()

    monkeypatch.setattr(pipeline, "fit", fit)
    monkeypatch.setattr(refit, "landmark_fit", landmark_refit)
    # every landmark re-fitted at every chance (misfit thresholds of ~0), iSAM2 rebuilt every 3 frames
    always = {"refit_misfit": 1e-9, "batch_rebuild_refit_misfit": 1e-9, "isam2_rescale_every": 3,
              "isam2_rescale_parallax_deg": 0.0}
    chosen = {**always, "fit_n_contour": 20, "batch_refit_n_contour": 24}
    # (method, options, rays of the first fits, rays of the re-fits): iSAM2 re-fits on fit_n_contour
    for method, options, first, again in (("graph", always, 64, 32), ("graph", chosen, 20, 24),
                                          ("graph-isam2", always, 64, 64), ("graph-isam2", chosen, 20, 20)):
        seen.clear()
        result = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, [method], options)[method]
        assert result.ok
        assert {n for is_refit, n in seen if not is_refit} == {first}, (method, options)
        assert {n for is_refit, n in seen if is_refit} == {again}, (method, options)
