"""Small helpers shared by several test modules: command lines and a camera with box masks."""

import importlib.util
import os
import signal
import subprocess
import sys

import numpy as np

from pathlib import Path

from sqfit import Camera, Intrinsics, look_at

#: A 64 x 48 camera 10 m out on +x, looking at the origin.
INTR = Intrinsics(64, 48, 40.0, 30.0, 32.0, 24.0)
CAM = Camera(INTR, look_at([10.0, 0, 0], [0, 0, 0]))


def rect_mask(r0=10, r1=20, c0=5, c1=30, shape=(48, 64)):
    """``(h, w) bool``: True on rows ``r0:r1`` and columns ``c0:c1``."""
    mask = np.zeros(shape, bool)
    mask[r0:r1, c0:c1] = True
    return mask


def run_command(program, *args):
    """Run ``python -m PROGRAM.cli ARGS`` (``program``: ``"sqsim"`` or ``"sqfit"``); text output captured."""
    return subprocess.run([sys.executable, "-m", f"{program}.cli", *map(str, args)], capture_output=True, text=True)


def popen_interruptible(cmd, **kwargs):
    """``subprocess.Popen(cmd, start_new_session=True, **kwargs)`` with the child's SIGINT at Python's
    default, as from a terminal, whatever this process inherited: a shell starts background jobs
    (``.ci/run > log &``) with SIGINT ignored, a process started so keeps ignoring it, and a test of
    Ctrl-C would then hang. A handled signal is reset to its default by exec."""
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen(cmd, start_new_session=True, **kwargs)
    finally:
        signal.signal(signal.SIGINT, inherited)


def kill_group(proc):
    """SIGKILL the process group of ``proc`` (started by :func:`popen_interruptible`) and reap it:
    whatever a test asserted, no worker of the group keeps running."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def assert_bad_file(path, text, reader, match, error=ValueError):
    """Write ``text`` to ``path``; ``reader(path)`` must raise ``error`` whose message matches ``match``."""
    import pytest

    path.write_text(text)
    with pytest.raises(error, match=match):
        reader(path)


def mask_shapes():
    """Small masks with known outlines: a rectangle, an L (a concave corner), a block in the image's
    top-right corner (touches the border)."""
    square = np.zeros((40, 50), bool)
    square[5:20, 10:30] = True
    ell = square.copy()
    ell[20:35, 10:16] = True  # a concave corner
    border = np.zeros((30, 30), bool)
    border[:12, 20:] = True  # touches the image border, corner included
    return {"square": square, "ell": ell, "border": border}


def turned_pose(pose, rotvec):
    """``pose`` (camera -> world, ``(4, 4)``) with its rotation turned by ``rotvec`` (radians, about
    the camera's own axes: ``R exp([rotvec]x)``), a copy."""
    from scipy.spatial.transform import Rotation

    out = np.array(pose, dtype=np.float64)
    out[:3, :3] = out[:3, :3] @ Rotation.from_rotvec(rotvec).as_matrix()
    return out


def stage(result, name):
    """The last :class:`sqfit.StageRecord` named ``name`` of a :class:`sqfit.FitResult` (the default chain
    ends in 3R, so 3H's record is not the last one)."""
    return [s for s in result.stages if s.name == name][-1]


def through_3h(obs, options):
    """The :class:`sqfit.fitting.stages.FitState` after stages 1, 2M and 3H on ``obs`` (an ObservationSet), run
    as the chain runs them (numpy's floating-point warnings off): what 3H hands on, ``camera_corrections``
    included, which :class:`sqfit.FitResult` does not carry."""
    from sqfit.fitting.stages import STAGES, default_state

    state = default_state(obs)
    with np.errstate(all="ignore"):
        for name in ("1", "2M", "3H"):
            state = STAGES[name](state, obs, options)
    return state


def graph_values(poses, objects):
    """``gtsam.Values`` of a superquadric graph: ``X(i)`` at each of ``poses`` (camera -> world) and
    each object's landmark ``L(j)``, ``S(j)`` at ``objects`` (``{j: sqfit.Superquadric}``)."""
    import gtsam
    from gtsam.symbol_shorthand import L, S, X

    from sqfit.graph.landmark import superquadric_to_landmark

    values = gtsam.Values()
    for i, T in enumerate(poses):
        values.insert(X(i), gtsam.Pose3(T))
    for oid, sq in objects.items():
        T, shape = superquadric_to_landmark(sq)
        values.insert(L(oid), gtsam.Pose3(T))
        values.insert(S(oid), shape)
    return values


def sq_vector(size, shape):
    """11 superquadric parameters with these half-axes and shape exponents, at a fixed pose."""
    return np.r_[size, shape, 0.5, -1.0, 2.0, 0.1, -0.2, 0.3]


#: The repository's benchmark and script folders.
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def script_module(path):
    """The module of the Python file ``path`` (a benchmark or a script), loaded under its file name."""
    spec = importlib.util.spec_from_file_location(Path(path).stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def benchmark_script(name, monkeypatch):
    """The module of ``benchmarks/NAME.py``, loaded with ``benchmarks/`` on the path (the scripts import
    ``_common``)."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    return script_module(BENCHMARKS / f"{name}.py")
