import json
import signal
import subprocess
import sys
import time

import pytest

import sqfit
from sqsim.data.provenance import library_versions
from sqsim.runs.experiment import parse_chains, run_experiment
from sqsim.world.scene import parse_scene

from _helpers import run_command  # noqa: E402

CHAINS = ["1-2-3D", "1-2-3D-3A"]
STAT_KEYS = {"median", "mean", "std"}


def small_scene(trials=4, seed=3, chains=CHAINS):
    return parse_scene({"experiment": {"name": "small", "seed": seed, "trials": trials, "chains": list(chains)},
                        "masks": {"renderer": "polygon"}}, source="<test>")


def without_time(summary):
    """Summaries are compared without timings, which differ between runs by nature."""
    return {**summary, "chains": {c: {k: v for k, v in e.items() if k != "time_s"}
                                  for c, e in summary["chains"].items()}}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    return out, run_experiment(small_scene(), out, progress=False)


def test_summary_has_every_chain_with_design_keys(reference):
    out, summary = reference
    assert set(summary) >= {"scene", "trials", "resampled", "seed", "chains", "installs"}
    assert summary["installs"] == [library_versions()] == json.loads((out / "experiment.json").read_text())["installs"]
    assert summary["trials"] == 4 and summary["seed"] == 3 and summary["scene"] == "small"
    assert list(summary["chains"]) == CHAINS
    for entry in summary["chains"].values():
        for metric in ("iou", "r_iou", "r_iou_m", "time_s"):
            assert set(entry[metric]) == STAT_KEYS
        assert 0.0 <= entry["success_rate"] <= 1.0 and entry["errors"] >= 0
    assert json.loads((out / "summary.json").read_text()) == summary
    for name in ("table.md", "table.tex", "violin.png", "example.png", "trials.jsonl", "experiment.json"):
        assert (out / name).stat().st_size > 0, name
    records = [json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()]
    assert len(records) == 4 * len(CHAINS)
    assert all(len(r["stages"]) == len(r["chain"].split("-")) for r in records if r["status"] == "ok")
    table = (out / "table.md").read_text()
    assert "1 → 2 → 3D → 3A" in table and "*paper*" in table
    comparison = (out / "comparison.md").read_text()
    iou = summary["chains"]["1-2-3D-3A"]["iou"]["median"]
    assert f"| 1 → 2 → 3D → 3A | {iou:.3f} (0.760) | {iou - 0.760:+.3f} |" in comparison


def test_the_staged_fitter_recovers_the_objects(reference):
    _, summary = reference
    entry = summary["chains"]["1-2-3D-3A"]
    assert entry["success_rate"] == 1.0 and entry["errors"] == 0
    assert entry["iou"]["median"] > 0.6 and entry["r_iou"]["median"] > 0.8


def test_rerun_is_a_no_op_and_more_trials_resume(reference, tmp_path):
    out, summary = reference
    before = (out / "trials.jsonl").read_bytes()
    assert without_time(run_experiment(small_scene(), out, progress=False)) == without_time(summary)
    assert (out / "trials.jsonl").read_bytes() == before
    # Two trials first, then four: same as four at once.
    run_experiment(small_scene(trials=2), tmp_path, progress=False)
    assert without_time(run_experiment(small_scene(trials=4), tmp_path, progress=False)) == without_time(summary)


def test_results_do_not_depend_on_worker_count(reference, tmp_path):
    _, summary = reference
    assert without_time(run_experiment(small_scene(), tmp_path, workers=2, progress=False)) == without_time(summary)


