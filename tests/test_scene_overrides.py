"""``--set SECTION.KEY=VALUE``: scene keys replaced on the command line (sqsim.world.scene.scene_overrides)."""

import json
from pathlib import Path

import pytest

from sqsim.cli import main as sqsim_main
from sqsim.world.scene import load_scene, scene_overrides

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenes" / "paper.toml"


@pytest.mark.parametrize("item, key, value", [
    ("noise.dropout=0.1", "noise.dropout", 0.1),
    ("trajectory.views=4", "trajectory.views", 4),
    ("experiment.limit=false", "experiment.limit", False),
    ('objects.kind="household"', "objects.kind", "household"),
    ("objects.kind=household", "objects.kind", "household"),  # a bare word is a string
    ('objects.catalogue=["mug", "can"]', "objects.catalogue", ["mug", "can"]),
    ("objects.catalogue=[mug, can]", "objects.catalogue", ["mug", "can"]),  # so are bare words in a list
    ("objects.size=[0.5, 2.5]", "objects.size", [0.5, 2.5]),
    ("experiment.chains=[1-2-3D, default]", "experiment.chains", ["1-2-3D", "default"]),  # chains are words too
    ("objects.path=meshes/duck.obj", "objects.path", "meshes/duck.obj"),  # and paths without spaces
    ("objects.path=/data/scans/mug_col.obj", "objects.path", "/data/scans/mug_col.obj"),
    (" noise.dropout = 0.2 ", "noise.dropout", 0.2),
])
def test_values_are_toml_or_bare_words(item, key, value):
    assert scene_overrides([item]) == {key: value}


def test_a_key_set_twice_keeps_the_last_value():
    assert scene_overrides(["noise.dropout=0.1", "trajectory.views=5", "noise.dropout=0.3"]) == \
        {"noise.dropout": 0.3, "trajectory.views": 5}
    assert scene_overrides([]) == {} and scene_overrides(None) == {}


@pytest.mark.parametrize("item, match", [
    ("noise.dropout", "expected SECTION.KEY=VALUE"),
    ("noise.dropout=", "expected SECTION.KEY=VALUE"),
    ("noize.dropout=0.1", "unknown section 'noize'"),
    ("noise=0.1", "expected SECTION.KEY=VALUE"),
    ("noise.blur=1", "unknown key 'blur' in \\[noise\\]"),
    ('objects.catalogue=[mug, "can"]', "neither TOML nor a bare word"),
    ("objects.kind=house hold", "neither TOML nor a bare word"),
])
def test_bad_items_are_named(item, match):
    with pytest.raises(ValueError, match=match) as info:
        scene_overrides([item])
    assert repr(item) in str(info.value)


def test_overrides_apply_before_validation():
    # paper.toml has superquadrics: a catalogue alone is refused, kind and catalogue together are a scene
    with pytest.raises(ValueError, match="objects.catalogue is only used with objects.kind"):
        load_scene(PAPER, {"objects.catalogue": ["mug"]})
    scene = load_scene(PAPER, scene_overrides(["objects.kind=household", "objects.catalogue=[mug]",
                                               "trajectory.views=4"]))
    assert scene.objects.kind == "household" and tuple(scene.objects.catalogue) == ("mug",)
    assert scene.trajectory.views == 4 and len(scene.cameras()) == 4
    assert load_scene(PAPER).trajectory.views == 3  # the file is not touched


def test_a_bad_value_names_the_file_the_key_and_the_override():
    with pytest.raises(ValueError) as info:
        load_scene(PAPER, {"noise.dropout": 2})
    message = str(info.value)
    assert "paper.toml" in message and "noise.dropout must be < 1" in message
    assert "with noise.dropout=2 set over the file's keys" in message


def test_experiment_command_records_the_scene_as_set(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["experiment", str(PAPER), "--set", "trajectory.views=4", "--set", "experiment.limit=false",
            "--trials", "1", "--chains", "1", "-o", str(out), "--no-progress"]
    assert sqsim_main(args) == 0
    config = json.loads((out / "experiment.json").read_text())
    assert config["scene"]["trajectory"]["views"] == 4
    record = json.loads((out / "trials.jsonl").read_text().splitlines()[0])
    assert len(record["cameras"]) == 4
    capsys.readouterr()
    # the same directory with another value is another experiment: refused, nothing appended
    assert sqsim_main(args[:3] + ["trajectory.views=5"] + args[4:]) == 2
    assert "holds a different experiment" in capsys.readouterr().err
    assert len((out / "trials.jsonl").read_text().splitlines()) == 1


def test_bad_set_is_one_line_error(tmp_path, capsys):
    code = sqsim_main(["experiment", str(PAPER), "--set", "noise.blur=1", "-o", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "unknown key 'blur' in [noise]" in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("command", ["experiment", "generate", "slam", "sequence", "sweep"])
def test_every_command_that_reads_a_scene_takes_set(command, capsys):
    with pytest.raises(SystemExit):
        sqsim_main([command, "--help"])
    assert "--set SECTION.KEY=VALUE" in capsys.readouterr().out


def test_sweep_points_start_from_the_scene_as_set(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", str(PAPER), "--set", "trajectory.views=4", "--set", "experiment.limit=false",
            "--param", "noise.dropout", "--values", "0,0.1", "--trials", "1", "--chains", "1", "-o", str(out),
            "--no-progress"]
    assert sqsim_main(args) == 0
    configs = [json.loads(p.read_text()) for p in sorted(out.glob("points/*/experiment.json"))]
    assert len(configs) == 2 and {c["scene"]["noise"]["dropout"] for c in configs} == {0.0, 0.1}
    assert all(c["scene"]["trajectory"]["views"] == 4 for c in configs)


def test_a_relative_mesh_path_is_taken_from_the_current_directory(tmp_path, monkeypatch):
    import trimesh

    (tmp_path / "meshes").mkdir()
    trimesh.creation.box(extents=(1.0, 2.0, 3.0)).export(tmp_path / "meshes" / "box.obj")
    (tmp_path / "scenes").mkdir()
    in_file = tmp_path / "scenes" / "mesh.toml"
    in_file.write_text('[objects]\nkind = "mesh"\npath = "meshes/box.obj"\n')
    monkeypatch.chdir(tmp_path)
    scene = load_scene(PAPER, scene_overrides(["objects.kind=mesh", "objects.path=meshes/box.obj"]))
    assert scene.objects.path == str(tmp_path / "meshes" / "box.obj")
    # in a scene file the same path is relative to the file's directory: scenes/meshes/box.obj, not there
    with pytest.raises(ValueError, match="mesh file not found"):
        load_scene(in_file)
    # sqsim sweep's --set reads it the same way as every other command's
    from sqsim.runs.sweep import load_sweep

    swept, _ = load_sweep(in_file, scene_overrides(["objects.path=meshes/box.obj"]))
    assert swept.objects.path == str(tmp_path / "meshes" / "box.obj")
