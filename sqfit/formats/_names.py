"""Matching a COCO ``file_name`` to the names of another file (pose sources, timestamp lists)."""

from __future__ import annotations

from pathlib import PurePosixPath


def base_name(name):
    """Last component of a path written with ``/`` or ``\\``."""
    return PurePosixPath(str(name).replace("\\", "/")).name


class NameIndex:
    """Find a name among ``names``: the exact name, else its base name if exactly one has it.

    COLMAP and TUM's ``rgb.txt`` store names relative to their folder (``rgb/0001.png``) while a
    COCO file often has the bare ``0001.png``; a base name shared by several entries is ambiguous.
    """

    def __init__(self, names):
        self.names = set(names)
        self.by_base = {}
        for name in self.names:
            self.by_base.setdefault(base_name(name), []).append(name)

    def find(self, name, what="pose"):
        """``(matched name, None)``, or ``(None, why not)`` with ``what`` naming the entries."""
        candidates = [name] if name in self.names else self.by_base.get(base_name(name), [])
        if len(candidates) == 1:
            return candidates[0], None
        if not candidates:
            return None, f"no {what} with this file name or base name"
        plural = what[:-1] + "ies" if what.endswith("y") else what + "s"
        return None, (f"base name matches {len(candidates)} {plural} ({', '.join(sorted(candidates)[:3])}); "
                      "use full names")
