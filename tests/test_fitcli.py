import json
import subprocess
import sys

import numpy as np
import pytest

from sqfit.cli import main
from sqfit.views.dataset import write_mask_png
from sqfit.testing import paper_trial


def write_trial(root, name, trial, with_gt=True, extra_empty_object=False):
    d = root / "trials" / name
    (d / "masks").mkdir(parents=True)
    views = []
    for k, (cam, mask) in enumerate(zip(trial.cameras, trial.masks)):
        image = mask.astype(np.uint16) * 3  # instance id 3
        write_mask_png(d / "masks" / f"view_{k:02d}.png", image)
        views.append(cam.to_dict())
    (d / "cameras.json").write_text(json.dumps({"views": views}))
    if with_gt:
        objects = [{"id": 3, "kind": "superquadric", "params": trial.gt.to_vector().tolist()}]
        if extra_empty_object:
            objects.append({"id": 9, "kind": "superquadric"})
        (d / "gt.json").write_text(json.dumps({"trial": 0, "objects": objects}))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    write_trial(root, "000000", paper_trial(2), extra_empty_object=True)
    write_trial(root, "000001", paper_trial(4), with_gt=False)  # a user's data: ids from the masks
    return root


def test_fit_command_writes_one_record_per_object(dataset, tmp_path, capsys):
    out = tmp_path / "fits.jsonl"
    assert main(["fit", str(dataset), "-o", str(out), "--chain", "1-2-3D", "--no-progress", "--seed", "1"]) == 0
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert [(r["trial"], r["object_id"]) for r in records] == [("000000", 3), ("000000", 9), ("000001", 3)]
    ok = [r for r in records if r["object_id"] == 3]
    for r in ok:
        assert r["status"] == "ok" and r["chain"] == "1-2-3D" and len(r["params"]) == 11
        assert [s["name"] for s in r["stages"]] == ["1", "2", "3D"]
        assert all(len(s["superquadric"]) == 11 and s["seconds"] > 0 for s in r["stages"])
    # Object 9 is listed in gt.json but absent from every mask: recorded, not fatal.
    assert records[1]["status"] == "too_few_views"
    assert "wrote 3 fit record(s)" in capsys.readouterr().out
    # Seeded: the same command gives the same parameters.
    out2 = tmp_path / "again.jsonl"
    main(["fit", str(dataset), "-o", str(out2), "--chain", "1-2-3D", "--no-progress", "--seed", "1"])
    assert [json.loads(x)["params"] for x in out2.read_text().splitlines()] == [r["params"] for r in records]


def test_fit_command_errors_are_one_line(tmp_path):
    res = subprocess.run([sys.executable, "-m", "sqfit.cli", "fit", str(tmp_path / "missing"), "-o",
                          str(tmp_path / "f.jsonl")], capture_output=True, text=True)
    assert res.returncode == 2 and "dataset directory not found" in res.stderr
    res = subprocess.run([sys.executable, "-m", "sqfit.cli", "fit", str(tmp_path), "-o", str(tmp_path / "f.jsonl"),
                          "--chain", "1-9"], capture_output=True, text=True)
    assert res.returncode == 2 and "unknown stage" in res.stderr


def test_broken_trial_is_recorded(dataset, tmp_path):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(dataset, root)
    (root / "trials" / "000001" / "cameras.json").write_text("{not json")
    out = tmp_path / "fits.jsonl"
    assert main(["fit", str(root), "-o", str(out), "--chain", "1-2", "--no-progress"]) == 0
    records = [json.loads(x) for x in out.read_text().splitlines()]
    assert records[-1]["trial"] == "000001" and records[-1]["status"] == "error"
    assert "not valid JSON" in records[-1]["message"]


