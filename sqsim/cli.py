"""Command line of the simulator: ``sqsim COMMAND --help`` explains each command."""

from __future__ import annotations

import sys

from sqfit._cli import dispatch

#: name -> (module with add_arguments/run, one-line help)
COMMANDS = {
    "demo": ("sqsim.demo", "sample a superquadric, project it into three cameras, print a summary"),
}


def main(argv=None):
    return dispatch(argv, COMMANDS, "sqsim", "Render superquadric scenes to instance masks and "
                    "evaluate the sqfit fitter on them. See 'sqsim COMMAND --help'.")


if __name__ == "__main__":
    sys.exit(main())
