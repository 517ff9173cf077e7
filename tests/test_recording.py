"""Rerun recordings, read back with rerun's own chunk reader (``rerun.chunk.RrdReader``)."""

import json
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

import sqfit  # noqa: E402
import sqfit.geometry.superquadric  # noqa: E402
from sqfit.cli.fit import fit_dataset  # noqa: E402
from sqfit.recording import Recorder  # noqa: E402
from sqsim.runs.generate import generate  # noqa: E402
from sqsim.runs.experiment import run_experiment  # noqa: E402
from sqsim.world.scene import parse_scene  # noqa: E402

SCENE = {"experiment": {"name": "rec", "seed": 2, "trials": 2, "chains": ["1-2-3D"]},
         "camera": {"width": 160, "height": 120, "fx": 100.0, "fy": 75.0, "cx": 80.0, "cy": 60.0},
         "objects": {"count": 2, "size": [0.3, 1.5], "position": [-1.5, 1.5]},
         "masks": {"renderer": "polygon", "min_area_px": 20},
         "noise": {"pose_rotation_deg": 0.5}}


def read(path):
    """entity path -> {"components": set, "timelines": set, "rows": {timeline or "static": count}}."""
    from rerun.chunk import RrdReader

    out = defaultdict(lambda: {"components": set(), "timelines": set(), "rows": defaultdict(int), "batches": []})
    for chunk in RrdReader(str(path)).stream():
        e = out[chunk.entity_path]
        batch = chunk.to_record_batch()
        e["components"] |= {n for n in batch.schema.names if ":" in n}
        e["timelines"] |= set(chunk.timeline_names)
        for t in (chunk.timeline_names or ["static"]):
            e["rows"][t] += chunk.num_rows
        e["batches"].append(batch)
    return out


def column(entity, name):
    values = []
    for batch in entity["batches"]:
        if name in batch.schema.names:
            values += batch.column(name).to_pylist()
    return values


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("rec")
    scene = parse_scene(SCENE, source="<test>")
    generate(scene, root / "data", progress=False, rerun=root / "data.rrd")
    return root


def test_generate_records_cameras_masks_and_ground_truth(dataset):
    got = read(dataset / "data.rrd")
    for t in ("000000", "000001"):
        for v in range(3):
            cam = got[f"/trials/{t}/cameras/view_{v:02d}"]
            assert {"Pinhole:image_from_camera", "Pinhole:resolution", "Transform3D:mat3x3",
                    "Transform3D:translation"} <= cam["components"]
            assert cam["rows"] == {"static": 1}
            assert "SegmentationImage:buffer" in got[f"/trials/{t}/cameras/view_{v:02d}/mask"]["components"]
            assert "Transform3D:translation" in got[f"/trials/{t}/true_cameras/view_{v:02d}"]["components"]
        for k in (1, 2):
            gt = got[f"/trials/{t}/ground_truth/object_{k}"]
            assert {"Mesh3D:vertex_positions", "Mesh3D:triangle_indices"} <= gt["components"]
    # the camera's image is the instance mask, pixel for pixel
    from sqfit.views.dataset import load_trial

    trial = load_trial(dataset / "data" / "trials" / "000001")
    buffer = column(got["/trials/000001/cameras/view_02/mask"], "SegmentationImage:buffer")[0][0]
    np.testing.assert_array_equal(np.frombuffer(bytes(buffer), np.uint16).reshape(120, 160), trial.images[2])
    K = np.asarray(column(got["/trials/000001/cameras/view_02"], "Pinhole:image_from_camera")[0][0])
    assert np.allclose(K.reshape(3, 3).T, [[100, 0, 80], [0, 75, 60], [0, 0, 1]])
    assert not any("/fits/" in e for e in got)


def test_fit_records_every_stage_on_the_stage_timeline(dataset, tmp_path):
    n, _ = fit_dataset(dataset / "data", tmp_path / "fits.jsonl", "1-2-3D", progress=False,
                       rerun=tmp_path / "fits.rrd")
    assert n == 4
    stages = {(r["trial"], r["object_id"]): r["stages"]
              for r in map(json.loads, (tmp_path / "fits.jsonl").read_text().splitlines())}
    got = read(tmp_path / "fits.rrd")
    fits = sorted(e for e in got if e.startswith("/trials/") and "/fits/" in e and "/cameras/" not in e)
    assert fits == [f"/trials/{t}/fits/1-2-3D/object_{k}" for t in ("000000", "000001") for k in (1, 2)]
    for e in fits:
        assert got[e]["timelines"] >= {"stage"} and got[e]["rows"]["stage"] == 3  # one row per stage
        assert column(got[e], "stage") == [0, 1, 2]
        assert [x[0] for x in column(got[e], "stage_name")] == ["1", "2", "3D"]
        t, k = e.split("/")[2], int(e.rsplit("_", 1)[1])
        assert [x[0] for x in column(got[e], "stage_status")] == [st["status"] for st in stages[t, k]]
        # the mesh after the last stage is the fitted superquadric's surface
        sq = sqfit.Superquadric.from_vector(np.asarray(stages[t, k][-1]["superquadric"]))
        last = np.asarray(column(got[e], "Mesh3D:vertex_positions")[-1], dtype=np.float64)
        assert len(last) == 6 * 24**2 + 2 and np.allclose(sqfit.geometry.superquadric.implicit(sq, last), 1.0, atol=1e-2)
        assert "Mesh3D:vertex_positions" in got[e]["components"]
    from rerun.chunk import RrdReader  # the default blueprint: one 3D view per trial

    reader = RrdReader(str(tmp_path / "fits.rrd"))
    views = {c.entity_path for c in reader.stream(store=reader.blueprints()[0]) if c.entity_path.count("/") == 2
             and c.entity_path.startswith("/view/")}
    assert len(views) == 2
    outline = got["/trials/000001/cameras/view_01/fits/1-2-3D/object_2"]
    assert "LineStrips2D:strips" in outline["components"] and outline["rows"]["stage"] == 3
    assert "SegmentationImage:buffer" in got["/trials/000000/cameras/view_00/mask"]["components"]