def test_dask_local_cluster_gives_the_same_results(reference, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, summary = reference
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        got = run_experiment(small_scene(), tmp_path, scheduler=cluster.scheduler_address, progress=False)
    assert without_time(got) == without_time(summary)


def test_killed_experiment_resumes_to_the_same_summary(reference, tmp_path):
    _, summary = reference
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text('[experiment]\nname = "small"\nseed = 3\ntrials = 4\nchains = ["1-2-3D", "1-2-3D-3A"]\n'
                          '[masks]\nrenderer = "polygon"\n')
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "sqsim.cli", "experiment", str(scene_file), "-o", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    jsonl = out / "trials.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and not (jsonl.exists() and jsonl.stat().st_size > 0):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = len(jsonl.read_text().splitlines())
    assert 0 < done < 4 * len(CHAINS), "the kill should land mid-way"
    with open(jsonl, "a") as fh:  # as if the kill cut a line in half
        fh.write('{"trial": 3, "chain": "1-2')
    assert subprocess.run(cmd, capture_output=True).returncode == 0
    lines = jsonl.read_text().splitlines()
    assert len(lines) == 4 * len(CHAINS)
    assert len({(json.loads(x)["trial"], json.loads(x)["chain"]) for x in lines}) == len(lines)
    got = json.loads((out / "summary.json").read_text())
    assert without_time(got) == without_time(summary)


def test_resume_into_a_different_experiment_is_refused(reference):
    out, _ = reference
    with pytest.raises(ValueError, match="holds a different experiment"):
        run_experiment(small_scene(seed=4), out, progress=False)


def test_chain_arguments(tmp_path):
    assert parse_chains("default") == [sqfit.DEFAULT_CHAIN]
    assert parse_chains("paper") == list(sqfit.PAPER_CHAINS)
    assert parse_chains("1-2-3D, default,1-2-3D") == ["1-2-3D", sqfit.DEFAULT_CHAIN]
    with pytest.raises(ValueError, match="--chains is empty"):
        parse_chains(" , ")
    with pytest.raises(ValueError, match=r"unknown stage\(s\) \['3Z'\]"):
        run_experiment(small_scene(chains=["1-3Z"]), tmp_path / "never-created", progress=False)
    assert not (tmp_path / "never-created").exists()


def test_cli_reports_bad_scene_cleanly(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[experiment\nname=")
    out = run_command("sqsim", "experiment", bad, "-o", tmp_path / "o")
    assert out.returncode == 2
    assert "bad.toml" in out.stderr and "Traceback" not in out.stderr


def test_mesh_ground_truths_are_scored_by_mesh_boolean(tmp_path):
    scene = parse_scene({"experiment": {"name": "boxes", "seed": 2, "trials": 2, "chains": ["default"]},
                         "objects": {"kind": "box"}, "masks": {"renderer": "polygon"}}, source="<test>")
    summary = run_experiment(scene, tmp_path, progress=False)
    records = [json.loads(line) for line in (tmp_path / "trials.jsonl").read_text().splitlines()]
    assert [r["gt"]["kind"] for r in records] == ["box", "box"]
    assert all(r["status"] == "ok" and r["metrics"]["iou"] > 0.5 for r in records)
    assert summary["chains"][sqfit.DEFAULT_CHAIN]["success_rate"] == 1.0
    assert not (tmp_path / "example.png").exists()  # the example figure needs a superquadric ground truth


def test_best_chain_prefers_reliability():
    from sqsim.reports.experiment import best_chain

    entry = lambda success, iou: {"success_rate": success, "iou": {"median": iou}, "time_s": {"median": 0.1}}  # noqa: E731
    assert best_chain({"chains": {"a": entry(0.99, 0.93), "b": entry(1.0, 0.91), "c": entry(1.0, 0.80)}}) == "b"


def test_resume_accepts_configs_written_before_a_scene_key_existed(reference, tmp_path):
    import shutil

    out, summary = reference
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    config = json.loads((copy / "experiment.json").read_text())
    del config["scene"]["masks"]["cleanup"]  # as written by a version without that key
    (copy / "experiment.json").write_text(json.dumps(config))
    assert without_time(run_experiment(small_scene(), copy, progress=False)) == without_time(summary)


def test_unfittable_observations_are_recorded_not_fatal(tmp_path):
    # Erosion wipes every mask out: each record says why, and the summary counts errors.
    scene = small_scene(trials=1, chains=["default"]).with_overrides({"noise.erosion_px": 500})
    summary = run_experiment(scene, tmp_path, progress=False)
    (record,) = [json.loads(line) for line in (tmp_path / "trials.jsonl").read_text().splitlines()]
    assert record["status"] == "bad_observation" and "at least 2" in record["message"]
    assert record["metrics"] == {"iou": 0.0, "r_iou": 0.0, "r_iou_m": 0.0, "r_iou_m_contour": 0.0,
                                 "time_s": 0.0, "success": False}
    entry = summary["chains"][sqfit.DEFAULT_CHAIN]
    assert entry["errors"] == 1 and entry["success_rate"] == 0.0
