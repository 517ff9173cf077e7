"""Small helpers shared by several test modules: command lines and a camera with box masks."""

import subprocess
import sys

import numpy as np

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


def assert_bad_file(path, text, reader, match, error=ValueError):
    """Write ``text`` to ``path``; ``reader(path)`` must raise ``error`` whose message matches ``match``."""
    import pytest

    path.write_text(text)
    with pytest.raises(error, match=match):
        reader(path)
