import json

import pytest

from sqsim.world.scene import parse_scene
from sqsim.runs.sweep import load_sweep, parse_axes, parse_value, point_name, run_sweep

from _helpers import run_command  # noqa: E402


def tiny_scene():
    return parse_scene({"experiment": {"name": "tiny", "seed": 5, "trials": 2, "chains": ["1-2-3D"]},
                        "masks": {"renderer": "polygon"}}, source="<test>")


def test_sweep_writes_curves_and_matches_each_point(tmp_path):
    axes = [("noise.erosion_px", [0, 3])]
    rows = run_sweep(tiny_scene(), axes, tmp_path, progress=False)
    assert [(r["point"], r["chain"]) for r in rows] == [({"noise.erosion_px": 0}, "1-2-3D"),
                                                        ({"noise.erosion_px": 3}, "1-2-3D")]
    for row in rows:
        summary = json.loads((tmp_path / "points" / point_name(row["point"]) / "summary.json").read_text())
        entry = summary["chains"]["1-2-3D"]
        assert row["iou"]["median"] == pytest.approx(entry["iou"]["median"])
        assert row["iou"]["q25"] <= row["iou"]["median"] <= row["iou"]["q75"]
        assert row["success_rate"] == entry["success_rate"]
    assert [json.loads(x) for x in (tmp_path / "sweep.jsonl").read_text().splitlines()] == rows
    assert "noise.erosion_px" in (tmp_path / "sweep.md").read_text()
    assert (tmp_path / "sweep.png").stat().st_size > 10_000
    # The swept value reached each point's experiment.
    for value in (0, 3):
        config = json.loads((tmp_path / "points" / f"noise.erosion_px={value}" / "experiment.json").read_text())
        assert config["scene"]["noise"]["erosion_px"] == value


def test_sweep_file_merges_over_its_base(tmp_path):
    (tmp_path / "base.toml").write_text('[experiment]\nname = "b"\ntrials = 7\n[masks]\nsamples = 50\n')
    (tmp_path / "s.toml").write_text('[sweep]\nbase = "base.toml"\n[[sweep.axis]]\nparam = "noise.dropout"\n'
                                     'values = [0.0, 0.1]\n[experiment]\ntrials = 3\n')
    scene, axes = load_sweep(tmp_path / "s.toml")
    assert axes == [("noise.dropout", [0.0, 0.1])]
    assert scene.experiment.trials == 3 and scene.experiment.name == "b" and scene.masks.samples == 50


def test_shipped_sweep_scenes_are_valid():
    import glob

    files = sorted(glob.glob("scenes/sweep-*.toml"))
    assert len(files) == 14
    for f in files:
        scene, axes = load_sweep(f)
        assert 1 <= len(axes) <= 2 and scene.experiment.trials == 30
        for key, values in axes:
            for v in values:
                scene.with_overrides({key: v})


@pytest.mark.parametrize(
    "content, match",
    [
        ("[sweep]\nbase = 'missing.toml'\n", "scene file not found"),
        ("[sweep]\nbasis = 'x'\n", r"unknown key\(s\) \['basis'\] in \[sweep\]"),
        ("[sweep]\n[[sweep.axis]]\nparam = 'noise.dropout'\n", "needs exactly the keys 'param' and 'values'"),
        ("[sweep]\n[[sweep.axis]]\nparam = 'noise.dropout'\nvalues = []\n", "values must be a non-empty list"),
        ("[sweep\n", "malformed TOML"),
    ],
)
def test_bad_sweep_files(tmp_path, content, match):
    (tmp_path / "s.toml").write_text(content)
    with pytest.raises((ValueError, OSError), match=match):
        load_sweep(tmp_path / "s.toml")


def test_axis_arguments():
    assert parse_value("3") == 3 and parse_value("0.5") == 0.5 and parse_value("contour") == "contour"
    assert parse_axes(["a.b", "c.d"], ["1,2", "x"]) == [("a.b", [1, 2]), ("c.d", ["x"])]
    with pytest.raises(ValueError, match="every --param needs one --values"):
        parse_axes(["a.b"], [])
    with pytest.raises(ValueError, match="swept twice"):
        parse_axes(["a.b", "a.b"], ["1", "2"])


def test_unknown_key_fails_before_running(tmp_path):
    with pytest.raises(ValueError, match="unknown override key 'noise.erosion'"):
        run_sweep(tiny_scene(), [("noise.erosion", [1])], tmp_path, progress=False)
    assert not (tmp_path / "points").exists()


def test_cli_needs_something_to_sweep(tmp_path):
    scene = tmp_path / "plain.toml"
    scene.write_text("[experiment]\ntrials = 1\n")
    out = run_command("sqsim", "sweep", scene, "-o", tmp_path / "o")
    assert out.returncode == 2 and "nothing to sweep" in out.stderr


def test_boolean_scene_keys_can_be_swept():
    assert parse_value("true") is True and parse_value("False") is False
    assert tiny_scene().with_overrides({"masks.cleanup": True}).masks.cleanup is True
    with pytest.raises(ValueError, match="masks.cleanup must be true or false"):
        tiny_scene().with_overrides({"masks.cleanup": "yes"})
