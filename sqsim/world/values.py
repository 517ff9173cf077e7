"""Value checkers of scene keys.

Each factory returns a function that takes a TOML value and returns the cleaned value or raises
``ValueError(problem)``; ``sqsim.world.scene.parse_scene`` prefixes the problem with the file and key.
"""

from __future__ import annotations

import math

__all__ = ["integer", "number", "choice", "boolean", "nonempty_string", "vector", "interval",
           "nonempty_strings", "optional_path", "waypoint_rows", "catalogue"]


def integer(lo=None):
    def check(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v:
            raise ValueError(f"must be an integer, got {v!r}")
        if lo is not None and v < lo:
            raise ValueError(f"must be >= {lo}, got {v!r}")
        return int(v)
    return check


def number(lo=None, hi=None, lo_open=False, hi_open=False):
    def check(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"must be a finite number, got {v!r}")
        v = float(v)
        if lo is not None and (v < lo or (lo_open and v == lo)):
            raise ValueError(f"must be {'>' if lo_open else '>='} {lo}, got {v!r}")
        if hi is not None and (v > hi or (hi_open and v == hi)):
            raise ValueError(f"must be {'<' if hi_open else '<='} {hi}, got {v!r}")
        return v
    return check


def choice(choices):
    def check(v):
        if v not in choices:
            raise ValueError(f"must be one of {list(choices)}, got {v!r}")
        return v
    return check


def boolean(v):
    if not isinstance(v, bool):
        raise ValueError(f"must be true or false, got {v!r}")
    return v


def nonempty_string(v):
    if not isinstance(v, str) or not v:
        raise ValueError(f"must be a non-empty string, got {v!r}")
    return v


def vector(n, item=number()):
    def check(v):
        if not isinstance(v, (list, tuple)) or len(v) != n:
            raise ValueError(f"must be a list of {n} numbers, got {v!r}")
        return tuple(item(x) for x in v)
    return check


def interval(lo=None, lo_open=False, hi=None):
    pair = vector(2, number(lo, hi, lo_open=lo_open))

    def check(v):
        a, b = pair(v)
        if a > b:
            raise ValueError(f"must be [low, high] with low <= high, got {list(v)!r}")
        return (a, b)
    return check


def nonempty_strings(v):
    if not isinstance(v, (list, tuple)) or not v:
        raise ValueError(f"must be a non-empty list of strings, got {v!r}")
    return tuple(nonempty_string(x) for x in v)


def optional_path(v):
    return None if v in (None, "") else nonempty_string(v)


def waypoint_rows(v):
    from .trajectory import check_waypoint_rows

    return check_waypoint_rows(v)


def catalogue(v):
    from .household import check_catalogue

    return check_catalogue(v)
