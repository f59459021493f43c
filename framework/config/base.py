"""What every configuration section shares: the frozen, strict base model, and the
constants that code outside the configuration reads (the ``base_dir`` validation-context
key plugins resolve relative paths with, the report's default point distance). Imports
only pydantic."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

#: chi^2 with 3 degrees of freedom exceeded with probability 1e-4.
CHI2_3DOF_1E4 = 21.108
#: The distance from the sensor (mm, along its line of sight) of the point whose
#: uncertainty the report gives when ``[report] point_distance_mm`` is not set.
POINT_DISTANCE_MM = 100.0
#: The key of the pydantic validation context that holds the folder of the configuration
#: file: a plugin section's validator resolves its relative paths against it.
BASE_DIR_CONTEXT_KEY = "base_dir"


class Section(BaseModel):
    """A configuration section: frozen, unknown keys refused, its schema built on first use."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")
