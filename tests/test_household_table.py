"""scripts/household_table.py: the README's per-kind table from experiment outputs."""

import json
import subprocess
import sys
from pathlib import Path

import sqfit

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "household_table.py"


def _run_dir(path, seed, rows):
    """An experiment output with records ``(item, chain, iou, limit, seconds)``."""
    path.mkdir()
    (path / "experiment.json").write_text(json.dumps({"scene": {"experiment": {"seed": seed}}}))
    lines = []
    for trial, (item, chain, iou, limit, seconds) in enumerate(rows):
        record = {"trial": trial, "object": 1, "chain": chain, "gt": {"item": item, "item_seed": trial},
                  "metrics": {"iou": iou}, "time_s": seconds}
        if limit is not None:
            record["limit"] = {"iou": limit}
            record["metrics"]["iou_limit"] = limit
        lines.append(json.dumps(record))
    (path / "trials.jsonl").write_text("\n".join(lines) + "\n")
    return str(path)


def test_rows_per_kind_and_seed_with_the_targets_in_bold(tmp_path):
    d = sqfit.DEFAULT_CHAIN
    a = _run_dir(tmp_path / "a", 0, [("can", d, 0.98, 0.99, 0.01), ("can", "HULL", 0.90, 0.99, 0.3),
                                     ("mug", d, 0.70, 0.92, 0.08), ("mug", "HULL", 0.69, 0.92, 0.4)])
    b = _run_dir(tmp_path / "b", 4, [("mug", d, 0.80, 0.90, 0.1), ("mug", "HULL", 0.60, 0.90, 0.5),
                                     ("can", d, 0.96, None, 0.012), ("can", "HULL", 0.97, None, 0.3)])
    out = subprocess.run([sys.executable, str(SCRIPT), b, a], capture_output=True, text=True, check=True).stdout
    rows = {line.split(" | ")[0].lstrip("| "): line for line in out.splitlines() if line.startswith("| ")}
    # seeds in ascending order whatever the order of the directories; the targets 0.95 and +0.03 in bold
    assert rows["mug"] == ("| mug | 0.700 / 0.800 | 0.690 / 0.600 | 0.920 / 0.900 | 0.76 / 0.89 | +0.010 / **+0.200** "
                           "| 80 / 400, 100 / 500 |")
    # a run without limits leaves its limit cells empty; a negative difference gets a minus sign
    assert rows["can"] == ("| can | 0.980 / 0.960 | 0.900 / 0.970 | 0.990 / – | **0.99** / – "
                           "| **+0.080** / −0.010 | 10 / 300, 12 / 300 |")
    assert list(rows)[1:] == ["mug", "can"]  # the README's order of kinds
    assert "seeds 0 / 4; objects per kind and seed: 1" in out


def test_a_ratio_just_below_the_target_is_not_rounded_up_to_it(tmp_path):
    d = sqfit.DEFAULT_CHAIN
    a = _run_dir(tmp_path / "a", 0, [("book", d, 0.92414, 0.97315, 0.03), ("book", "HULL", 0.537, 0.97315, 0.3)])
    b = _run_dir(tmp_path / "b", 4, [("book", d, 0.9299, 0.97318, 0.03), ("book", "HULL", 0.547, 0.97318, 0.3)])
    out = subprocess.run([sys.executable, str(SCRIPT), a, b], capture_output=True, text=True, check=True).stdout
    row = next(line for line in out.splitlines() if line.startswith("| book"))
    # 0.92414 / 0.97315 = 0.94964: "0.95" would read as the target met; 0.9555 rounds to a met 0.96
    assert "| 0.9496 / **0.96** |" in row, row


def test_not_an_experiment_output_is_one_line(tmp_path):
    res = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True)
    assert res.returncode == 1 and "not an sqsim experiment output" in res.stderr


def test_mesh_file_objects_are_grouped_by_file_name(tmp_path):
    d = sqfit.DEFAULT_CHAIN
    run = tmp_path / "duck"
    _run_dir(run, 1, [("x", d, 0.6, 0.7, 0.1), ("x", "HULL", 0.5, 0.7, 0.3)])
    lines = [json.loads(line) for line in (run / "trials.jsonl").read_text().splitlines()]
    for r in lines:
        r["gt"] = {"kind": "mesh", "path": "/data/scans/duck_vhacd.obj"}
    (run / "trials.jsonl").write_text("\n".join(json.dumps(r) for r in lines) + "\n")
    out = subprocess.run([sys.executable, str(SCRIPT), str(run)], capture_output=True, text=True, check=True).stdout
    assert "| duck vhacd | 0.600 | 0.500 | 0.700 | 0.86 | **+0.100** | 100 / 300 |" in out


def test_the_silhouettes_table_counts_where_the_limit_matches_the_masks_better(tmp_path):
    d = sqfit.DEFAULT_CHAIN
    run = tmp_path / "bowls"
    _run_dir(run, 0, [("bowl", d, 0.5, 0.7, 0.1), ("bowl", d, 0.6, 0.7, 0.1), ("bowl", d, 0.4, 0.7, 0.1)])
    lines = [json.loads(line) for line in (run / "trials.jsonl").read_text().splitlines()]
    for r, (fit, limit) in zip(lines, [(0.9, 0.7), (0.8, 0.85), (0.7, 0.6)]):
        r["metrics"].update(r_iou_m_contour=fit, r_iou_m_contour_limit=limit)
    (run / "trials.jsonl").write_text("\n".join(json.dumps(r) for r in lines) + "\n")
    out = subprocess.run([sys.executable, str(SCRIPT), str(run), "--silhouettes"], capture_output=True, text=True,
                         check=True).stdout
    assert "| bowl | 0.800 | 0.700 | 1 of 3 |" in out.splitlines()
    plain = subprocess.run([sys.executable, str(SCRIPT), str(run)], capture_output=True, text=True, check=True).stdout
    assert "the limit's match better" not in plain
