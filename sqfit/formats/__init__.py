"""Readers and writers of the field's exchange formats, one module per format.

- :mod:`sqfit.formats.tum` — TUM RGB-D trajectories (``t tx ty tz qx qy qz qw``, camera -> world).

Modules here import only numpy/scipy at top level; an optional library a format needs is imported
inside the function that uses it.
"""
