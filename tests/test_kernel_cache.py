"""numba's cache of the compiled kernels follows changes of the kernels they call in another file
(sqfit.kernels.kernel_cache): a checkout whose ``ray_kernels.py`` changed must not keep running
silhouette factors compiled against the old one."""

import os
import shutil
import subprocess
import sys

import pytest

import sqfit
from sqfit.kernels import kernel_cache

pytest.importorskip("numba")

#: One silhouette factor of four rays through a superquadric 5 m ahead: prints the residuals' sum.
PROBE = """
import sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from sqfit.fitting import line_gauge, raycost
from sqfit.kernels import view_kernels
camera, landmark = np.eye(4)[None].copy(), np.eye(4)[None].copy()
landmark[0, 2, 3] = 5.0
shape = np.array([[0.5, 0.4, 0.3, 1.0, 1.0]])
bearings = np.array([[[0.1, 0.0, 1.0], [0.0, 0.09, 1.0], [-0.1, 0.0, 1.0], [0.0, -0.09, 1.0]]])
off, on = np.zeros((1, 4), dtype=bool), np.ones((1, 4), dtype=bool)
rows = np.zeros(1, dtype=np.int64)
r = view_kernels.silhouette_rows(camera, landmark, shape, rows, bearings, np.ones((1, 4)), off, off, on,
                                 np.array([0.01] * 3 + [0.1] * 2), np.array([10.0] * 3 + [1.9] * 2),
                                 *line_gauge.solver_args(start="nearest"), *raycost.CROSSING_ARGS)[0]
print(repr(float(r.sum())))
"""


def _write(path, text=""):
    with open(path, "w") as f:
        f.write(text)


def test_refresh_removes_the_kernel_modules_cache_files_when_a_source_changes(tmp_path):
    src, cache = tmp_path / "src", tmp_path / "cache"
    src.mkdir()
    cache.mkdir()
    sources = {name: str(src / f"{name}.py") for name in ("ray_kernels", "view_kernels")}
    _write(sources["ray_kernels"], "a = 1\n")
    _write(sources["view_kernels"], "b = 2\n")
    kernel_files = ["view_kernels.silhouette_rows-40.py311.nbi", "view_kernels.silhouette_rows-40.py311.1.nbc",
                    "ray_kernels.nan_max-36.py311.nbi"]
    others = ["ray_kernels.cpython-311.pyc", "costs.f-1.py311.nbi", "ray_kernels.py"]

    def populate():
        for name in kernel_files + others:
            _write(cache / name)

    populate()
    # no stamp yet: whatever is cached was compiled from unknown sources
    assert kernel_cache.refresh(str(cache), sources) == 3
    assert sorted(os.listdir(cache)) == sorted(others + [kernel_cache.STAMP])
    assert (cache / kernel_cache.STAMP).read_text().strip() == kernel_cache.source_digest(sources)
    populate()
    assert kernel_cache.refresh(str(cache), sources) == 0  # the same sources: the cache stands
    assert all((cache / name).exists() for name in kernel_files)
    _write(sources["ray_kernels"], "a = 3\n")  # a change of the file the others call
    assert kernel_cache.refresh(str(cache), sources) == 3
    assert not any((cache / name).exists() for name in kernel_files)
    assert all((cache / name).exists() for name in others)
    assert kernel_cache.refresh(str(tmp_path / "missing"), sources) == 0


def test_a_change_of_the_ray_kernels_reaches_the_cached_silhouette_kernel(tmp_path):
    """The numba cache alone keeps the silhouette kernel compiled against the old ray kernels (this
    test fails without :mod:`sqfit.kernels.kernel_cache`); with it, the change takes effect."""
    package = os.path.dirname(sqfit.__file__)
    shutil.copytree(package, tmp_path / "sqfit", ignore=shutil.ignore_patterns("__pycache__"))
    probe = tmp_path / "probe.py"
    _write(probe, PROBE)

    def run():
        done = subprocess.run([sys.executable, str(probe), str(tmp_path)], capture_output=True, text=True, timeout=600,
                              env={**os.environ, "NUMBA_CACHE_DIR": ""})
        assert done.returncode == 0, done.stderr
        return float(done.stdout)

    before = run()
    assert run() == before  # from the cache
    kernels = tmp_path / "sqfit" / "kernels" / "ray_kernels.py"
    text = kernels.read_text()
    line = "    return math.log(rnorm) - math.log(S_)\n"
    assert text.count(line) == 1
    kernels.write_text(text.replace(line, "    return math.log(rnorm) - math.log(S_) + 1.0\n"))
    after = run()
    assert after != pytest.approx(before, abs=1e-6)
