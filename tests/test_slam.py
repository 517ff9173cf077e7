"""``sqsim slam``: files, evo-readable trajectories, consistent summary, resume, bad input."""

import json

import numpy as np
import pytest

pytest.importorskip("gtsam")
pytest.importorskip("evo")

from sqfit.metrics import iou_3d  # noqa: E402
from sqfit.views.sequence import Sequence  # noqa: E402
from sqfit.geometry.superquadric import Superquadric  # noqa: E402
from sqsim.cli import main  # noqa: E402
from sqfit.graph import GraphOptions  # noqa: E402
from sqsim.world.scene import parse_scene  # noqa: E402
from sqsim.imaging.sequence import simulate_sequence  # noqa: E402
from sqsim.runs.slam import evaluate_sequence, run_slam, scene_graph_options, trajectory_errors  # noqa: E402

TINY = {
    "experiment": {"name": "tiny", "seed": 0, "trials": 1},
    "camera": {"width": 160, "height": 120, "fx": 100.0, "fy": 75.0, "cx": 80.0, "cy": 60.0},
    "trajectory": {"kind": "orbit", "frames": 8, "radius": 5.0, "height": 1.6, "look_at": [0.0, 0.0, 0.3],
                   "arc_deg": 60.0},
    "objects": {"count": 2, "layout": "ground", "upright": True, "size": [0.3, 0.5], "position": [-1.0, 1.0],
                "shape": [0.5, 1.5]},
    "masks": {"renderer": "polygon", "min_area_px": 20},
    "noise": {"odometry_rotation_deg": 0.5, "odometry_translation_m": 0.02},
}
METHODS = ["odometry", "quadric"]


def tiny_scene(tmp_path):
    path = tmp_path / "tiny.toml"
    lines = []
    for section, values in TINY.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in values.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("slam")
    out = tmp / "out"
    status = main(["slam", str(tiny_scene(tmp)), "-o", str(out), "--sequences", "2", "--methods", ",".join(METHODS),
                   "--no-progress"])
    assert status == 0
    return out


def test_slam_writes_every_file(run_dir):
    for name in ("slam.json", "summary.json", "table.md"):
        assert (run_dir / name).is_file()
    installs = json.loads((run_dir / "slam.json").read_text())["installs"]
    assert json.loads((run_dir / "summary.json").read_text())["installs"] == installs and len(installs) == 1
    assert installs[0]["numpy"] is not None and installs[0]["gtsam"] is not None
    for k in range(2):
        d = run_dir / "sequences" / f"{k:06d}"
        for name in ("true.tum", "odometry.tum", "quadric.tum", "objects.json", "record.json", "topdown.png"):
            assert (d / name).is_file(), name
    table = (run_dir / "table.md").read_text()
    assert "| odometry |" in table and "quadric (QuadricSLAM, boxes)" in table


def test_slam_tum_files_read_by_evo_and_match_the_summary(run_dir):
    from evo.core import metrics
    from evo.tools import file_interface

    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["sequences"] == [0, 1] and list(summary["methods"]) == METHODS
    scene = parse_scene(TINY)
    for k in range(2):
        d = run_dir / "sequences" / f"{k:06d}"
        seq = simulate_sequence(scene, seed=0, index=k)
        true = file_interface.read_tum_trajectory_file(d / "true.tum")
        np.testing.assert_allclose(true.positions_xyz, seq.true_poses[:, :3, 3], atol=1e-12)
        np.testing.assert_allclose(true.timestamps, seq.timestamps)
        for m in METHODS:
            est = file_interface.read_tum_trajectory_file(d / f"{m}.tum")
            ape = metrics.APE(metrics.PoseRelation.translation_part)
            ape.process_data((true, est))
            ate = ape.get_statistic(metrics.StatisticsType.rmse)
            assert summary["methods"][m]["ate_m"]["per_sequence"][k] == pytest.approx(ate, rel=1e-9)
        odometry = file_interface.read_tum_trajectory_file(d / "odometry.tum")
        np.testing.assert_allclose(odometry.positions_xyz, seq.odometry_poses[:, :3, 3], atol=1e-12)


