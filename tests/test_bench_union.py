"""benchmarks/bench_union.py: one lamp, both kernel choices, the parts of an evaluation and their comparison."""

import re

import pytest

from _helpers import benchmark_script

pytest.importorskip("numba")


def test_bench_union_times_both_kernel_choices_and_compares_their_gradients(capsys, monkeypatch):
    bench = benchmark_script("bench_union", monkeypatch)
    monkeypatch.setattr(bench, "CALLS", 2)
    bench.main(["--trials", "1", "--repeat", "1"])
    out = capsys.readouterr().out
    assert "objects.catalogue=[lamp]" in out.splitlines()[0]
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| (numba|numpy) \| (.*) \|$", out, re.M)}
    assert set(rows) == {"numba", "numpy"}
    for cells in rows.values():
        figures = [float(x) for x in re.findall(r"[\d.]+", cells)]
        assert len(figures) == 6 and all(f > 0 for f in figures)
    gap = float(re.search(r"largest difference of the IoUs and gradients (\S+)", out).group(1))
    assert gap < 1e-8
