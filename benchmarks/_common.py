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


def household_parser(doc, repeat_help, trials):
    """:func:`scene_parser` on ``scenes/household.toml`` with ``--set`` (scene overrides, as sqsim experiment's)."""
    parser = scene_parser(doc, repeat_help, trials=trials)
    parser.set_defaults(scene=str(ROOT / "scenes" / "household.toml"))
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="scene override, as sqsim experiment's --set")
    return parser


def rendered_objects(args):
    """The observations of each object of trials ``0 .. args.trials - 1`` of ``args.scene`` (with
    ``args.overrides`` and ``args.renderer``), rendered once: a list of per-object observation lists."""
    from sqsim.imaging.render import get_renderer
    from sqsim.imaging.trial import observations, simulate_trial
    from sqsim.world.scene import load_scene, scene_overrides

    overrides = scene_overrides(args.overrides)
    if args.renderer:
        overrides["masks.renderer"] = args.renderer
    scene = load_scene(args.scene, overrides)
    renderer = get_renderer(scene.masks.renderer, scene.intrinsics)
    objects = []
    for i in range(args.trials):
        sim = simulate_trial(scene, i, renderer)
        objects += [list(observations(sim, obj.id, scene)) for obj in sim.objects]
    return objects
