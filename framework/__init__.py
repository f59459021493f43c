"""spherecal: hand-eye calibration of a laser line sensor with a reference sphere.

Conventions (frames, transform direction, units, quaternion order) are stated once in
``docs/conventions.md``; every module follows them.
"""

__version__ = "0.1.0"

from spherecal import _moved

_moved.install()
