"""A refused plan says each distinct reason once, with how many targets (in how many
sweeps or stations) have it and the first few of them; a speed beyond a limit names the
keys that change it; an eye-to-hand sphere centre given in base says so."""

import re

from spherecal.app.plan_checks import EXAMPLES_PER_REASON, mounting_hint
from spherecal.cli import EXIT_DATA, main
from spherecal.config.load import load_config

OTF_EYE_TO_HAND = "sim-on-the-fly-eye-to-hand.toml"
OTF_WORKSPACE = r"^max_mm = \[1700.0, 600.0, 1500.0\]$"
OTF_SPHERE = r"^sphere_centre_mm = \[4.0, -3.0, 150.0\].*$"


def refusal(capsys, cfg) -> list[str]:
    """The refusal's lines (its head first) of ``calibrate CONFIG --yes --dry-run``."""
    assert main(["calibrate", str(cfg), "--yes", "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    return err.split("spherecal: error: ")[1].rstrip("\n").splitlines()


def test_sweeps_outside_the_workspace_are_one_line_with_their_count_and_first_three(sim_config, capsys):
    cfg = sim_config(OTF_EYE_TO_HAND, **{OTF_WORKSPACE: "max_mm = [1700.0, 600.0, 1100.0]"})
    head, *lines = refusal(capsys, cfg)
    assert "the on-the-fly plan breaks the limits; nothing was moved" in head
    assert len(lines) == 1, lines
    m = re.match(r"  (\d+) targets in (\d+) sweeps \((.*)\): the first at \[[-\d., ]+\] mm is outside "
                 r"acquisition\.workspace \[600\.0, -800\.0, 300\.0\]\.\.\[1700\.0, 600\.0, 1100\.0\]$", lines[0])
    assert m, lines[0]
    named = re.findall(r"target \d+ \(station S\d, sweep (\d+)\)", m.group(3))
    # the first target of each of the first three sweeps at fault, in the plan's order
    assert len(named) == EXAMPLES_PER_REASON and named == sorted(set(named), key=int)
    assert m.group(3).endswith(", ...") and int(m.group(1)) > int(m.group(2)) > EXAMPLES_PER_REASON


def test_a_speed_beyond_the_robots_limit_is_one_line_naming_the_keys_to_change(sim_config, capsys):
    cfg = sim_config(OTF_EYE_TO_HAND, **{r"^max_speed_mm_s = 250.0$": "max_speed_mm_s = 80.0"})
    head, *lines = refusal(capsys, cfg)
    assert "breaks the robot's limits" in head
    speed = [x for x in lines if "exceeds the configured max_speed_mm_s = 80.0" in x]
    # the plan's targets at 100 mm/s, and the first move from where the arm stands to one
    assert len(speed) == 2 and speed[1].startswith("  the first move, from where the arm stands"), lines
    grouped = speed[0]
    assert re.match(r"  \d+ targets in \d+ sweeps \(target 0 \(station S1, sweep 0\), ", grouped), grouped
    assert grouped.endswith("raise [robot] max_speed_mm_s to at least 100 mm/s, or lower the speed set in "
                            "[acquisition] approach_speed_mm_s and [acquisition.on_the_fly] speeds_mm_s")


def test_a_speed_beyond_the_limit_stop_and_go_names_its_keys(sim_config, capsys):
    cfg = sim_config(**{r"^max_speed_mm_s = 250.0$": "max_speed_mm_s = 50.0"})
    _, *lines = refusal(capsys, cfg)
    grouped = [x for x in lines if "max_speed_mm_s = 50.0" in x and "targets in" in x]
    assert len(grouped) == 1 and re.match(r"  \d+ targets in \d+ stations \(target 0 \(station S1\)", grouped[0])
    assert "raise [robot] max_speed_mm_s to at least 100 mm/s, or lower the speed set in " \
           "[acquisition] approach_speed_mm_s" in grouped[0]


def test_an_eye_to_hand_sphere_centre_in_base_is_named_as_such(sim_config, capsys):
    # where the sphere is in base, in front of the sensor, given as its place on the flange
    cfg = sim_config(OTF_EYE_TO_HAND, **{OTF_SPHERE: "sphere_centre_mm = [1250.0, -200.0, 700.0]"})
    head, *lines = refusal(capsys, cfg)
    assert "acquisition.sphere_centre_mm = [1250, -200, 700] puts the sphere 1.45 m from the flange: for " \
           "mounting = \"eye_to_hand\" it is the sphere's centre in the flange frame" in head
    assert "looks like a position in base" in head and "is the mounting right?" not in head
    assert len(lines) == 1 and lines[0].startswith("  232 targets in 32 sweeps (")


def test_a_nearer_sphere_centre_is_named_when_no_target_fits(sim_config, capsys):
    """472 mm from the flange is a long stylus, or a position in base: said when no target
    of the plan passes, not otherwise."""
    small_box = {r"^max_mm = \[1700.0, 600.0, 1500.0\]$": "max_mm = [700.0, 600.0, 1500.0]"}
    cfg = sim_config("sim-eye-to-hand.toml", **small_box,
                     **{r"^sphere_centre_mm = .*$": "sphere_centre_mm = [400.0, 0.0, 250.0]"})
    loaded = load_config(cfg).config
    assert mounting_hint(loaded.mounting, loaded.nominal_transform, loaded.acquisition) is None
    head, *lines = refusal(capsys, cfg)
    assert "puts the sphere 0.47 m from the flange" in head and "looks like a position in base" in head
    # the example's stylus, 150 mm: a workspace that fits nothing says nothing of the frame
    cfg = sim_config("sim-eye-to-hand.toml", **small_box)
    head, *lines = refusal(capsys, cfg)
    assert "flange" not in head and "mounting" not in head


def test_reasons_differing_in_measures_are_one_and_in_whole_numbers_are_not():
    import numpy as np

    from spherecal.app.plan_checks import grouped_problems
    from spherecal.core.models import Pose
    from spherecal.motion.acquisition import PlanProblem, Target

    def problem(k, station, reason):
        return PlanProblem(Target(k, station, Pose.from_rt(np.eye(3), [k, 0.0, 0.0]), False, 20.0), reason)

    lines = grouped_problems([problem(0, "S1", "joint 3 = 71.25 deg is outside its range -60 .. 65"),
                              problem(1, "S1", "joint 5 = 131.5 deg is outside its range -120 .. 120"),
                              problem(2, "S2", "joint 3 = 80.5 deg is outside its range -60 .. 65")])
    assert lines == ["2 targets in 2 stations (target 0 (station S1), target 2 (station S2)): the first: joint 3 = "
                     "71.25 deg is outside its range -60 .. 65",
                     "target 1 (station S1): joint 5 = 131.5 deg is outside its range -120 .. 120"]
