"""Named constants with their units, in one place."""

#: Parameter vector layout (paper, section III-B): ``[ax, ay, az, e1, e2, px, py, pz, rx, ry, rz]``.
PARAMETER_NAMES = ("ax", "ay", "az", "e1", "e2", "px", "py", "pz", "rx", "ry", "rz")
N_PARAMS = 11
SIZE = slice(0, 3)  #: half-axis lengths a, metres
SHAPE = slice(3, 5)  #: shape exponents e1 (latitude), e2 (longitude), unitless
POSITION = slice(5, 8)  #: centre in the world frame, metres
ROTATION = slice(8, 11)  #: Euler angles, radians (convention in ``sqfit.geometry.superquadric``)

#: Shape exponents a ``Superquadric`` accepts at all: convex shapes only (e <= 2); below the
#: lower end, powers of 2/e overflow float64 even in log space handling of the mesh.
SHAPE_DOMAIN = (0.01, 2.0)

#: Bounds of the paper's soft constraint (eq. 4 and 7) used by the optimiser's penalty.
SHAPE_BOUNDS = (0.1, 1.9)
SIZE_MIN = 0.1  #: metres
#: Shape bounds of the penalty of the silhouette stages (3G, 3H; beyond the paper): boxes and
#: cylinders need flatter ends than ``e = 0.1``, whose rounded edges inflate the fit by ~3 %
#: (README, "Beyond the paper"). Nearly every box fit ends at the lower bound, and its edges are
#: still rounded there: 0.015 instead of 0.03 took boxes from 0.971 / 0.970 / 0.970 to 0.981 / 0.982
#: / 0.983 median IoU (30 trials, seeds 0 / 1 / 2, default chain, whose axis screen keeps 0.03:
#: ``sqfit.fitting.axis_screen.SCREEN_SHAPE_MIN``; README "Real masks"). The penalty holds fits at
#: the bound (none below 0.01499 there), above ``SHAPE_DOMAIN[0]``. 3H's plain run on clean masks
#: has its own, lower one: ``sqfit.fitting.plain_run.PLAIN_SHAPE_MIN``.
SILHOUETTE_SHAPE_BOUNDS = (0.015, 1.9)

#: Penalty weights c_p of eq. 7 (paper, Table I).
PENALTY_RIOU = 1.0
PENALTY_ANALYTIC = 100.0

#: Default number of samples N per observation (paper, Table I).
DEFAULT_SAMPLES = 100

#: Views of one object a fit needs at least (one view fixes no depth); fewer is ``too_few_views``.
MIN_VIEWS = 2

#: A fit whose R-IOU-M (its silhouettes against the visible part of the masks) is below this gets
#: a warning in ``FitResult.warnings``: its silhouettes barely overlap the masks, so the superquadric
#: is very likely wrong. Good fits score 0.75-0.95 on clean and noisy masks (README, "Beyond the
#: paper"); stage 3H re-fits such a result once (``sqfit.fitting.axis_screen.RESCUE_R_IOU_M``).
POOR_FIT_R_IOU_M = 0.5
