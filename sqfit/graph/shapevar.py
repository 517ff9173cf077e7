"""The landmark's size/shape variable ``S(j)``: how the graph stores ``[ax, ay, az, e1, e2]``.

``plain`` stores the vector itself. ``log`` stores ``z`` with ``a = A_MIN + exp(min(z_a, Z_A_MAX))``
and ``e = E_MIN + (E_MAX - E_MIN) sigmoid(z_e)``: every value of the variable is a valid superquadric
inside the range the silhouette residual is evaluated on (:data:`sqfit.graph.landmark.EVAL_LOWER`,
``EVAL_UPPER``), so a Gauss-Newton step, however long, cannot leave it. With ``plain``, iSAM2's
undamped steps took a landmark's size and shape to ``a_y = -5.3, e2 = -4.4`` in one update on an
evaluation sequence, where the residual is clipped and the bound penalty, zero inside the bounds,
was not seen from the step's start (docs/slam-history.md "Issue 23, eleventh pass").

The factors keep their residuals in ``[a, e]`` (:mod:`sqfit.graph.landmark`,
:mod:`sqfit.graph.floor`) and multiply their size/shape Jacobian columns by ``d[a, e] / dz``
(:meth:`ShapeVariable.shape_and_jacobian`, a diagonal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["KINDS", "ShapeVariable", "PLAIN", "shape_variable"]

#: The kinds of size/shape variable (``GraphOptions.shape_variable``).
KINDS = ("plain", "log")
#: ``log``: the smallest size (m) and the range of the exponents, those of the silhouette residual's
#: evaluation (:data:`sqfit.graph.landmark.EVAL_LOWER`, ``EVAL_UPPER``; not imported here to keep
#: this module below the residuals).
A_MIN, E_MIN, E_MAX = 0.01, 0.05, 2.0
#: ``log``: sizes stop growing at ``A_MIN + exp(Z_A_MAX)`` (1 km; zero derivative beyond), where a
#: Gauss-Newton step along a direction the views do not fix would otherwise overflow the factors.
Z_A_MAX = np.log(1000.0)


@dataclass(frozen=True)
class ShapeVariable:
    """One kind of size/shape variable (module docstring); ``kind`` one of :data:`KINDS`."""

    kind: str = "plain"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"shape variable must be one of {', '.join(KINDS)}, got {self.kind!r}")

    @property
    def plain(self):
        return self.kind == "plain"

    def value(self, shape):
        """The variable of ``shape`` (``(..., 5)`` ``[ax, ay, az, e1, e2]``); with ``log`` sizes
        below :data:`A_MIN` + 1e-9 and exponents outside ``(E_MIN, E_MAX)`` are taken just inside."""
        shape = np.array(shape, dtype=np.float64)
        if self.plain:
            return shape
        z = np.empty_like(shape)
        z[..., :3] = np.log(np.maximum(shape[..., :3] - A_MIN, 1e-9))
        u = np.clip((shape[..., 3:] - E_MIN) / (E_MAX - E_MIN), 1e-9, 1.0 - 1e-9)
        z[..., 3:] = np.log(u) - np.log1p(-u)
        return z

    def shape(self, z):
        """``[ax, ay, az, e1, e2]`` of the variable ``z`` (``(..., 5)``)."""
        return self.shape_and_jacobian(z)[0]

    def shape_and_jacobian(self, z):
        """``(shape, d)``: the size/shape of ``z`` and ``d shape / d z`` (elementwise: the map is
        diagonal), both shaped as ``z``."""
        z = np.asarray(z, dtype=np.float64)
        if self.plain:
            return z.copy(), np.ones_like(z)
        shape, d = np.empty_like(z), np.empty_like(z)
        grow = np.exp(np.minimum(z[..., :3], Z_A_MAX))
        shape[..., :3], d[..., :3] = A_MIN + grow, np.where(z[..., :3] < Z_A_MAX, grow, 0.0)
        u = 0.5 * (1.0 + np.tanh(0.5 * z[..., 3:]))  # the logistic function, without overflow
        shape[..., 3:] = E_MIN + (E_MAX - E_MIN) * u
        d[..., 3:] = (E_MAX - E_MIN) * u * (1.0 - u)
        return shape, d

    def prior_sigmas(self, shape, sigma):
        """Per-entry standard deviations, in units of the variable, of a prior of ``sigma`` (units
        of ``shape``) at ``shape``: equal to first order."""
        d = self.shape_and_jacobian(self.value(shape))[1]
        return float(sigma) / np.maximum(d, 1e-12)

    def scaled(self, z, s):
        """The variable with its sizes scaled by ``s`` (> 0), its shape unchanged."""
        if self.plain:
            out = np.array(z, dtype=np.float64)
            out[..., :3] *= s
            return out
        shape = self.shape(z)
        shape[..., :3] *= s
        return self.value(shape)


#: The ``plain`` variable (the default of the factors).
PLAIN = ShapeVariable("plain")


def shape_variable(options):
    """The :class:`ShapeVariable` of ``options`` (a GraphOptions; its ``shape_variable``)."""
    return ShapeVariable(options.shape_variable)
