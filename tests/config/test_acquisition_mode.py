"""``[acquisition] mode``: stop_and_go by default (automatic its former name), on_the_fly
with its sweeps held to the speed limit, anything else refused naming the choices."""

import pytest
from pydantic import ValidationError

from spherecal.config import AcquisitionConfig

BASE = {"sphere_centre_mm": (1100.0, 150.0, 400.0), "workspace": {"min_mm": (0, 0, 0), "max_mm": (1, 1, 1)}}


def test_the_default_is_stop_and_go_and_automatic_is_its_former_name():
    assert AcquisitionConfig(**BASE).mode == "stop_and_go"
    assert AcquisitionConfig(**BASE, mode="automatic").mode == "stop_and_go"
    assert AcquisitionConfig(**BASE, mode="on_the_fly").on_the_fly.speeds_mm_s == (50.0, 100.0)


def test_an_on_the_fly_sweep_faster_than_the_limit_is_refused_naming_it():
    with pytest.raises(ValidationError, match=r"on_the_fly.speeds_mm_s: 300.0 mm/s exceeds max_speed_mm_s = 250"):
        AcquisitionConfig(**BASE, mode="on_the_fly", on_the_fly={"speeds_mm_s": (50.0, 300.0)})
    # stop-and-go does not sweep on the fly: the plan's speeds are not its concern
    AcquisitionConfig(**BASE, on_the_fly={"speeds_mm_s": (50.0, 300.0)})


def test_an_unknown_mode_is_refused_naming_the_choices():
    with pytest.raises(ValidationError, match="'stop_and_go', 'on_the_fly' or 'manual'"):
        AcquisitionConfig(**BASE, mode="continuous")
