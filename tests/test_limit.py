"""Representation limit: sqfit.limit.best_superquadric and its per-object cache, sqsim.world.limit."""

import json

import numpy as np
import pytest
import trimesh

import sqfit

from sqfit.geometry.superquadric import Superquadric, contains, to_mesh, unit_volume, volume
from sqfit.limit import best_superquadric, interior_points, search_volume
from sqfit.metrics import iou_3d
from sqsim.world.household import build_household
from sqsim.world.limit import LimitCache, limit_key, object_limit
from sqsim.world.objects import make_object
from sqsim.world.scene import parse_scene


def test_unit_volume_is_the_factor_of_the_closed_form_volume():
    sq = Superquadric((0.5, 2.0, 1.5), (0.3, 1.4))
    assert volume(sq) == pytest.approx(1.5 * unit_volume((0.3, 1.4)), rel=1e-15)
    assert unit_volume((1.0, 1.0)) == pytest.approx(4 / 3 * np.pi, rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_interior_points_are_inside_uniform_and_about_n(seed):
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.apply_translation((1.0, -2.0, 0.3))
    points = interior_points(box, 4096, seed)
    assert 0.97 * 4096 < len(points) < 1.03 * 4096
    local = points - (1.0, -2.0, 0.3)
    assert np.all(np.abs(local) <= (1.0, 0.5, 0.25))
    # Uniform: a quarter of the box holds about a quarter of the points.
    assert np.mean(local[:, 0] > 0.5) == pytest.approx(0.25, abs=0.02)


def test_interior_points_of_a_mug_lie_in_its_solid_and_fill_it():
    # Independent of the ray parity: the exact boolean of a tiny cube at each point lies in the mug.
    mug = build_household("mug", 3)
    points = interior_points(mug, 2048, 0)
    assert len(points) == pytest.approx(2048, rel=0.04)  # cells of |M| / n: the count measures the volume
    side = 1e-4
    for point in points[:: len(points) // 30]:
        probe = trimesh.creation.box(extents=(side,) * 3, transform=trimesh.transformations.translation_matrix(point))
        inside = trimesh.boolean.intersection([mug, probe], engine="manifold")
        assert inside.volume == pytest.approx(side ** 3, rel=1e-3)


@pytest.mark.parametrize("params", [
    (1.0, 0.6, 0.4, 0.5, 1.2, 0.3, -0.2, 0.1, 0.3, 0.5, -1.0),
    (0.5, 0.8, 1.2, 1.4, 0.3, -1.0, 2.0, 0.5, -1.2, 0.2, 2.0),
])
def test_a_superquadric_mesh_is_its_own_limit(params):
    true = Superquadric.from_vector(params)
    limit = best_superquadric(to_mesh(true, 32), rng=0)
    assert limit.iou >= 0.98
    assert iou_3d(limit.superquadric, true) >= 0.97
    # The parameters up to the symmetries (x <-> y with the same e2; signs of the axes).
    found = limit.superquadric
    assert found.shape == pytest.approx(true.shape, abs=0.12)
    assert sorted(found.size[:2]) == pytest.approx(sorted(true.size[:2]), rel=0.04)
    assert found.size[2] == pytest.approx(true.size[2], rel=0.04)
    np.testing.assert_allclose(found.position, true.position, atol=0.02)
    z_true, z_found = true.rotation_matrix[:, 2], found.rotation_matrix[:, 2]
    assert abs(z_true @ z_found) > 0.99


def test_a_box_is_nearly_a_superquadric_and_a_mug_is_not():
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    limit = best_superquadric(box, rng=0)
    assert limit.iou > 0.97 and max(limit.superquadric.shape) < 0.25
    mug = best_superquadric(build_household("mug", 2), rng=0)
    assert 0.7 < mug.iou < 0.97


def test_the_search_is_reproducible_from_its_seed():
    mesh = build_household("toy", 4)
    a, b = best_superquadric(mesh, rng=5), best_superquadric(mesh, rng=5)
    assert a.superquadric == b.superquadric and a.iou == b.iou
    c = best_superquadric(mesh, rng=6)
    assert c.iou == pytest.approx(a.iou, abs=0.02)  # another sample, nearly the same optimum


def test_bad_meshes_and_settings_are_refused_naming_them():
    box = trimesh.creation.box()
    with pytest.raises(ValueError, match="mesh must be a triangle mesh"):
        best_superquadric(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="mesh must be watertight"):
        best_superquadric(trimesh.Trimesh(box.vertices, box.faces[:-1]))
    with pytest.raises(ValueError, match=r"search_points must be an integer in \[64, points=4096\]"):
        best_superquadric(box, points=4096, search_points=8192)
    with pytest.raises(ValueError, match=r"starts must be an integer in \[1, 24\]"):
        best_superquadric(box, starts=0)
    with pytest.raises(ValueError, match="n must be an integer >= 64"):
        interior_points(box, 10)


def test_search_volume_finds_the_superquadric_a_uniform_sample_was_drawn_from():
    true = Superquadric((0.8, 0.5, 0.3), (0.4, 1.3), (0.5, -0.2, 1.0), (0.4, -0.3, 1.1))
    rng = np.random.default_rng(3)
    box = rng.uniform(-1.0, 1.0, (60000, 3)) + true.position
    sample = box[contains(true, box)]
    (estimate, found), *_ = search_volume(sample, volume(true), 0, final=1)[0]
    assert estimate > 0.95 and iou_3d(found, true) > 0.95


def test_search_volume_refuses_bad_samples_and_settings_naming_them():
    sample = np.random.default_rng(0).uniform(-1.0, 1.0, (200, 3))
    with pytest.raises(ValueError, match=r"sample must hold >= 64 points"):
        search_volume(sample[:10], 1.0)
    with pytest.raises(ValueError, match="volume must be a positive number"):
        search_volume(sample, 0.0)
    with pytest.raises(ValueError, match="final must be an integer >= 1"):
        search_volume(sample, 1.0, final=0)
    with pytest.raises(ValueError, match=r"starts must be an integer in \[1, 24\]"):
        search_volume(sample, 1.0, starts=30)


def test_object_limits_are_cached_per_mesh_up_to_pose_and_scale(tmp_path):
    cache = LimitCache(tmp_path)
    a = make_object(1, "household", (1.5, 1, 1), None, (0.3, -1, 2), (0.3, 1.0, -2), item=("mug", 3))
    b = make_object(1, "household", (0.7, 1, 1), None, (2, 1, 0), (-1.3, 0.2, 0.5), item=("mug", 3))
    other = make_object(1, "household", (0.7, 1, 1), None, (2, 1, 0), (-1.3, 0.2, 0.5), item=("mug", 4))
    assert limit_key(a) == limit_key(b) != limit_key(other)
    la = object_limit(a, cache)
    assert not la.cached and la.seconds > 0 and (cache.hits, cache.misses) == (0, 1)
    lb = object_limit(b, cache)
    assert lb.cached and lb.iou == la.iou and (cache.hits, cache.misses) == (1, 1)
    from sqfit.metrics import iou_3d_mesh

    # Mapped into each object's pose and scale: the same IoU against each mesh.
    assert iou_3d_mesh(la.superquadric, a.mesh) == pytest.approx(la.iou, abs=1e-6)
    assert iou_3d_mesh(lb.superquadric, b.mesh) == pytest.approx(la.iou, abs=1e-6)
    # On disk: a new cache over the same directory finds it.
    again = object_limit(b, LimitCache(tmp_path))
    assert again.cached and again.superquadric == lb.superquadric
    assert len(list(tmp_path.glob("*.json"))) == 1
    json.loads(next(tmp_path.glob("*.json")).read_text())


def test_a_superquadric_ground_truth_is_its_own_limit():
    obj = make_object(1, "superquadric", (1.0, 0.5, 0.7), (0.4, 1.3), (0, 0, 0), (0.1, 0.2, 0.3))
    limit = object_limit(obj, LimitCache())
    assert limit.iou == 1.0 and limit.superquadric == obj.superquadric and limit.seconds == 0.0


def test_experiment_records_and_summarises_the_limit_once_per_object(tmp_path):
    from sqsim.runs.experiment import run_experiment

    scene = parse_scene({"experiment": {"name": "limit", "seed": 1, "trials": 2, "chains": ["default", "1-2"]},
                         "objects": {"kind": "household", "catalogue": ["can", "mug"], "size": [0.8, 1.5],
                                     "position": [-1.0, 1.0]},
                         "trajectory": {"views": 4, "height": 4.0},
                         "masks": {"renderer": "polygon"}}, source="<test>")
    summary = run_experiment(scene, tmp_path, progress=False, figures=False)
    records = [json.loads(line) for line in (tmp_path / "trials.jsonl").read_text().splitlines()]
    assert len(records) == 4
    for trial in (0, 1):
        pair = [r for r in records if r["trial"] == trial]
        assert pair[0]["limit"] == pair[1]["limit"]  # one search per object, shared by its chains
        assert 0.5 < pair[0]["metrics"]["iou_limit"] <= 1.0
        # the limit's silhouettes, placed in the world, match the masks (a can's nearly exactly)
        agreement = pair[0]["metrics"]["r_iou_m_contour_limit"]
        assert agreement == pair[1]["metrics"]["r_iou_m_contour_limit"]
        assert agreement > (0.9 if pair[0]["gt"]["item"] == "can" else 0.5)
    assert len(list((tmp_path / "limits").glob("*.json"))) == 2
    entry = summary["chains"][sqfit.DEFAULT_CHAIN]
    ratios = [r["metrics"]["iou"] / r["metrics"]["iou_limit"] for r in records if r["chain"] == sqfit.DEFAULT_CHAIN]
    assert entry["iou_over_limit"]["median"] == pytest.approx(np.median(ratios))
    assert set(entry["by_item"]) <= {"can", "mug"} and sum(e["fits"] for e in entry["by_item"].values()) == 2
    limits_agree = [r["metrics"]["r_iou_m_contour_limit"] for r in records if r["chain"] == sqfit.DEFAULT_CHAIN]
    assert entry["r_iou_m_contour_limit"]["median"] == pytest.approx(np.median(limits_agree))
    assert all("r_iou_m_contour" in e and "r_iou_m_contour_limit" in e for e in entry["by_item"].values())
    assert "iou_limit" in summary
    table = (tmp_path / "table.md").read_text()
    assert "Limit M" in table and "IOU/Limit M" in table and "| kind |" in table
    assert "Limit" in (tmp_path / "table.tex").read_text()


def test_experiments_on_superquadrics_and_without_the_limit_keep_their_tables(tmp_path):
    from sqsim.runs.experiment import run_experiment

    base = {"experiment": {"name": "sq", "seed": 1, "trials": 1, "chains": ["1-2"]}, "masks": {"renderer": "polygon"}}
    summary = run_experiment(parse_scene(base, source="<test>"), tmp_path / "sq", progress=False, figures=False)
    record = json.loads((tmp_path / "sq" / "trials.jsonl").read_text())
    assert "iou_limit" not in record["metrics"] and "limit" not in record  # 1 by definition, not written
    assert "iou_limit" not in summary and "Limit" not in (tmp_path / "sq" / "table.md").read_text()
    off = {**base, "experiment": {**base["experiment"], "limit": False}, "objects": {"kind": "box"}}
    summary = run_experiment(parse_scene(off, source="<test>"), tmp_path / "off", progress=False, figures=False)
    record = json.loads((tmp_path / "off" / "trials.jsonl").read_text())
    assert "iou_limit" not in record["metrics"] and "iou_limit" not in summary
