"""JSON files read with errors that name the file: the one reader every JSON format here shares."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["read_json"]


def read_json(path, what="file"):
    """The content of a JSON file.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file is, for the message of a missing file (``"COCO file"``, ``"pose file"``).

    Raises
    ------
    OSError
        ``"<what> not found: <path>"``.
    ValueError
        ``"<path> is not valid JSON: ..."`` (malformed JSON or not UTF-8).
    """
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise OSError(f"{what} not found: {path}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
