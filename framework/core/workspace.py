"""The workspace box: an axis-aligned box in the robot's base frame (mm) that flange
positions must stay in, for the configuration's plan limits and a robot's own limits."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from spherecal.core.models import Vec3



class WorkspaceBox(BaseModel):
    """Axis-aligned box in the base frame (mm) the flange origin must stay in. A robot
    refuses a move whose target (or start) lies outside before anything is sent; a plan
    whose targets lie outside is refused before the first motion. A robot plugin may
    derive a box with its arm's defaults (the IRB 2400's reach, for example)."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    min_mm: Vec3 = Field(description="lower corner (x, y, z) in base, mm")
    max_mm: Vec3 = Field(description="upper corner (x, y, z) in base, mm")

    @model_validator(mode="after")
    def _ordered(self):
        for axis, lo, hi in zip("xyz", self.min_mm, self.max_mm):
            if not lo < hi:
                raise ValueError(f"min_mm {axis} = {lo} must be below max_mm {axis} = {hi}")
        return self

    def contains(self, point_mm) -> bool:
        """Whether ``point_mm`` (x, y, z in base, mm) lies in the box, faces included."""
        return all(lo <= p <= hi for p, lo, hi in zip(point_mm, self.min_mm, self.max_mm))

    def fraction_outside(self, a, b) -> float:
        """The fraction (0..1) of the straight segment from point ``a`` to point ``b``
        (mm, base) that lies outside the box. A box is convex: 0 when both ends are in it."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        s0, s1 = 0.0, 1.0
        for lo, hi, p, d in zip(self.min_mm, self.max_mm, a, b - a):
            if d == 0.0:
                if not lo <= p <= hi:
                    return 1.0
                continue
            t0, t1 = sorted(((lo - p) / d, (hi - p) / d))
            s0, s1 = max(s0, t0), min(s1, t1)
        return 1.0 if s1 < s0 else 1.0 - (s1 - s0)
