"""Command-line pieces shared by the benchmark scripts."""

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def scene_parser(doc, repeat_help, trials=100):
    """An argument parser with ``--scene`` (default scenes/paper.toml), ``--trials``, ``--renderer``, ``--repeat``."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "paper.toml"))
    parser.add_argument("--trials", type=int, default=trials)
    parser.add_argument("--renderer", default=None, help="osmesa | egl | polygon (default: the scene's)")
    parser.add_argument("--repeat", type=int, default=3, help=repeat_help)
    return parser
