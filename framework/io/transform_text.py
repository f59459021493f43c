"""A transform typed as text, ``x,y,z,qw,qx,qy,qz``: translation in mm and a unit
quaternion, w first (the project's order, docs/conventions.md). The command line takes
one this way (``solve --nominal``, ``compare`` and ``validate --transform``), and so do
the text files ``compare`` reads."""

from __future__ import annotations

import math

from spherecal.core.errors import ConfigError
from spherecal.core.models import Pose

#: What the text holds, for messages.
XYZ_QUAT_USAGE = "x,y,z,qw,qx,qy,qz (mm and a unit quaternion, w first)"


def parse_xyz_quat(text: str, what: str = "--transform") -> Pose:
    """``x,y,z,qw,qx,qy,qz``: seven finite numbers (mm) and a unit quaternion (w first);
    :class:`ConfigError` naming ``what`` and the value at fault otherwise."""
    usage = f"{what} takes {XYZ_QUAT_USAGE}"
    parts = _parts(text)
    if len(parts) != 7:
        raise ConfigError(f"{usage}; got {len(parts)} value(s) in {text!r:.80}")
    values = []
    for i, part in enumerate(parts):
        try:
            v = float(part)
        except ValueError:
            raise ConfigError(f"{usage}; value {i + 1} is {part.strip()!r:.40}, not a number") from None
        if not math.isfinite(v) or abs(v) > 1e6:
            raise ConfigError(f"{usage}; value {i + 1} is {part.strip()!r:.40}: a finite number of at most 1e6 is "
                              "needed")
        values.append(v)
    n = math.sqrt(sum(c * c for c in values[3:]))
    if abs(n - 1.0) > 1e-3:
        raise ConfigError(f"{usage}; the quaternion {values[3:]} has norm {n:.6f}, not 1")
    return Pose.from_xyz_quat_wxyz(values[:3], values[3:])


def looks_like_numbers(text: str) -> bool:
    """True when ``text`` is a list of numbers (a transform given as numbers, not as a
    file or a controller's frame)."""
    try:
        [float(p) for p in _parts(text)]
    except ValueError:
        return False
    return True


def _parts(text: str) -> list[str]:
    """The comma-separated values of ``x,y,z,...`` (brackets around them allowed)."""
    return text.replace(";", ",").strip().strip("[]()").split(",")
