"""Before the first motion of a real robot: the plan summary and a typed 'yes', or
--yes. Simulated cells move nothing real and ask nothing (the other tests)."""

import builtins
import re
from pathlib import Path

import pytest

from spherecal.cli import EXIT_DEVICE, EXIT_USAGE, main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def hardware_config(tmp_path):
    text = (EXAMPLES / "irb2400-nxsensor-eye-in-hand.toml").read_text()
    text = re.sub(r"(?m)^output_dir = .*$", 'output_dir = "out"', text)
    text = re.sub(r'(?m)^port = .*$', f'port = "{tmp_path / "no-such-serial-port"}"', text)
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def test_without_input_nothing_is_opened_and_yes_is_named(hardware_config, capsys):
    # under pytest, standard input cannot be read: as in a script without a terminal
    assert main(["calibrate", str(hardware_config)]) == EXIT_USAGE
    cap = capsys.readouterr()
    assert "about to move the real robot" in cap.err and "--yes" in cap.err and "nothing was moved" in cap.err
    assert not (hardware_config.parent / "out").exists()


@pytest.mark.parametrize("answer", ["no", "", "y", "YES please"])
def test_anything_but_yes_stops(hardware_config, capsys, monkeypatch, answer):
    monkeypatch.setattr(builtins, "input", lambda prompt="": answer)
    assert main(["calibrate", str(hardware_config)]) == EXIT_USAGE
    assert "not confirmed" in capsys.readouterr().err
    assert not (hardware_config.parent / "out").exists()


@pytest.mark.parametrize("how", ["typed", "--yes"])
def test_a_confirmed_run_goes_on_to_the_devices(hardware_config, capsys, monkeypatch, how):
    asked = []
    monkeypatch.setattr(builtins, "input", lambda prompt="": asked.append(prompt) or "yes")
    argv = ["calibrate", str(hardware_config)] + (["--yes"] if how == "--yes" else [])
    # past the confirmation the robot's (missing) serial port is opened: a device error
    assert main(argv) == EXIT_DEVICE
    assert "no-such-serial-port" in capsys.readouterr().err
    assert bool(asked) == (how == "typed")


@pytest.mark.slow
def test_a_kinematic_calibration_shows_its_identification_before_the_motion(hardware_config, capsys, monkeypatch):
    """identify_kinematics on real hardware: the planner's stations and what they identify
    are in the motion's summary the operator confirms."""
    text = hardware_config.read_text().replace("[calibration]\n", "[calibration]\nidentify_kinematics = true\n", 1)
    hardware_config.write_text(text)
    monkeypatch.setattr(builtins, "input", lambda prompt="": "no")
    assert main(["calibrate", str(hardware_config)]) == EXIT_USAGE
    err = " ".join(capsys.readouterr().err.split())
    confirm = err[err.index("calibrate is about to move the real robot"):]
    assert re.search(r"about to move the real robot: \d+ shots in 20 stations \(plan above\), at most [\d.]+ mm/s; "
                     r"kinematic identification: the plan \(20 stations\) identifies 18 of 36 geometric parameters "
                     r"\(per joint: 0, 4, 4, 4, 4, 2\), condition number \d+", confirm), confirm
    assert "not confirmed" in err and not (hardware_config.parent / "out").exists()


def test_quiet_still_shows_what_yes_would_confirm(hardware_config, capsys, monkeypatch):
    monkeypatch.setattr(builtins, "input", lambda prompt="": "no")
    assert main(["calibrate", str(hardware_config), "-q"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert re.search(r"calibrate is about to move the real robot: \d+ shots in \d+ stations", err)
    assert "plan: " not in err  # the rest of the progress stays quiet
