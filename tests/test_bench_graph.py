"""benchmarks/bench_graph.py: the growth test's --prefix and --scene-lap-pattern options, --exact-odometry."""

import json
import re

import pytest

from sqfit import graph
from sqfit.graph.testing import position_rmse, synthetic_sequence
from _helpers import BENCHMARKS, script_module

_PATH = BENCHMARKS / "bench_graph.py"


@pytest.fixture(scope="module")
def bench():
    return script_module(_PATH)


def test_prefix_compares_the_first_frames_alone_with_the_whole_run(bench, tmp_path, capsys):
    out = tmp_path / "rows.json"
    bench.main(["--seeds", "1", "--frames", "10", "--objects", "2", "--methods", "graph", "--prefix", "6",
                "--json", str(out)])
    (row,) = json.loads(out.read_text())
    assert row["prefix_frames"] == 6
    # the first frames alone: the method on those frames' odometry and observations only
    seq = synthetic_sequence(0, 10, 2)
    observations = {key: o for key, o in seq.observations.items() if key[0] < 6}
    alone = graph.run(seq.intrinsics, seq.odometry_poses[:6], observations, ["graph"])["graph"]
    assert row["ate_prefix_alone_m"] == pytest.approx(position_rmse(alone.poses, seq.true_poses[:6]), rel=1e-9)
    # inside the whole run: the run's own poses of those frames (not its whole-run ATE)
    full = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"])["graph"]
    assert row["ate_prefix_in_run_m"] == pytest.approx(position_rmse(full.poses[:6], seq.true_poses[:6]), rel=1e-9)
    assert row["ate_m"] == pytest.approx(position_rmse(full.poses, seq.true_poses), rel=1e-9)
    assert row["ate_prefix_in_run_m"] != row["ate_m"]
    assert 0.0 <= row["iou_prefix_alone"] <= 1.0 and 0.0 <= row["iou_prefix_in_run"] <= 1.0
    assert "the first 6 frames alone and inside the whole run" in capsys.readouterr().out


@pytest.mark.parametrize("argv, match", [
    (["--prefix", "1"], r"--prefix must be 0 \(none\) or at least 2 frames, got 1"),
    (["--scene-lap-pattern", "lap"], r"--scene-lap-pattern needs --scene"),
])
def test_growth_options_are_checked(bench, argv, match, capsys):
    with pytest.raises(SystemExit):
        bench.main(argv)
    assert re.search(match, capsys.readouterr().err)


def test_exact_odometry_gives_the_methods_the_true_poses(bench, tmp_path, capsys):
    out = tmp_path / "rows.json"
    bench.main(["--seeds", "1", "--frames", "8", "--objects", "2", "--methods", "odometry,graph", "--exact-odometry",
                "--json", str(out)])
    odometry, batch = json.loads(out.read_text())
    # the odometry the methods were given is the truth: its own ATE and the rows' odometry columns are 0
    assert odometry["ate_m"] == pytest.approx(0.0, abs=1e-12)
    assert batch["ate_odometry_m"] == pytest.approx(0.0, abs=1e-12)
    # and the graph ran from it: the same as graph.run given the true poses as odometry
    seq = synthetic_sequence(0, 8, 2)
    exact = graph.run(seq.intrinsics, seq.true_poses, seq.observations, ["graph"])["graph"]
    assert batch["ate_m"] == pytest.approx(position_rmse(exact.poses, seq.true_poses), rel=1e-9)
    noisy = graph.run(seq.intrinsics, seq.odometry_poses, seq.observations, ["graph"])["graph"]
    assert batch["ate_m"] != pytest.approx(position_rmse(noisy.poses, seq.true_poses), rel=1e-6)
    assert "the true poses as odometry" in capsys.readouterr().out
