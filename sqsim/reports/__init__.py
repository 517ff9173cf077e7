"""Reports: tables and figures of runs, from their records (no fitting here).

Above :mod:`sqsim.data`, below :mod:`sqsim.runs`, which calls them.

- :mod:`.experiment` — summary statistics, Markdown/LaTeX tables, violin and example figures;
- :mod:`.sequence` — ``sqsim sequence``: one simulated sequence, its drift and a top-down figure;
- :mod:`.slam` — summaries, tables and top-down figures of ``sqsim slam`` runs.
"""
