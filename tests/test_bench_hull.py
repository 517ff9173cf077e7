"""benchmarks/bench_hull.py: one household object, both kernel choices, its table and its comparison."""

import importlib.util
import re
from pathlib import Path

import pytest

pytest.importorskip("numba")

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_hull.py"


def test_bench_hull_times_both_kernel_choices_and_compares_them(capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(_PATH.parent))  # the script imports benchmarks/_common.py
    spec = importlib.util.spec_from_file_location("bench_hull", _PATH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--trials", "1", "--repeat", "1", "--set", "objects.catalogue=[can]"])
    out = capsys.readouterr().out
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| (numba|numpy) \| (.*) \|$", out, re.M)}
    assert set(rows) == {"numba", "numpy"}
    for cells in rows.values():
        figures = [float(x) for x in re.findall(r"[\d.]+", cells)]
        assert len(figures) == 6 and all(f > 0 for f in figures)
    assert "the same hull on 1 of 1 objects" in out
