import subprocess
import sys


def test_sqfit_does_not_import_opengl_or_sqsim():
    code = ("import sys, sqfit, sqfit.cli; "
            "import sqfit.recording, sqfit.cli.fit; "
            "bad = [m for m in ('OpenGL', 'pyrender', 'sqsim', 'pycolmap', 'pycocotools', 'rerun', 'distributed', 'numba', "
            "'llvmlite') "
            "if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_help_works():
    for prog in ("sqsim", "sqfit"):
        out = subprocess.run([sys.executable, "-m", f"{prog}.cli", "--help"], capture_output=True, text=True)
        assert out.returncode == 0 and "COMMAND" in out.stdout, out.stderr


def test_formats_import_no_optional_library():
    code = ("import sys, sqfit.formats, sqfit.cli.fit; "
            "bad = [m for m in ('pycolmap', 'pycocotools', 'sqsim') if m in sys.modules]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_sequence_readers_import_no_optional_library():
    code = ("import sys, sqfit.views.dataset, sqfit.formats.tum; "
            "bad = [m for m in ('OpenGL', 'pyrender', 'sqsim', 'evo', 'gtsam') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_sqfit_does_not_import_gtsam_but_sqfit_graph_does():
    code = ("import sys, sqfit, sqfit.cli; assert 'gtsam' not in sys.modules, 'sqfit imported gtsam'; "
            "import sqfit.graph; assert 'gtsam' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_first_fit_imports_numba_lazily():
    # the compiled kernels come in at the first fit that needs them, not with the package
    code = ("import sys, sqfit; from sqfit.testing import paper_trial; assert 'numba' not in sys.modules; "
            "sqfit.fit(paper_trial(0).observations); "
            "import sqfit.fitting.backend as b; assert ('numba' in sys.modules) == (b.kernels_name() == 'numba')")
    subprocess.run([sys.executable, "-c", code], check=True)