def test_experiment_records_each_chain(tmp_path):
    scene = parse_scene({**SCENE, "experiment": {**SCENE["experiment"], "chains": ["1-2-3D", "1-3E"]}}, "<t>")
    run_experiment(scene, tmp_path / "run", progress=False, figures=False, rerun=tmp_path / "run.rrd")
    got = read(tmp_path / "run.rrd")
    for t in ("000000", "000001"):
        for chain, n_stages in (("1-2-3D", 3), ("1-3E", 2)):
            for k in (1, 2):
                assert got[f"/trials/{t}/fits/{chain}/object_{k}"]["rows"]["stage"] == n_stages
        assert "SegmentationImage:buffer" in got[f"/trials/{t}/cameras/view_00/mask"]["components"]
        assert "Mesh3D:vertex_positions" in got[f"/trials/{t}/ground_truth/object_1"]["components"]
    # re-running into the finished directory fits nothing and records the same entities
    run_experiment(scene, tmp_path / "run", progress=False, figures=False, rerun=tmp_path / "again.rrd")
    again = read(tmp_path / "again.rrd")
    assert {e for e in again if e.startswith("/trials")} == {e for e in got if e.startswith("/trials")}


def test_recording_errors(tmp_path):
    with pytest.raises(ValueError, match="must end in .rrd, got '.*out.txt'"):
        Recorder(tmp_path / "out.txt")
    scene = parse_scene(SCENE, source="<test>")
    with pytest.raises(ValueError, match="must end in .rrd"):
        generate(scene, tmp_path / "d", progress=False, rerun=tmp_path / "x.rr")
    assert not (tmp_path / "d").exists()  # refused before any work
    with Recorder(tmp_path / "r.rrd") as rec:
        with pytest.raises(ValueError, match=r"images must have shape \(v, h, w\) with v = 1"):
            rec.log_trial("t", [sqfit_camera()], np.zeros((2, 4, 4)))


def test_only_the_first_trials_are_recorded_when_limited(dataset, tmp_path, capsys):
    scene = parse_scene(SCENE, source="<test>")
    generate(scene, dataset / "data", progress=False, rerun=tmp_path / "one.rrd", rerun_trials=1)
    err = capsys.readouterr().err
    assert "recorded 1 trial(s)" in err and "1 more not recorded" in err
    got = read(tmp_path / "one.rrd")
    assert {e.split("/")[2] for e in got if e.startswith("/trials/")} == {"000000"}
    fit_dataset(dataset / "data", tmp_path / "f.jsonl", "1-2", progress=False, rerun=tmp_path / "f.rrd", rerun_trials=1)
    got = read(tmp_path / "f.rrd")
    assert {e.split("/")[2] for e in got if e.startswith("/trials/")} == {"000000"}
    assert "/trials/000000/fits/1-2/object_2" in got
    with pytest.raises(ValueError, match=r"--rerun-trials\) must be an integer >= 1, got 0"):
        generate(scene, tmp_path / "x", progress=False, rerun=tmp_path / "x.rrd", rerun_trials=0)
    assert not (tmp_path / "x").exists()


def test_cli_fit_rerun(dataset, tmp_path):
    out = subprocess.run([sys.executable, "-m", "sqfit.cli", "fit", str(dataset / "data"), "-o",
                          str(tmp_path / "f.jsonl"), "--chain", "1-2", "--rerun", str(tmp_path / "f.rrd"),
                          "--no-progress"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert read(tmp_path / "f.rrd")["/trials/000000/fits/1-2/object_1"]["rows"]["stage"] == 2
    bad = subprocess.run([sys.executable, "-m", "sqfit.cli", "fit", str(dataset / "data"), "-o",
                          str(tmp_path / "g.jsonl"), "--rerun", str(tmp_path / "g.txt"), "--no-progress"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "must end in .rrd" in bad.stderr


def sqfit_camera():
    import sqfit

    return sqfit.Camera(sqfit.Intrinsics(4, 4, 2.0, 2.0, 2.0, 2.0), np.eye(4))


def test_mesh_kinds_are_recorded_as_oriented_boxes(tmp_path):
    scene = parse_scene({**SCENE, "objects": {**SCENE["objects"], "kind": "box", "count": 1},
                         "experiment": {**SCENE["experiment"], "trials": 1}}, source="<test>")
    generate(scene, tmp_path / "d", progress=False, rerun=tmp_path / "d.rrd")
    gt = read(tmp_path / "d.rrd")["/trials/000000/ground_truth/object_1"]
    from sqfit.views.dataset import load_trial

    obj = load_trial(tmp_path / "d" / "trials" / "000000").objects[0]
    assert np.allclose(column(gt, "Boxes3D:half_sizes")[0][0], obj["size"])
    assert np.allclose(column(gt, "Transform3D:translation")[0][0], obj["position"])
