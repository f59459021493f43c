"""Example spherecal plugins (simulation only).

- :mod:`.cartesian`: robot type ``example_cartesian``, a Cartesian robot with a wrist
  that puts the simulated cell's flange exactly where it is told.
- :mod:`.profiler`: sensor type ``example_profiler``, which reads profiles from the
  simulated cell.

Both are registered through the ``"spherecal"`` entry-point group (see pyproject.toml).
"""

__version__ = "0.1.0"
