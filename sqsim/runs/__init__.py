"""Runs: the commands that simulate, fit and score many trials, resumably and in parallel.

The top layer of sqsim.

- :mod:`.parallel` — bounded, resumable maps over processes or a Dask cluster;
- :mod:`.generate` — ``sqsim generate``: datasets;
- :mod:`.experiment` — ``sqsim experiment``: the permutation experiment;
- :mod:`.sweep` — ``sqsim sweep``: experiments over a grid of scene values;
- :mod:`.slam` — ``sqsim slam``: sequences through the factor graph and its baselines.
"""