def test_slam_summary_is_consistent_with_the_records(run_dir):
    summary = json.loads((run_dir / "summary.json").read_text())
    odo = summary["methods"]["odometry"]["ate_m"]["per_sequence"]
    quad = summary["methods"]["quadric"]
    for k in range(2):
        d = run_dir / "sequences" / f"{k:06d}"
        record = json.loads((d / "record.json").read_text())
        objects = json.loads((d / "objects.json").read_text())
        row = record["methods"]["quadric"]
        assert quad["ate_change_vs_odometry"]["per_sequence"][k] == pytest.approx(row["ate_m"] / odo[k] - 1)
        assert quad["iou_median_per_sequence"][k] == pytest.approx(np.median(list(row["iou"].values())))
        for oid, params in objects["methods"]["quadric"].items():
            true = Superquadric.from_vector(objects["true"][oid]["params"])
            assert row["iou"][oid] == pytest.approx(iou_3d(Superquadric.from_vector(params), true), abs=1e-9)
        assert 0.0 <= row["iou_median"] <= 1.0 and row["cpu_seconds"] >= 0.0
        assert record["methods"]["quadric"]["odometry_chi2"] is None  # graph methods only (test_graph.py)
        assert objects["methods"]["odometry"] == {} and record["methods"]["odometry"]["iou"] == {}
    ious = [v for k in range(2) for v in json.loads((run_dir / "sequences" / f"{k:06d}" / "record.json")
                                                   .read_text())["methods"]["quadric"]["iou"].values()]
    assert quad["iou"]["median"] == pytest.approx(np.median(ious)) and quad["iou"]["objects"] == len(ious)


def test_slam_summary_counts_the_runs_off_the_odometry(run_dir):
    from sqsim.reports.slam import summarize, table_markdown

    records = [json.loads((run_dir / "sequences" / f"{k:06d}" / "record.json").read_text()) for k in range(2)]
    options = json.loads((run_dir / "summary.json").read_text())["options"]
    assert all(summarize(records, METHODS, "tiny", 0, options)["methods"][m]["off_odometry"] == 0 for m in METHODS)
    # a graph method's record carries its estimate's chi-square (None elsewhere); one above the limit counts
    limit = GraphOptions.coerce(options).batch_odometry_chi2
    records[0]["methods"]["quadric"]["odometry_chi2"] = 0.5 * limit
    records[1]["methods"]["quadric"]["odometry_chi2"] = 2.0 * limit
    summary = summarize(records, METHODS, "tiny", 0, options)
    assert summary["methods"]["quadric"]["off_odometry"] == 1 and summary["methods"]["odometry"]["off_odometry"] == 0
    assert "failed / off the odometry / missing objects" in table_markdown(summary)


def test_slam_resumes_without_recomputing(run_dir, tmp_path):
    record = run_dir / "sequences" / "000000" / "record.json"
    before = record.stat().st_mtime_ns
    summary = run_slam(parse_scene(TINY), run_dir, sequences=2, methods=METHODS, progress=False)
    assert record.stat().st_mtime_ns == before and summary["sequences"] == [0, 1]
    with pytest.raises(ValueError, match="holds a different slam run"):
        run_slam(parse_scene(TINY), run_dir, sequences=2, methods=["odometry"], progress=False)


def test_trajectory_errors_without_alignment():
    true = np.stack([np.eye(4)] * 5)
    true[:, 0, 3] = np.cos(np.arange(5.0))
    true[:, 1, 3] = np.sin(np.arange(5.0))
    shifted = true.copy()
    shifted[:, 2, 3] += 0.1  # a constant offset: ATE 0.1 unaligned, 0 after SE(3) alignment, RPE 0
    e = trajectory_errors(true, shifted, np.arange(5.0))
    assert e["ate_m"] == pytest.approx(0.1) and e["ate_se3_m"] == pytest.approx(0.0, abs=1e-9)
    assert e["rpe_m"] == pytest.approx(0.0, abs=1e-12) and e["rpe_deg"] == pytest.approx(0.0, abs=1e-6)
    line = np.stack([np.eye(4)] * 5)
    line[:, 0, 3] = np.arange(5.0)
    assert trajectory_errors(line, line, np.arange(5.0))["ate_se3_m"] is None  # collinear: no unique alignment


# --- bad input ---------------------------------------------------------------------------------------

def test_slam_refuses_a_non_sequence_scene(tmp_path):
    with pytest.raises(ValueError, match="is not a sequence scene"):
        run_slam(parse_scene({"experiment": {"trials": 1}}), tmp_path / "o", progress=False)
    assert main(["slam", "scenes/paper.toml", "-o", str(tmp_path / "p"), "--no-progress"]) == 2


