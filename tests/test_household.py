"""Household catalogue (sqsim.world.household) and its scene integration: kinds, proportions, mesh files."""

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sqsim.world.household import CATALOGUE, build_household, check_catalogue
from sqsim.world.layout import ground_layout
from sqsim.world.objects import draw_objects, make_object, make_objects, sample_objects
from sqsim.world.scene import load_scene, parse_scene

KINDS = list(CATALOGUE)
SCENES = Path(__file__).resolve().parent.parent / "scenes"


# --- the catalogue --------------------------------------------------------------------------------

def test_the_catalogue_has_at_least_ten_kinds():
    assert len(CATALOGUE) >= 10
    assert {"mug", "bottle", "chair", "toy"} <= set(CATALOGUE)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("name", KINDS)
def test_every_kind_is_one_closed_outward_solid_centred_on_its_box(name, seed):
    mesh = build_household(name, seed)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert mesh.body_count == 1
    np.testing.assert_allclose(mesh.bounds[0], -mesh.bounds[1], atol=1e-12)
    # Metres, everyday sizes: between a can and a table.
    assert 0.05 < mesh.extents.max() < 2.0


@pytest.mark.parametrize("name", KINDS)
def test_a_kind_is_reproducible_from_its_seed_and_varies_across_seeds(name):
    a, b = build_household(name, 7), build_household(name, 7)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    extents = np.array([build_household(name, s).extents for s in range(5)])
    spread = extents.max(axis=0) / extents.min(axis=0)
    assert spread.max() > 1.05  # proportions drawn per seed


@pytest.mark.parametrize("name", ["bottle", "can", "bowl", "lamp"])
def test_solids_of_revolution_stand_on_the_z_axis(name):
    mesh = build_household(name, 1)
    assert mesh.extents[0] == pytest.approx(mesh.extents[1], rel=1e-3)
    np.testing.assert_allclose(mesh.center_mass[:2], 0.0, atol=1e-3 * mesh.extents.max())


def test_canonical_frame_handle_to_plus_x_backs_to_plus_y():
    mug = build_household("mug", 2)
    assert mug.center_mass[0] < -0.005  # the handle widens the box to +x only
    tip = mug.vertices[np.argmax(mug.vertices[:, 0])]
    assert abs(tip[1]) < 0.015 and abs(tip[2]) < 0.3 * mug.extents[2]
    for name in ("chair", "laptop"):  # backrest / lid rise behind the seat / keyboard
        mesh = build_household(name, 2)
        assert mesh.vertices[np.argmax(mesh.vertices[:, 2]), 1] > 0
    table = build_household("table", 2)
    assert table.extents[2] < table.extents[0]  # z up: a table is wider than tall


def test_catalogue_names_are_checked():
    assert check_catalogue(["mug", "can", "mug"]) == ("mug", "can")
    with pytest.raises(ValueError, match=r"unknown household kind\(s\) \['spoon'\] \(valid: mug, bottle"):
        check_catalogue(["mug", "spoon"])
    with pytest.raises(ValueError, match="must be a non-empty list of household kinds"):
        check_catalogue([])
    with pytest.raises(ValueError, match="must be a non-empty list of household kinds"):
        check_catalogue("mug")
    with pytest.raises(ValueError, match="must be a non-empty list of household kinds"):
        check_catalogue(["mug", 3])
    with pytest.raises(ValueError, match="unknown household kind 'spoon' \\(valid: mug"):
        build_household("spoon", 0)


# --- scenes ---------------------------------------------------------------------------------------

def household_scene(**objects):
    return parse_scene({"objects": {"kind": "household", **objects}})


