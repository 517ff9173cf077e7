"""scripts/slab_thickness.py: the thickness the default fits a slab, and which factor each score of the masks picks."""

import pytest

from _helpers import SCRIPTS, script_module

SCRIPT = SCRIPTS / "slab_thickness.py"


@pytest.mark.parametrize("argv", [["--trials", "0"], ["--factors", "0.5", "0"]])
def test_the_script_refuses_no_trials_and_factors_that_are_not_positive(argv):
    with pytest.raises(SystemExit):
        script_module(SCRIPT).main(argv)


def test_a_tables_row_undoes_the_step_and_scores_each_factor(capsys):
    """Table 3 of seed 0 (tests/test_weighted_overlap.py): the step thinned it by 0.65; from the fit before it,
    the full contours pick no thinner top than the opened masks, and the weighted overlap picks the step's factor."""
    module = script_module(SCRIPT)
    module.main(["--kinds", "table", "--trials", "4", "--factors", "0.65", "0.8", "1.0", "1.2"])
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("table   3:"))
    assert "(step x0.65)" in row, row
    assert "weighted x0.65 ->" in row and "full x1.00 ->" in row, row
    assert "table medians over" in out
