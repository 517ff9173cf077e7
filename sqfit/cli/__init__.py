"""Command line of the fitter: ``sqfit COMMAND --help`` explains each command.

The top layer of sqfit: :mod:`.dispatch` (the sub-command dispatcher ``sqsim`` shares) and one
module per command (:mod:`.fit`).
"""

from __future__ import annotations

import sys

from .dispatch import dispatch

#: name -> (module with add_arguments/run, one-line help)
COMMANDS = {
    "fit": ("sqfit.cli.fit", "fit every object of a dataset (sqsim generate format), or of a COCO file with "
            "COLMAP, JSON or TUM poses (--coco, --poses), with a chain of stages"),
}


def main(argv=None):
    return dispatch(argv, COMMANDS, "sqfit", "Fit superquadrics to multi-view instance masks. "
                    "See 'sqfit COMMAND --help'.")


if __name__ == "__main__":
    sys.exit(main())
