"""Example spherecal plugins.

- :mod:`.arm`: robot type ``example_arm``, a six-axis arm whose controller speaks XA/1,
  a TCP protocol of its own (:mod:`.xa_protocol`); its geometry in :mod:`.arm_kinematics`,
  its simulated controller on the simulated cell in :mod:`.arm_sim`.
- :mod:`.profiler`: sensor type ``example_profiler``, which reads profiles from the
  simulated cell.

Both are registered through the ``"spherecal"`` entry-point group (see pyproject.toml).
"""

__version__ = "0.1.0"
