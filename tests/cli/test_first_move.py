"""The first move, from wherever the arm stands, is checked like any other before
anything moves.

Every other move runs between two planned targets, both inside the workspace box, so its
straight path is too; the first starts where the arm happens to be. The simulated arm
starts at ``robot.simulated.home_joints_deg``."""

import re

import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_DATA, main
from spherecal.config import WorkspaceConfig, load_config
from spherecal.devices.contract import DeviceContext
from spherecal.core.errors import InputError
from spherecal.estimation import calibrate
from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import plugin
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config
from tests.cli.cells import simulated_cell
from spherecal.sim import SweepPlan, simulate_dataset
from spherecal.sim.cell import standard_cell
from reference_sensor import reference_fov

#: The example's first target (station S1), base, mm.
FIRST_TARGET_MM = [1132.0, 163.3, 583.3]
#: Leaning back: the flange at (502.5, 0, 1275.5) mm, behind the workspace (x >= 600).
LEANING_BACK = "[0.0, -30.0, 0.0, 0.0, 90.0, 0.0]"


def with_home(sim_config, joints: str, **replace):
    return sim_config(**{r"^max_speed_mm_s = 250.0$": f"max_speed_mm_s = 250.0\nsimulated.home_joints_deg = {joints}",
                         **replace})


@pytest.mark.parametrize("dry_run", [False, True])
def test_an_arm_outside_the_workspace_is_refused_before_any_motion(sim_config, irb2400_controllers, capsys, dry_run):
    cfg = with_home(sim_config, LEANING_BACK)
    assert main(["calibrate", str(cfg), "--no-report"] + (["--dry-run"] if dry_run else [])) == EXIT_DATA
    err = capsys.readouterr().err
    # x runs from 502.5 to 1132.0 and enters the box at 600: (600 - 502.5) / 629.5 = 15 % of the way
    # the reading carries the cell's pose noise (0.02 mm): 502.5, -0.0, 1275.6
    assert re.search(r"the arm stands at \[502\.5, -?0\.0, 1275\.[56]\] mm, outside acquisition\.workspace "
                     r"\[600\.0, -600\.0, 300\.0\]\.\.\[1600\.0, 800\.0, 1400\.0\]: the straight move to the first "
                     r"target 0 \(station S1\) would run outside it for 15% of the way\. Jog the arm into the workspace",
                     err)

    assert "nothing was moved" in err
    (server,) = irb2400_controllers
    assert server.controller.moves == 0 and "TGT" not in server.controller.requests
    assert not (cfg.parent / "out" / "journal.jsonl").exists()


def test_the_robots_own_workspace_is_checked_for_the_first_move_too(sim_config, irb2400_controllers, capsys):
    """The arm stands (855, 0, 1370) mm: inside acquisition.workspace, above the robot
    section's own box (z <= 1300): its check_move refuses the first move."""
    cfg = with_home(sim_config, "[0.0, 0.0, 0.0, 0.0, 90.0, 0.0]",
                    **{r"^\[acquisition\.workspace\]$": "[robot.workspace]\nmin_mm = [-1600.0, -1600.0, 0.0]\n"
                                                         "max_mm = [1600.0, 1600.0, 1300.0]\n\n[acquisition.workspace]"})
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert re.search(r"the first move, from where the arm stands to target 0 \(station S1\): move_linear: start flange "
                     r"position \[855\.0, 0\.0, 1370\.0\] mm is outside the configured workspace box", err)
    assert "jog the arm into the box first" in err and "nothing was moved" in err
    assert irb2400_controllers[0].controller.moves == 0


@pytest.mark.slow
def test_resume_checks_the_move_to_the_first_target_left(sim_config, irb2400_controllers, capsys):
    """Stopped after five shots, the arm was jogged away: --resume checks the move from
    there to target 5 (the first of station S2), not to target 0."""
    cfg = sim_config(exact_arm=True, **{r"^profiles_per_station = 10$": "profiles_per_station = 5"})
    assert main(["calibrate", str(cfg), "--no-report"]) == 0
    journal = cfg.parent / "out" / "journal.jsonl"
    lines = journal.read_text().splitlines(keepends=True)
    journal.write_text("".join(lines[:6]))  # the header and shots 0-4
    for f in cfg.parent.joinpath("out").iterdir():
        if f.name != "journal.jsonl":
            f.unlink()
    cfg.write_text(cfg.read_text().replace("max_speed_mm_s = 250.0\n",
                                           f"max_speed_mm_s = 250.0\nsimulated.home_joints_deg = {LEANING_BACK}\n", 1))
    assert main(["calibrate", str(cfg), "--no-report", "--resume"]) == EXIT_DATA
    assert "the straight move to the first target 5 (station S2)" in capsys.readouterr().err
    assert irb2400_controllers[-1].controller.moves == 0


def test_the_robot_refuses_a_move_from_outside_its_box_at_move_time_too():
    cell = standard_cell(seed=1, fov=reference_fov())
    cfg = AbbIrb2400Config(timeout_s=0.5, simulated={"transport": "pty"},
                           workspace={"min_mm": [-1600, -1600, 0], "max_mm": [1600, 1600, 1300]})
    robot = plugin.create_robot(cfg, DeviceContext(cell=cell, log=lambda m: None))
    with robot:
        target = Pose.from_xyz_quat_wxyz(FIRST_TARGET_MM, (0.0, 0.0, 1.0, 0.0))
        robot.check_target(target, 100.0)  # the target alone is fine
        for action in (robot.check_move, robot.move_linear):
            with pytest.raises(InputError, match=r"start flange position \[855\.0, 0\.0, 1370\.0\] mm is outside"):
                action(target, 100.0)
        assert robot.simulator.controller.moves == 0


@pytest.mark.parametrize("a, b, outside", [
    ((5, 5, 5), (8, 1, 9), 0.0),  # both ends inside: all of it inside
    ((-5, 5, 5), (5, 5, 5), 0.5),  # enters half-way
    ((-5, 5, 5), (15, 5, 5), 0.5),  # in and out again: the middle half inside
    ((-5, 11, 5), (5, 11, 5), 1.0),  # parallel to x, above the box
    ((-10, -10, 5), (20, 20, 5), 2 / 3),  # the diagonal: inside from 1/3 to 2/3
])
def test_fraction_of_a_straight_path_outside_a_box(a, b, outside):
    box = WorkspaceConfig(min_mm=(0, 0, 0), max_mm=(10, 10, 10))
    assert box.fraction_outside(a, b) == pytest.approx(outside)


@pytest.mark.parametrize("command", ["validate", "scan"])
def test_validate_and_scan_check_their_first_move_too(sim_config, irb2400_controllers, capsys, command):
    cfg = with_home(sim_config, LEANING_BACK)
    out = cfg.parent / "out"
    out.mkdir()
    cell = simulated_cell(load_config(cfg).config)
    dataio.write_result(out / "result.json", calibrate(simulate_dataset(cell, SweepPlan(profiles_per_station=5))))
    assert main([command, str(cfg)] + (["--no-report"] if command == "validate" else [])) == EXIT_DATA
    err = capsys.readouterr().err
    assert "the arm stands at [502.5," in err and "would run outside it for" in err and "nothing was moved" in err
    assert irb2400_controllers[0].controller.moves == 0
