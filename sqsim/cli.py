"""Command line of the simulator: ``sqsim COMMAND --help`` explains each command."""

from __future__ import annotations

import os
import sys

# Our matrices are small: BLAS threads only add overhead and make single-process timings noisy.
# Set before numpy is first imported (importing sqfit imports numpy).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from sqfit.cli.dispatch import dispatch  # noqa: E402

#: name -> (module with add_arguments/run, one-line help)
COMMANDS = {
    "demo": ("sqsim.demo", "sample a superquadric, project it into three cameras, print a summary"),
    "experiment": ("sqsim.runs.experiment", "run the permutation experiment: simulate, fit chains, evaluate, report"),
    "sweep": ("sqsim.runs.sweep", "run the experiment over a grid of scene values; degradation curves"),
    "generate": ("sqsim.runs.generate", "render a scene's trials to a mask dataset (resumable, COCO annotations)"),
    "sequence": ("sqsim.reports.sequence", "simulate one image sequence: visibility, odometry drift, top-down figure"),
    "slam": ("sqsim.runs.slam", "run sequences through the factor graph and its baselines: trajectories, objects, ATE/RPE, IoU"),
}


def main(argv=None):
    return dispatch(argv, COMMANDS, "sqsim", "Render superquadric scenes to instance masks and "
                    "evaluate the sqfit fitter on them. See 'sqsim COMMAND --help'.")


if __name__ == "__main__":
    sys.exit(main())