@pytest.mark.parametrize("objects, match", [
    ({"kind": "household", "catalogue": ["mug", "spoon"]},
     r"objects\.catalogue has unknown household kind\(s\) \['spoon'\] \(valid: mug, bottle, can"),
    ({"kind": "household", "catalogue": []}, r"objects\.catalogue must be a non-empty list of household kinds"),
    ({"kind": "box", "catalogue": ["mug"]}, r"objects\.catalogue is only used with objects\.kind = \"household\""),
    ({"kind": "household", "proportions": "squash"}, r"objects\.proportions must be one of \['keep', 'stretch'\]"),
    ({"kind": "cylinder", "proportions": "keep"}, r"objects\.proportions is only used with objects\.kind = \"mesh\""),
    ({"kind": "household", "path": "a.obj"}, r"objects\.path is only used with objects\.kind = \"mesh\""),
])
def test_bad_household_keys_are_refused_naming_the_key(objects, match):
    with pytest.raises(ValueError, match=match):
        parse_scene({"objects": objects}, source="scene.toml")


def test_draws_follow_the_catalogue_and_are_seeded():
    scene = household_scene(count=12)
    a = sample_objects(scene.objects, np.random.default_rng(5))
    b = sample_objects(scene.objects, np.random.default_rng(5))
    assert [o.item for o in a] == [o.item for o in b] and len({o.item for o in a}) > 3
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.mesh.vertices, y.mesh.vertices)
    only = household_scene(count=6, catalogue=["mug", "can"])
    assert {o.item for o in sample_objects(only.objects, np.random.default_rng(5))} <= {"mug", "can"}
    assert parse_scene(only.to_dict()).objects.catalogue == ("mug", "can")


def test_the_record_rebuilds_the_object():
    scene = household_scene(count=2)
    draws = draw_objects(scene.objects, np.random.default_rng(1))
    for obj in make_objects(scene.objects, draws):
        d = obj.to_dict()
        assert d["kind"] == "household" and d["item"] in CATALOGUE and isinstance(d["item_seed"], int)
        again = make_object(1, "household", (max(d["size"]), 0, 0), None, d["position"], d["rotation"],
                            item=(d["item"], d["item_seed"]))
        np.testing.assert_allclose(again.mesh.vertices, obj.mesh.vertices, atol=1e-12)
        json.dumps(d)


def test_keep_sets_the_longest_half_extent_and_stretch_each_axis():
    natural = build_household("monitor", 3)
    kept = make_object(1, "household", (1.5, 9.0, 9.0), None, (0, 0, 0), (0, 0, 0), item=("monitor", 3))
    half = kept.mesh.extents / 2
    assert half.max() == pytest.approx(1.5)
    np.testing.assert_allclose(half / half.max(), natural.extents / natural.extents.max(), rtol=1e-9)
    np.testing.assert_allclose(kept.size, half, rtol=1e-9)
    stretched = make_object(1, "household", (1.5, 0.5, 0.25), None, (0, 0, 0), (0, 0, 0), proportions="stretch",
                            item=("monitor", 3))
    np.testing.assert_allclose(stretched.mesh.bounds, [[-1.5, -0.5, -0.25], [1.5, 0.5, 0.25]], atol=1e-9)


def test_mesh_files_keep_their_proportions_by_default(tmp_path):
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.apply_translation((3.0, 0.0, 1.0))
    box.export(tmp_path / "slab.stl")
    (tmp_path / "scene.toml").write_text('[objects]\nkind = "mesh"\npath = "slab.stl"\n')
    scene = load_scene(tmp_path / "scene.toml")
    obj = make_objects(scene.objects, [(1, np.array([0.8, 5.0, 5.0]), None, np.zeros(3), np.zeros(3), None)])[0]
    np.testing.assert_allclose(obj.mesh.bounds, [[-0.8, -0.4, -0.2], [0.8, 0.4, 0.2]], atol=1e-9)
    stretch = scene.with_overrides({"objects.proportions": "stretch"})
    obj = make_objects(stretch.objects, [(1, np.array([0.8, 5.0, 5.0]), None, np.zeros(3), np.zeros(3), None)])[0]
    np.testing.assert_allclose(obj.mesh.bounds, [[-0.8, -5, -5], [0.8, 5, 5]], atol=1e-9)


