"""simulate, solve, plugins, --help, the manual mode and the hardware example."""

import subprocess
import sys

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.motion.acquisition import acquire_manual, check_targets, plan_targets
from spherecal.cli import EXIT_DATA, EXIT_OK, build_parser, main
from spherecal.config import AcquisitionConfig, WorkspaceConfig, load_config
from spherecal.devices.contract import DeviceContext
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.sim import plan_stations, standard_cell

from pathlib import Path
from reference_sensor import reference_fov

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_simulate_then_solve_recovers_the_truth(tmp_path, capsys):
    ds_path = tmp_path / "sim.jsonl"
    assert main(["simulate", str(ds_path), "--mounting", "eye_to_hand", "--seed", "4", "--profiles", "8"]) == EXIT_OK
    ds = dataio.read_dataset(ds_path)
    assert ds.mounting == "eye_to_hand" and len(ds.observations) == 32
    assert main(["simulate", str(ds_path)]) == EXIT_DATA  # never overwrites without --force
    out = tmp_path / "res"
    assert main(["solve", str(ds_path), "--out", str(out), "--no-report"]) == EXIT_OK
    printed = capsys.readouterr().out
    assert "base_from_sensor" in printed and "simulated truth: error" in printed
    result = dataio.read_result(out / "result.json")
    true = Pose.model_validate(ds.provenance["true_transform"])
    assert geo.rotation_angle_deg(true.rotation_matrix, result.transform.rotation_matrix) < 5 * np.linalg.norm(result.std_rotation_deg)


def test_solve_a_broken_dataset_says_where(tmp_path, capsys):
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"format": "spherecal-dataset", "version": 99}\n')
    assert main(["solve", str(bad)]) == EXIT_DATA
    assert "bad.jsonl" in capsys.readouterr().err


def test_solve_degenerate_data_says_what_to_add(tmp_path, capsys):
    from spherecal.sim import SweepPlan, simulate_dataset

    ds = simulate_dataset(standard_cell("eye_in_hand", fov=reference_fov()),
                          SweepPlan(tilts_deg=[(0, 0, 0), (20, 0, 0)]))
    path = tmp_path / "two.jsonl"
    dataio.write_dataset(path, ds)
    assert main(["solve", str(path), "--no-report"]) == EXIT_DATA
    assert "tilted about a different axis" in capsys.readouterr().err


def test_plugins_lists_robots_and_sensors_with_fields(capsys):
    assert main(["plugins"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "robot type 'abb_irb2400'" in out and "sensor type 'nxsensor_i'" in out
    assert "max_speed_mm_s" in out and "j23_coupled" in out


@pytest.mark.parametrize("command", ["calibrate", "solve", "simulate", "plugins"])
def test_every_command_has_help(command):
    proc = subprocess.run([sys.executable, "-m", "spherecal.cli", command, "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "usage: spherecal" in proc.stdout


def test_top_level_help_documents_exit_codes():
    text = build_parser().format_help()
    for code in ["0 ", "2 ", "3 ", "4 ", "130"]:
        assert code in text


def test_manual_mode_captures_on_enter_and_refuses_rotation_within_a_station(tmp_path):
    """The operator 'jogs' (the test moves the simulated robot) and presses Enter."""
    cell = standard_cell("eye_in_hand", seed=3, fov=reference_fov())
    cell.noise_per_pose = True
    host = PluginHost()
    ctx = DeviceContext(cell=cell, log=lambda m: None)
    robot = host.create_robot({"type": "abb_irb2400"}, ctx)
    sensor = host.create_sensor({"type": "nxsensor_i"}, ctx)
    stations = plan_stations("eye_in_hand", cell.true_transform, cell.sphere_centre_mm, 19.1, field_of_view=cell.fov)
    s1, s2 = stations[0][1][:5], stations[1][1][:5]
    script = [(p, "") for p in s1] + [(s2[0], "")] + [(None, "s")] + [(p, "") for p in s2] + [(None, "q")]
    it = iter(script)
    log = []

    def ask(prompt):
        pose, key = next(it)
        if pose is not None:
            robot.move_linear(pose, 100.0)
        return key

    acq = AcquisitionConfig(sphere_centre_mm=(0, 0, 0), workspace=WorkspaceConfig(min_mm=(-1, -1, -1), max_mm=(1, 1, 1)))
    try:
        with dataio.DatasetWriter(tmp_path / "j.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.1) as w:
            rep = acquire_manual(robot, sensor, w, acq, ask=ask, log=log.append, first_station=3)
    finally:
        sensor.close()
        robot.close()
    ds = dataio.read_dataset(tmp_path / "j.jsonl")
    assert rep.taken == 10
    assert [o.station for o in ds.observations] == ["M3"] * 5 + ["M4"] * 5  # a resumed session numbers on
    assert any("refused: orientation differs" in m for m in log)


def test_hardware_example_is_valid_and_its_plan_is_reachable():
    """The real-hardware configuration validates, its plan stays in the workspace and
    every target is reachable by the IRB 2400 within its joint limits (checked with the
    plugin's kinematics, no controller needed)."""
    host = PluginHost()
    from spherecal.app.cell import configured_for_sensor

    loaded, _ = configured_for_sensor(load_config(EXAMPLES / "irb2400-nxsensor-eye-in-hand.toml"), host)
    cfg = loaded.config
    assert cfg.simulation is None and cfg.robot["port"] == "/dev/ttyUSB0"
    robot_cfg = host.validate_robot_config("abb_irb2400", cfg.robot)
    host.validate_sensor_config("nxsensor_i", cfg.sensor)
    exports = host.export_plan(cfg.export, cfg.mounting, cfg.robot["type"])
    # the tool's name is set; its load is left for the user to give (never invented)
    rapid_settings = exports.selected[0].settings
    assert exports.names[0] == "abb_rapid" and rapid_settings.tool_name == "tSensor"
    assert rapid_settings.mass_kg is None and rapid_settings.cog_mm is None
    targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere)
    assert check_targets(targets, cfg.acquisition) == []
    from spherecal.robots.abb_irb2400.kinematics import kinematics_for

    kin = kinematics_for(robot_cfg.geometry, robot_cfg.j23_coupled)
    seed = np.zeros(6)
    for t in targets:
        seed = kin.joints_from_flange_pose(t.pose, seed_joints_deg=seed)


@pytest.mark.slow
def test_simulate_from_a_kinematic_configuration_uses_its_plan_and_records_joints(tmp_path):
    """simulate --config plans as calibrate does: the kinematic planner's stations, every
    shot with the arm's joints, so that solve --identify-kinematics can use the file."""
    from pathlib import Path

    from spherecal.config import load_config

    example = Path(__file__).resolve().parents[2] / "examples" / "sim-kinematic-eye-in-hand.toml"
    out = tmp_path / "kin.jsonl"
    assert main(["simulate", str(out), "--config", str(example)]) == EXIT_OK
    ds = dataio.read_dataset(out)
    stations = load_config(example).config.acquisition.kinematic_plan.stations
    assert len({o.station for o in ds.observations}) == stations == 20
    assert all(o.joints_deg is not None and len(o.joints_deg) == 6 for o in ds.observations)
