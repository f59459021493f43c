"""A kinematic calibration's robot_calibrated.urdf in use: `validate` and `scan` on the
simulated cell (its arm with a real arm's geometric error), the IRB 2400 taking the model
as `calibrated_model`, given relative to the configuration file."""

import json

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_VALIDATION, EXIT_OK, main
from spherecal.config import load_config
from spherecal.motion.kinematic_plan import plan_kinematic_stations
from spherecal.plugins.host import PluginHost
from spherecal.io.ply import read_ply
from spherecal.app.cell import configured_for_sensor
from spherecal.app.plugin_host import open_devices
from spherecal.app.solving import calibration_options, solve_and_write
from spherecal.sim import simulate_dataset
from spherecal.core.urdf import read_urdf_chain
from tests.cli.cells import simulated_cell

#: The eye-in-hand example with identify_kinematics (the planner's stations, kept off the
#: sphere's edge), a plate to scan and short validation sweeps of the sphere and ball bar.
CALIBRATE = {
    r"^\[calibration\]$": "[calibration]\nidentify_kinematics = true",
    r"^profiles_per_station = 10$": "profiles_per_station = 5\nsweep_fraction = 0.7",
    r'^scan_object = "car_door_panel".*$': 'scan_object = "flat_plate"',
    r"^profiles_per_sweep = 24$": "profiles_per_sweep = 8",
    r"^step_mm = 1.0$": "step_mm = 2.0",
    r"^\[validation\.flat\].*\ncentre_mm = .*$": "",  # not judged here
}


@pytest.fixture
def calibrated(sim_config, tmp_path):
    """A kinematic calibration of the simulated cell written into <tmp>/out (acquired
    without the devices: the same cell, arm and plan), and the configuration."""
    path = sim_config(**CALIBRATE)
    loaded, _ = configured_for_sensor(load_config(path), PluginHost())  # as a run: the sensor's standoff
    cfg = loaded.config
    nominal = PluginHost().arm_kinematics(cfg.robot)
    cell = simulated_cell(cfg, nominal)  # as a run makes it
    cell.attach_arm(nominal)  # as the simulated controller does
    plan = plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere,
                                   nominal)
    dataset = simulate_dataset(cell, plan.sweep)
    out = tmp_path / "out"
    exports = PluginHost().export_plan(None, cfg.mounting, None)
    solution, _, written = solve_and_write(dataset, calibration_options(cfg), out, exports, log=lambda m: None,
                                           report=False, kinematics=nominal)
    assert written and (out / "robot_calibrated.urdf").exists()
    _check_the_red_mark(solution, nominal, out, tmp_path / "red")
    return path, out, dataio.read_result(out / "result.json"), nominal


def _check_the_red_mark(solution, kinematics, out, red_out):
    """The model of a result rated RED (written only with --force) says so in its header
    comment; a result not rated RED carries no such mark."""
    from dataclasses import replace

    from spherecal.io.exporters import RED_WARNING
    from spherecal.app.solving import write_calibrated_urdf

    assert RED_WARNING not in (out / "robot_calibrated.urdf").read_text()
    verdict = {"level": "red", "headline": "forced", "written_with_force": True}
    red = replace(solution, result=solution.result.model_copy(
        update={"diagnostics": solution.result.diagnostics.model_copy(update={"verdict": verdict})}))
    red_out.mkdir()
    text = write_calibrated_urdf(red, kinematics, red_out).read_text()
    assert text.splitlines()[2].strip() == RED_WARNING  # the first line of the header comment
    read_urdf_chain(red_out / "robot_calibrated.urdf", "base_link", "tool0")  # still a valid URDF


def with_model(path, model: str | None):
    """The configuration at ``path`` with (or without) ``[robot] calibrated_model``."""
    text = path.read_text()
    if model is not None:
        text = text.replace('type = "abb_irb2400"', f'type = "abb_irb2400"\ncalibrated_model = "{model}"', 1)
    target = path.with_name(("calibrated-" if model else "nominal-") + path.name)
    target.write_text(text)
    return target


@pytest.mark.slow
def test_validate_and_scan_through_the_calibrated_model(calibrated, tmp_path, monkeypatch):
    """The calibrated model given relative to the configuration (run from another folder)
    is the one the robot uses. With it the sphere fitted from each validation view lies
    within the calibration's predicted point error (k = 2) of the sphere the calibration
    found, and the ball bar's length within what two such points allow; through the
    nominal model the views disagree by several times more. Scanning a plate through the
    model writes it flat within the predicted point error, and in another place than the
    nominal model does."""
    path, out, result, nominal = calibrated
    k2 = result.robot_error.point_error_k2_mm
    assert 0.01 < k2 < 0.2
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # not the configuration's folder
    loaded = load_config(with_model(path, "out/robot_calibrated.urdf"))
    with open_devices(loaded, PluginHost(), simulated_cell(loaded.config), log=lambda m: None) as (robot, _sensor):
        assert robot.calibrated is not None and robot.calibrated.source == str(out / "robot_calibrated.urdf")
        model = read_urdf_chain(out / "robot_calibrated.urdf", "base_link", "tool0")
        q = np.radians(np.random.default_rng(0).uniform(-40, 40, (20, 6)))
        assert np.abs(robot.kin.chain.flange_matrices(q) - getattr(model, "chain", model).flange_matrices(q)).max() < 1e-9
        assert np.abs(robot.kin.chain.flange_matrices(q) - nominal.chain.flange_matrices(q)).max() > 0.05
    figures = {}
    for label, model in (("calibrated", "out/robot_calibrated.urdf"), ("nominal", None)):
        cfg = with_model(path, model)
        cfg.write_text(cfg.read_text().replace("[scan]\n", f'[scan]\nply = "scan-{label}.ply"\n'))
        code = main(["validate", str(cfg), "--no-report"])
        assert code == EXIT_OK or label == "nominal"
        v = json.loads((out / "validation.json").read_text())
        centres = np.array(list(v["centres_mm"].values()))
        figures[label] = (np.linalg.norm(centres - result.sphere_centre_mm, axis=1),
                          [abs(s["sphere_spacing_error_mm"]) for s in v["report"]["sphere_spacing"]])
        # a scan after a failed validation (the nominal model) writes its points and exits 5
        assert main(["scan", str(cfg)]) == (EXIT_OK if code == EXIT_OK else EXIT_VALIDATION)
    off, spacing = figures["calibrated"]
    assert len(off) == 4 and off.max() <= k2, (off, k2)
    assert len(spacing) == 3 and max(spacing) <= np.sqrt(2) * k2, (spacing, k2)
    assert np.sqrt(np.mean(figures["nominal"][0] ** 2)) > 3 * np.sqrt(np.mean(off**2)), figures

    def plate(label):
        v = read_ply(out / f"scan-{label}.ply")
        return np.column_stack([v["x"], v["y"], v["z"]]).astype(float)

    cal, nom = plate("calibrated"), plate("nominal")
    assert len(cal) > 20_000
    # flat: the residuals of a fitted plane (stray points on 10 % of the profiles aside)
    centred = cal - cal.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][2]
    assert np.percentile(np.abs(centred @ normal), 95) <= k2
    assert abs(np.median(cal[:, 2]) - np.median(nom[:, 2])) > 0.05  # every pose through the model
