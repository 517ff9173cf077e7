"""Files of a run directory: atomic writes (text, figures), the records of an earlier run, and the run
configuration that makes a re-run resume."""

from __future__ import annotations

import json
import os
import sys

from .provenance import library_versions

__all__ = ["atomic_write_text", "atomic_figure", "read_records", "check_or_write_run_config"]


def atomic_write_text(path, text):
    """Write ``text`` to ``path`` through a temporary file and a rename: readers never see half a file."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def check_or_write_run_config(path, config, scene, what, differs):
    """Write a run's configuration, or check that the run already in its directory is the same one.

    The same: the same ``config["format"]``, the same scene apart from its ``[experiment]`` section
    (read back through ``sqsim.world.scene.parse_scene``, so keys added to the scene format since take their
    defaults), the same seed, and the same value of every other key of ``config`` except ``version``.

    The file also lists under ``installs`` each install that ran the run
    (:func:`sqsim.data.provenance.library_versions`), in order: one, unless the run was resumed under other
    library versions, which is allowed with a warning on stderr naming what changed (the records added then come
    from another install, whose fits can differ at rounding level).

    Parameters
    ----------
    path : pathlib.Path
        E.g. ``DIR/experiment.json``.
    config : dict
        JSON-serialisable, with ``format`` and ``scene`` (``Scene.to_dict()``).
    scene : sqsim.world.scene.Scene
    what, differs : str
        For the error: ``"experiment"``, ``"scene or seed"``.

    Raises
    ------
    ValueError
        The file is not JSON, or holds a different run.

    Returns
    -------
    installs : list of dict or None
        The ``installs`` written: the library versions of each install that ran the run (None for one of
        a run directory written before they were recorded).
    """
    installs = [library_versions()]
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path} is not valid JSON ({exc}); remove it or use another --output") from None
        from ..world.scene import parse_scene

        try:
            old_scene = parse_scene(old.get("scene", {}), source=str(path)).to_dict()
        except ValueError:
            old_scene = None

        def fixed(s):
            return {k: v for k, v in s.items() if k != "experiment"}

        same = (old.get("format") == config["format"] and old_scene is not None
                and fixed(old_scene) == fixed(config["scene"])
                and old_scene["experiment"]["seed"] == scene.experiment.seed
                and all(old.get(k) == v for k, v in config.items() if k not in ("format", "version", "scene")))
        if not same:
            raise ValueError(f"{path.parent} holds a different {what} ({differs} differ); "
                             "use another --output directory or delete it")
        earlier = old.get("installs")
        if not isinstance(earlier, list) or not earlier:
            earlier = [None]  # an install of before the versions were recorded
        if installs[0] not in earlier:
            last = earlier[-1] or {}
            changed = ", ".join(f"{k} {last.get(k, '?')} -> {v}" for k, v in installs[0].items() if last.get(k, "?") != v)
            print(f"warning: {path.parent} was run with other library versions ({changed}); the records added "
                  f"now come from another install (each listed under 'installs' in {path.name})", file=sys.stderr)
            installs = earlier + installs
        else:
            installs = earlier
    atomic_write_text(path, json.dumps({**config, "installs": installs}, indent=1, sort_keys=True))
    return installs


def read_records(jsonl):
    """Records of an earlier run; a last line cut short by a kill is dropped (and truncated)."""
    if not jsonl.exists():
        return []
    raw = jsonl.read_bytes()
    complete = raw[: raw.rfind(b"\n") + 1]
    if len(complete) != len(raw):
        with open(jsonl, "r+b") as fh:
            fh.truncate(len(complete))
    records = []
    for n, line in enumerate(complete.decode().splitlines(), 1):
        if line.strip():
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise ValueError(f"{jsonl}:{n} is not valid JSON ({exc})") from None
    return records


def atomic_figure(draw, path, *args):
    """Call ``draw(*args, tmp)`` to save a figure to a temporary file, then rename it to ``path``."""
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    draw(*args, tmp)
    os.replace(tmp, path)
