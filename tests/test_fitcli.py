import json
import subprocess
import sys

import numpy as np
import pytest

from sqfit.cli import main
from sqfit.io import write_mask_png
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
