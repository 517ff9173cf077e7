"""Which install made a run: library versions in run directories, and the pinned set ./run.sh installs."""

import json
import re
import tomllib
from importlib import metadata
from pathlib import Path

import numpy as np
from packaging.requirements import Requirement

from sqsim.data import provenance
from sqsim.data.files import check_or_write_run_config
from sqsim.data.provenance import LIBRARIES, library_versions
from sqsim.world.scene import parse_scene

ROOT = Path(__file__).resolve().parents[1]


def test_library_versions_name_python_and_each_library():
    versions = library_versions()
    assert list(versions) == ["python", *LIBRARIES]
    assert versions["numpy"] == np.__version__
    assert versions["scipy"] == metadata.version("scipy")
    assert re.fullmatch(r"3\.\d+\.\d+.*", versions["python"])


def test_a_library_that_is_not_installed_is_none(monkeypatch):
    monkeypatch.setattr(provenance, "LIBRARIES", ("numpy", "no-such-distribution-sqkit"))
    assert library_versions()["no-such-distribution-sqkit"] is None


def _scene():
    return parse_scene({"experiment": {"name": "p", "seed": 1, "trials": 2}}, source="<test>")


def _config(scene):
    return {"format": "sqkit-experiment", "version": 1, "scene": scene.to_dict()}


def test_a_run_records_its_install_and_a_resume_under_other_versions_is_flagged(tmp_path, capsys):
    scene, path = _scene(), tmp_path / "experiment.json"
    assert check_or_write_run_config(path, _config(scene), scene, "experiment", "scene") == [library_versions()]
    assert json.loads(path.read_text())["installs"] == [library_versions()]
    # The same install again: nothing added, no warning.
    assert check_or_write_run_config(path, _config(scene), scene, "experiment", "scene") == [library_versions()]
    assert capsys.readouterr().err == ""
    # Started under another numpy: resumed with a warning naming it, both installs listed.
    old = {**library_versions(), "numpy": "1.26.0"}
    path.write_text(json.dumps({**json.loads(path.read_text()), "installs": [old]}))
    installs = check_or_write_run_config(path, _config(scene), scene, "experiment", "scene")
    assert installs == [old, library_versions()] == json.loads(path.read_text())["installs"]
    err = capsys.readouterr().err
    assert f"numpy 1.26.0 -> {np.__version__}" in err and "scipy" not in err and str(tmp_path) in err


def test_a_run_written_before_versions_were_recorded_lists_an_unknown_install(tmp_path, capsys):
    scene, path = _scene(), tmp_path / "experiment.json"
    path.write_text(json.dumps(_config(scene)))
    assert check_or_write_run_config(path, _config(scene), scene, "experiment", "scene") == [None, library_versions()]
    assert "other library versions" in capsys.readouterr().err


def _pins():
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not pinned with =="
            pins[re.sub(r"[-_.]+", "-", name).lower()] = version
    return pins


def test_constraints_pin_every_dependency_within_pyproject_ranges():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    run_sh = (ROOT / "run.sh").read_text()
    extras = re.search(r'-e "\.\[([a-z,]+)\]"', run_sh).group(1).split(",")
    assert set(extras) == set(project["optional-dependencies"])  # run.sh installs every extra
    pins = _pins()
    for text in project["dependencies"] + [r for e in extras for r in project["optional-dependencies"][e]]:
        req = Requirement(text)
        name = re.sub(r"[-_.]+", "-", req.name).lower()
        assert name in pins, f"{req.name} is not pinned in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), f"{req.name}=={pins[name]} is outside {req}"
    assert '-c "$pins"' in run_sh and 'CONSTRAINTS="${SQKIT_CONSTRAINTS-constraints.txt}"' in run_sh
    assert "# for-python: 3.11\n" in (ROOT / "constraints.txt").read_text()  # run.sh pins only on that Python
