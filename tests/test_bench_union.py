"""benchmarks/bench_union.py: one lamp, both kernel choices, the parts of an evaluation and their comparison."""

import importlib.util
import re
from pathlib import Path

import pytest

pytest.importorskip("numba")

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_union.py"


def test_bench_union_times_both_kernel_choices_and_compares_their_gradients(capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(_PATH.parent))  # the script imports benchmarks/_common.py
    spec = importlib.util.spec_from_file_location("bench_union", _PATH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
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