def test_view_with_empty_mask_is_named_in_the_record(tmp_path):
    trial = paper_trial(3)
    root = tmp_path / "ds"
    write_trial(root, "000000", trial)
    path = root / "trials" / "000000" / "masks" / "view_01.png"
    write_mask_png(path, np.zeros_like(trial.masks[1], dtype=np.uint16))  # object 3 absent from view 1
    out = tmp_path / "fits.jsonl"
    assert main(["fit", str(root), "-o", str(out), "--chain", "1-2", "--no-progress"]) == 0
    (record,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert record["status"] == "ok" and record["views"] == [0, 2]
    assert record["dropped_views"] == [{"view": 1, "reason": "the object's mask is empty in this view"}]
    assert record["warnings"][0] == "view 1 dropped: the object's mask is empty in this view"


def test_poor_fits_are_counted_on_screen(tmp_path, capsys):
    # Stages 1-2 on paper_trial(1) give an ellipsoid whose silhouettes barely match the masks.
    root = tmp_path / "ds"
    write_trial(root, "000000", paper_trial(1))
    out = tmp_path / "fits.jsonl"
    assert main(["fit", str(root), "-o", str(out), "--chain", "1-2", "--no-progress"]) == 0
    (record,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert record["status"] == "ok" and record["warnings"][-1].startswith("poor fit: ")
    assert "0 not ok; 1 flagged as poor fits (R-IOU-M < 0.5: see their warnings)" in capsys.readouterr().out


def test_rerun_with_coco_is_refused(tmp_path):
    res = subprocess.run([sys.executable, "-m", "sqfit.cli", "fit", "--coco", str(tmp_path / "a.json"), "--poses",
                          str(tmp_path), "-o", str(tmp_path / "f.jsonl"), "--rerun", str(tmp_path / "r.rrd")],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "--rerun records native datasets only" in res.stderr


def test_observe_views_names_views_and_keeps_samples():
    from sqfit import Observation
    from sqfit.views.dataset import observations_from_images, observe_views
    from sqfit.fitting.pipeline import FitResult

    trial = paper_trial(3)
    images = np.stack([m.astype(np.uint16) * 3 for m in trial.masks])
    images[0] = 0
    full = np.full_like(images[2], 3)  # covers the whole image: unusable, dropped with the reason
    views = observe_views(trial.cameras, [images[0], images[1], full], 3, 20, rng=5, names=["a", "b", "c"])
    assert views.views == [1] and [k for k, _ in views.dropped] == [0, 2]
    assert views.warnings[0] == "view 0 (a) dropped: the object's mask is empty in this view"
    assert "view 2 (c) dropped: mask covers the whole image" in views.warnings[1]
    same = observe_views(trial.cameras, images, 3, 20, rng=5)
    ref = observations_from_images(trial.cameras, images, 3, 20, rng=5)
    assert all(isinstance(o, Observation) for o in same.observations)
    np.testing.assert_array_equal(np.stack([o.samples for o in same.observations]),
                                  np.stack([o.samples for o in ref]))
    # Fit warnings number observations; the record names the view they came from.
    record = same.record(FitResult(None, warnings=["view 0: mask touches the image border (truncated silhouette)"]))
    assert record["warnings"] == ["view 0 dropped: the object's mask is empty in this view",
                                  "view 1: mask touches the image border (truncated silhouette)"]
    with pytest.raises(ValueError, match="one image per camera"):
        observe_views(trial.cameras, images[:2], 3)
    with pytest.raises(ValueError, match="one name per camera"):
        observe_views(trial.cameras, images, 3, names=["a"])


@pytest.mark.parametrize("where", ["import", "run"])
def test_ctrl_c_is_one_line_and_status_130_also_while_importing(where, monkeypatch, capsys):
    # Ctrl-C while a command's modules are still being imported (the first second of a run) gave a
    # KeyboardInterrupt traceback; now, as during the run, one line and status 130.
    import importlib
    import types

    cli = importlib.import_module("sqfit.cli.dispatch")  # the module (sqfit.cli re-exports the function)

    def run(args):
        raise KeyboardInterrupt

    module = types.SimpleNamespace(add_arguments=lambda parser: None, run=run)

    def import_module(name):
        if where == "import":
            raise KeyboardInterrupt
        return module

    monkeypatch.setattr(cli.importlib, "import_module", import_module)
    assert cli.dispatch(["go"], {"go": ("somewhere.go", "a command")}, "tool", "a tool") == 130
    assert capsys.readouterr().err.strip() == "tool go: interrupted"
