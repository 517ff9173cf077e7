import subprocess
import sys


import pytest


@pytest.mark.parametrize("imports, absent", [
    # the fitter and its command line: no renderer, no simulator, no optional library, no compiler
    ("sqfit, sqfit.cli, sqfit.recording, sqfit.cli.fit",
     ("OpenGL", "pyrender", "sqsim", "pycolmap", "pycocotools", "rerun", "distributed", "numba", "llvmlite")),
    ("sqfit.formats, sqfit.cli.fit", ("pycolmap", "pycocotools", "sqsim")),
    ("sqfit.views.dataset, sqfit.formats.tum", ("OpenGL", "pyrender", "sqsim", "evo", "gtsam")),
])
def test_imports_leave_heavy_modules_out(imports, absent):
    code = f"import sys, {imports}; bad = [m for m in {absent!r} if m in sys.modules]; assert not bad, bad"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_help_works():
    for prog in ("sqsim", "sqfit"):
        out = subprocess.run([sys.executable, "-m", f"{prog}.cli", "--help"], capture_output=True, text=True)
        assert out.returncode == 0 and "COMMAND" in out.stdout, out.stderr


def test_sqfit_does_not_import_gtsam_but_sqfit_graph_does():
    code = ("import sys, sqfit, sqfit.cli; assert 'gtsam' not in sys.modules, 'sqfit imported gtsam'; "
            "import sqfit.graph; assert 'gtsam' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_first_fit_imports_numba_lazily():
    # the compiled kernels come in at the first fit that needs them, not with the package
    code = ("import sys, sqfit; from sqfit.testing import paper_trial; assert 'numba' not in sys.modules; "
            "sqfit.fit(paper_trial(0).observations); "
            "import sqfit.kernels.backend as b; assert ('numba' in sys.modules) == (b.kernels_name() == 'numba')")
    subprocess.run([sys.executable, "-c", code], check=True)
