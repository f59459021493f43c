"""A plan that breaks the limits because the mounting is the wrong one names that cause
once, from the configuration's geometry, before the list of targets."""

import pytest

from spherecal.app.plan_checks import mounting_hint
from spherecal.cli import EXIT_DATA, main
from spherecal.config.load import load_config
from conftest import EXAMPLES


def test_an_eye_in_hand_cell_configured_eye_to_hand_names_the_mounting(sim_config, capsys):
    cfg = sim_config(**{r'^mounting = "eye_in_hand"': 'mounting = "eye_to_hand"'})
    assert main(["calibrate", str(cfg), "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    head, *targets = err.split("spherecal: error: ")[1].splitlines()
    # the base-frame sphere [1100, 150, 400] read in the flange frame: 1.18 m from the flange
    assert 'mounting = "eye_to_hand" puts the sphere 1.18 m from the flange' in head
    assert "the sensor 173 mm from the robot's base origin" in head and "is the mounting right?" in head
    assert targets and all("outside acquisition.workspace" in t for t in targets)
    assert err.count("is the mounting right?") == 1


def test_an_eye_to_hand_cell_configured_eye_in_hand_names_the_mounting(sim_config, capsys):
    cfg = sim_config("sim-eye-to-hand.toml", **{r'^mounting = "eye_to_hand"': 'mounting = "eye_in_hand"'})
    assert main(["calibrate", str(cfg), "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert 'mounting = "eye_in_hand" puts the sensor 1.56 m from the flange' in err
    assert "the sphere 150 mm from the robot's base origin" in err


def test_a_workspace_too_small_names_no_mounting(sim_config, capsys):
    cfg = sim_config(**{r"^max_mm = \[1600.0, 800.0, 1400.0\]": "max_mm = [1600.0, 800.0, 580.0]"})
    assert main(["calibrate", str(cfg), "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "outside acquisition.workspace" in err and "mounting" not in err


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_the_examples_look_like_their_mounting(name):
    cfg = load_config(EXAMPLES / name).config
    assert mounting_hint(cfg.mounting, cfg.nominal_transform, cfg.acquisition) is None
