import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_examples_run(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "the README should show how to call sqfit"
    for code in blocks:
        exec(compile(code, str(README), "exec"), {})
    assert "ok" in capsys.readouterr().out


def test_readme_first_screen_has_the_two_commands():
    first_screen = README.read_text().splitlines()[:25]
    commands = [line for line in first_screen if line.startswith("./run.sh ")]
    assert [c.split()[1] for c in commands] == ["main", "test"]
    ci = (README.parent / ".ci" / "run").read_text()
    assert "./run.sh test" in ci
