"""Helpers shared by the dataset tests (native, sequence and export datasets)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

#: A small camera (160 x 120) for scenes that write datasets quickly.
SMALL_CAMERA = """
[camera]
width = 160
height = 120
fx = 100.0
fy = 75.0
cx = 80.0
cy = 60.0
"""


def files(root):
    """``{relative path: bytes}`` of every file below ``root``."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(Path(root).rglob("*")) if p.is_file()}


def kill_generate_midway(scene_file, output, at_least, timeout_s=60.0):
    """Start ``sqsim generate SCENE -o OUTPUT``, SIGKILL it once ``at_least`` trials are finished.

    Returns
    -------
    cmd : list of str
        The command, to run again (it must resume).
    done : int
        Finished trial directories after the kill.
    """
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "sqsim.cli", "generate", str(scene_file), "-o", str(output), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trials = Path(output) / "trials"
    deadline = time.time() + timeout_s
    while time.time() < deadline and not (trials.is_dir() and len(list(trials.glob("0*"))) >= at_least):
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return cmd, len(list(trials.glob("0*")))


#: Two free objects with masks of at least 20 px: the body of the small dataset scenes.
TWO_OBJECTS = """[objects]
count = 2
size = [0.3, 1.5]
position = [-1.5, 1.5]
[masks]
min_area_px = 20
"""


def small_scene(seed, trials, noise):
    """TOML of a small dataset scene: ``SMALL_CAMERA``, ``TWO_OBJECTS`` and a ``[noise]`` table.

    ``noise`` : dict of ``key -> value`` of the noise table.
    """
    noise_lines = "".join(f"{k} = {v}\n" for k, v in noise.items())
    return f"[experiment]\nseed = {seed}\ntrials = {trials}\n" + SMALL_CAMERA + TWO_OBJECTS + "[noise]\n" + noise_lines


def small_parsed_scene(**sections):
    """A parsed small scene (``SMALL_CAMERA`` and two free objects), ``sections`` merged into its tables.

    ``sections`` : ``table name -> {key: value}``, e.g. ``noise={"dropout": 0.1}``.
    """
    from sqsim.world.scene import parse_scene

    data = {"camera": {"width": 160, "height": 120, "fx": 100.0, "fy": 75.0, "cx": 80.0, "cy": 60.0},
            "objects": {"size": [0.3, 1.5], "position": [-1.5, 1.5]}, "masks": {"min_area_px": 20}}
    for name, values in sections.items():
        data.setdefault(name, {}).update(values)
    return parse_scene(data)
