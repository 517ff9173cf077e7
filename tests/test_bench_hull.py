"""benchmarks/bench_hull.py: one household object, both kernel choices, its table and its comparison."""

import re

import pytest

from _helpers import benchmark_script

pytest.importorskip("numba")


def test_bench_hull_times_both_kernel_choices_and_compares_them(capsys, monkeypatch):
    bench = benchmark_script("bench_hull", monkeypatch)
    bench.main(["--trials", "1", "--repeat", "1", "--set", "objects.catalogue=[can]"])
    out = capsys.readouterr().out
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| (numba|numpy) \| (.*) \|$", out, re.M)}
    assert set(rows) == {"numba", "numpy"}
    for cells in rows.values():
        figures = [float(x) for x in re.findall(r"[\d.]+", cells)]
        assert len(figures) == 6 and all(f > 0 for f in figures)
    assert "the same hull on 1 of 1 objects" in out