def test_a_mesh_file_that_is_not_watertight_is_refused_when_the_scene_is_read(tmp_path):
    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces[:-1]).export(tmp_path / "open.stl")
    (tmp_path / "scene.toml").write_text('[objects]\nkind = "mesh"\npath = "open.stl"\n')
    refused = r"scene\.toml: objects\.path: mesh file .*open\.stl is not watertight"
    with pytest.raises(ValueError, match=refused) as info:
        load_scene(tmp_path / "scene.toml")
    assert "\n" not in str(info.value)
    (tmp_path / "junk.obj").write_text("this is not a mesh\n")
    (tmp_path / "junk.toml").write_text('[objects]\nkind = "mesh"\npath = "junk.obj"\n')
    with pytest.raises(ValueError, match=r"junk\.toml: objects\.path: mesh file .*junk\.obj holds no triangles"):
        load_scene(tmp_path / "junk.toml")


def test_household_objects_rest_upright_on_the_ground_layout():
    scene = parse_scene({"objects": {"kind": "household", "count": 4, "layout": "ground", "upright": True,
                                     "size": [0.2, 0.4], "position": [-3.0, 3.0]}})
    objects = ground_layout(scene.objects, np.random.default_rng(0))
    assert objects is not None and all(o.item in CATALOGUE for o in objects)
    for obj in objects:
        assert obj.mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
        assert obj.rotation[:2] == (0.0, 0.0)


def test_household_scene_file_reads():
    scene = load_scene(SCENES / "household.toml")
    assert scene.objects.kind == "household" and scene.trajectory.views == 4 and scene.trajectory.height > 0
    assert scene.noise_free and scene.objects.catalogue is None


def test_experiment_records_the_kind_of_each_object(tmp_path):
    from sqsim.runs.experiment import run_experiment

    scene = load_scene(SCENES / "household.toml").with_overrides(
        {"experiment.trials": 2, "objects.catalogue": ["can"]})
    run_experiment(scene, tmp_path, progress=False, figures=False)
    records = [json.loads(line) for line in (tmp_path / "trials.jsonl").read_text().splitlines()]
    assert [r["gt"]["item"] for r in records] == ["can", "can"]
    assert all(r["status"] == "ok" and r["metrics"]["iou"] > 0.8 for r in records)  # a can is nearly a superquadric


def test_make_object_refuses_an_unknown_kind_and_a_household_object_without_its_item():
    with pytest.raises(ValueError, match="unknown object kind 'torus'"):
        make_object(1, "torus", (1.0, 1.0, 1.0), None, (0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="a household object needs its catalogue kind"):
        make_object(1, "household", (1.0, 1.0, 1.0), None, (0, 0, 0), (0, 0, 0))


def solid_at(mesh, point, side=1e-4):
    """Whether a cube of ``side`` metres at ``point`` lies inside ``mesh`` (exact boolean)."""
    probe = trimesh.creation.box(extents=(side,) * 3)
    probe.apply_translation(point)
    inside = trimesh.boolean.intersection([mesh, probe], engine="manifold")
    return bool(not inside.is_empty and inside.volume > 0.5 * side ** 3)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("name", ["mug", "bowl"])
def test_containers_hold_contents_below_the_rim_and_the_handle_stays_below_it(name, seed):
    mesh = build_household(name, seed)
    top = mesh.bounds[1, 2]
    rim = mesh.vertices[mesh.vertices[:, 2] > top - 1e-9]
    axis = np.array([rim[:, 0].mean(), 0.0])  # the rim is a ring around the body's axis
    height = mesh.extents[2]
    assert not solid_at(mesh, (*axis, top - 0.02 * height))  # a recess under the rim...
    assert solid_at(mesh, (*axis, top - 0.5 * height))  # ... over the contents
    if name == "mug":
        assert rim[:, 0].max() < mesh.bounds[1, 0] - 0.01  # the handle reaches further out, not higher
