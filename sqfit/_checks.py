"""Input coercion and validation shared by every public function.

Each helper coerces first, then checks, and raises a ``ValueError`` whose message names the
argument and what was expected, so a bad input never surfaces as a traceback deep in numpy.
"""

from __future__ import annotations

import numpy as np


def check_shape(x, shape, name, dtype=np.float64, finite=True):
    """Coerce ``x`` to an array and check its shape.

    Parameters
    ----------
    x : array_like
        Value to check.
    shape : tuple of (int or None)
        Expected shape; ``None`` matches any length along that axis.
    name : str
        Argument name used in error messages.
    dtype : numpy dtype, optional
        Target dtype (default float64).
    finite : bool, optional
        Also require every value to be finite (no NaN or inf).

    Returns
    -------
    array : ndarray
        ``x`` as an array of ``dtype`` with the checked shape.
    """
    try:
        arr = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric with shape {_fmt(shape)}: {exc}") from None
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        raise ValueError(f"{name} must have shape {_fmt(shape)}, got {arr.shape}")
    if finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or inf values")
    return arr


def check_number(value, name, lo=None, lo_open=False):
    """Return ``value`` as a float, raising ``ValueError`` unless it is a finite number ``>= lo``
    (``> lo`` with ``lo_open``; no bound when ``lo`` is None)."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number, got {value!r}") from None
    if not np.isfinite(value) or (lo is not None and (value < lo or (lo_open and value == lo))):
        bound = "" if lo is None else f" {'>' if lo_open else '>='} {lo}"
        raise ValueError(f"{name} must be a finite number{bound}, got {value}")
    return value


def check_positive(value, name):
    """Return ``value`` as a float, raising unless it is finite and > 0."""
    return check_number(value, name, 0, lo_open=True)


def check_choice(value, choices, name):
    """Return ``value`` unchanged, raising unless it is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {sorted(choices)}, got {value!r}")
    return value


def check_fields(obj, integers=None, positive=(), nonnegative=()):
    """Check numeric fields of an options object; the first bad one raises ``ValueError`` naming it.

    Parameters
    ----------
    obj : object
        An options dataclass (its fields are read with ``getattr``).
    integers : dict, optional
        ``field name -> lowest allowed integer``.
    positive, nonnegative : sequence of str
        Fields that must be finite numbers > 0, resp. >= 0.
    """
    for name, lo in (integers or {}).items():
        v = getattr(obj, name)
        if int(v) != v or v < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {v}")
    for names, ok, bound in ((positive, np.greater, "> 0"), (nonnegative, np.greater_equal, ">= 0")):
        for name in names:
            v = getattr(obj, name)
            if not (np.isfinite(v) and ok(v, 0)):
                raise ValueError(f"{name} must be a finite number {bound}, got {v}")


def _fmt(shape):
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def coerce_options(cls, options, what):
    """``None`` -> ``cls()``, a dict -> ``cls(**options)``, an instance passes through.

    ``cls`` is an options dataclass; an unknown dict key raises ``ValueError`` naming it and the
    valid ones, anything else ``TypeError``. ``what`` names the options in messages ("fit").
    """
    if options is None:
        return cls()
    if isinstance(options, cls):
        return options
    if isinstance(options, dict):
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"unknown {what} option(s) {unknown}; valid options: {sorted(known)}")
        return cls(**options)
    raise TypeError(f"options must be None, a dict or a {cls.__name__}, got {type(options).__name__}")


class Options:
    """Base of the options dataclasses: :meth:`coerce` turns what a caller passes into options.

    A subclass sets ``WHAT``, the name of its options in messages (``"fit"``, ``"graph"``).
    """

    WHAT = "options"

    @classmethod
    def coerce(cls, options):
        """``None`` -> defaults, a dict -> options (unknown keys raise ValueError naming them)."""
        return coerce_options(cls, options, cls.WHAT)