@pytest.mark.parametrize("kwargs, match", [
    ({"methods": ["odometry", "slam"]}, "unknown or empty"),
    ({"options": {"n_kontour": 3}}, "unknown graph option"),
    ({"options": {"n_contour": 1}}, "n_contour must be an integer"),
    ({"sequences": 0}, "--sequences must be >= 1"),
    ({"workers": 0}, "--workers must be >= 1"),
])
def test_slam_bad_arguments(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        run_slam(parse_scene(TINY), tmp_path / "o", progress=False, **kwargs)


def test_slam_records_the_graph_options(run_dir, tmp_path):
    assert json.loads((run_dir / "slam.json").read_text())["options"] == {}  # the graph's own defaults
    out = tmp_path / "o"
    assert main(["slam", str(tiny_scene(tmp_path)), "-o", str(out), "--sequences", "1", "--methods", "odometry",
                 "--scene-odometry-noise", "--floor", "--options", '{"floor_sigma_m": 0.02}', "--no-progress",
                 "--no-figures"]) == 0
    assert json.loads((out / "slam.json").read_text())["options"] == {
        "odometry_sigma_m": 0.02, "odometry_sigma_deg": 0.5, "floor_z": 0.0, "floor_sigma_m": 0.02}


def test_scene_graph_options_floor_and_overrides():
    scene = parse_scene(TINY)
    assert scene_graph_options(scene) == {}
    assert scene_graph_options(scene, {"odometry_sigma_m": 0.01}, floor=True, odometry_noise=True) == {
        "odometry_sigma_m": 0.01, "odometry_sigma_deg": 0.5, "floor_z": 0.0}
    quiet = parse_scene({**TINY, "noise": {}})
    assert scene_graph_options(quiet, odometry_noise=True) == {}  # no noise declared: the graph's own defaults
    free = parse_scene({**TINY, "objects": {**TINY["objects"], "layout": "free", "upright": False}})
    with pytest.raises(ValueError, match="--floor needs objects.layout"):
        scene_graph_options(free, floor=True)


def test_slam_cli_bad_options(tmp_path, capsys):
    assert main(["slam", str(tiny_scene(tmp_path)), "-o", str(tmp_path / "o"), "--options", "{bad"]) == 2
    assert "--options is not valid JSON" in capsys.readouterr().err


def _copy(seq, **fields):
    values = {k: getattr(seq, k) for k in ("timestamps", "intrinsics", "true_poses", "odometry_poses", "images",
                                           "objects", "object_ids", "observed", "object_kinds")}
    values.update(fields)
    return Sequence(**values)


def test_slam_frame_without_a_pose_is_an_error():
    seq = simulate_sequence(parse_scene(TINY), seed=0, index=0)
    odometry = np.array(seq.odometry_poses)
    odometry[3] = np.nan
    with pytest.raises(ValueError, match="frame 3 has no pose"):
        evaluate_sequence(_copy(seq, odometry_poses=odometry), METHODS, min_area_px=20)
    with pytest.raises(ValueError, match="has no true poses"):
        evaluate_sequence(_copy(seq, true_poses=None), METHODS)


def test_slam_object_seen_once_is_skipped_with_a_warning():
    seq = simulate_sequence(parse_scene(TINY), seed=0, index=0)
    images = np.array(seq.images)
    frames = np.flatnonzero(seq.observed[:, 1])
    for k in frames[1:]:
        images[k][images[k] == 2] = 0  # object 2 left in its first frame only
    record = evaluate_sequence(_copy(seq, images=images), ["odometry", "fixed"], min_area_px=20, rng=0)
    assert any(w.startswith("fixed: object 2: skipped, seen in 1 frame only") for w in record["warnings"])
    fixed = record["methods"]["fixed"]
    assert "2" in fixed["skipped"] and fixed["missing"] == [2] and fixed["iou"]["2"] == 0.0
    assert "1" in fixed["objects"]


def test_slam_over_worker_processes_matches_in_process(run_dir, tmp_path):
    out = tmp_path / "parallel"
    summary = run_slam(parse_scene(TINY), out, sequences=2, methods=METHODS, workers=2, progress=False,
                       figures=False)
    serial = json.loads((run_dir / "summary.json").read_text())
    for m in METHODS:
        assert summary["methods"][m]["ate_m"]["per_sequence"] == serial["methods"][m]["ate_m"]["per_sequence"]
        assert summary["methods"][m]["iou_median_per_sequence"] == serial["methods"][m]["iou_median_per_sequence"]
    assert not (out / "sequences" / "000000" / "topdown.png").exists()


@pytest.mark.slow
def test_slam_acceptance_on_the_sequence_scene(tmp_path):
    """Issue 14's acceptance on one sequence of scenes/sequence.toml (the README gives five)."""
    from sqsim.world.scene import load_scene

    summary = run_slam(load_scene("scenes/sequence.toml"), tmp_path, sequences=1, progress=False, figures=False)
    m = summary["methods"]
    assert m["graph"]["ate_m"]["median"] <= 0.5 * m["odometry"]["ate_m"]["median"]
    assert m["graph"]["iou"]["median"] > m["fixed"]["iou"]["median"]
    assert m["graph"]["iou"]["median"] > m["quadric"]["iou"]["median"]
