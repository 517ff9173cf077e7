"""A small sub-command dispatcher shared by the ``sqfit`` and ``sqsim`` command lines.

Each command lives in its own module exposing ``add_arguments(parser)`` and ``run(args) -> int``;
a module is imported only when its command runs, so ``--help`` is fast and a command never pays
for another's imports. Expected errors (bad input, missing files) print one clear line and exit
with status 2 instead of a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Appends ``(default: X)`` where it tells something: not for None/False/[] or help that says it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" not in text and action.default not in (None, False, [], argparse.SUPPRESS)
                and action.option_strings):
            text += f" (default: {action.default})"
        return text


def dispatch(argv, commands, prog, description):
    """Parse ``argv`` and run the chosen command.

    Parameters
    ----------
    argv : list of str or None
        Arguments without the program name (``None``: ``sys.argv[1:]``).
    commands : dict
        ``name -> (module path, one-line help)``.
    prog, description : str

    Returns
    -------
    status : int
        Process exit status.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    name = f"{prog} {argv[0]}" if argv[:1] and argv[0] in commands else prog
    try:
        return _dispatch(argv, commands, prog, description)
    except KeyboardInterrupt:  # also while a command's modules are still being imported
        print(f"{name}: interrupted", file=sys.stderr)
        return 130


def _dispatch(argv, commands, prog, description):
    parser = argparse.ArgumentParser(prog=prog, description=description)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, help_text) in commands.items():
        p = sub.add_parser(name, help=help_text, description=help_text,
                           formatter_class=_HelpFormatter)
        p.set_defaults(_module=module)
        if argv[:1] == [name]:
            importlib.import_module(module).add_arguments(p)
    args = parser.parse_args(argv)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except (ValueError, OSError, ImportError) as exc:  # ImportError: a missing optional dependency
        print(f"{prog} {args.command}: error: {exc}", file=sys.stderr)
        return 2
