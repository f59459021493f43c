"""The keep-out check before motion, through the command line: a plan that brings the
sensor's body into (or within the clearance of) the sphere or its stand is refused before
anything moves, naming the targets or the move, the gap and what to change; the example
plans keep their distance."""

import pytest

from spherecal.cli import EXIT_DATA, EXIT_OK, EXIT_USAGE, main
from spherecal.config import load_config
from tests.cli.cells import simulated_cell
from tests.cli.conftest import EXAMPLES
from tests.cli.test_validate_scan import write_result_with

#: The sweep's sphere centre at sensor z = 70 mm: above the near end of the range (40) and
#: into the nxSensor-I's body (from z = 80).
SHORT_STANDOFF = {r"^profiles_per_station = 10$": "profiles_per_station = 10\nstandoff_z_mm = 70.0"}
#: Stations 2 and 3 tilted +60 and -60 deg about the sensor's y, one after the other: the
#: straight move between them swings the sensor's body through the sphere.
SWING = {r"^profiles_per_station = 10$": "profiles_per_station = 10\n"
                                         "tilts_deg = [[0.0, 0.0, 0.0], [0.0, 60.0, 0.0], [0.0, -60.0, 0.0], [45.0, 0.0, 0.0]]"}


def _keep_out(text: str) -> dict:
    """A ``[keep_out]`` section before ``[simulation]``."""
    return {r"^\[simulation\]$": f"[keep_out]\n{text}\n\n[simulation]"}


def test_a_standoff_into_the_sensors_body_is_refused(sim_config, irb2400_controllers, capsys):
    cfg = sim_config(**SHORT_STANDOFF)
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert ("the plan brings the sensor's body within keep_out.clearance_mm = 5 mm of the sphere or its stand; "
            "nothing was moved:\n") in err
    assert ("  targets 0, 1, 2, 3, 4, 5, 6, 7, 8, 9 (10 of 10) of station S1, worst target 0, flange at "
            "[1128.0, 157.2, 493.6] mm: the sensor's body overlaps the sphere by 13.1 mm\n") in err, err
    assert "station S3, worst target 20" in err and "overlaps the sphere by 31.1 mm" in err
    assert "At a target: put the sphere farther from the sensor (a lower acquisition.sweep.standoff_z_mm" in err
    assert "x -100..30, y -35..35, z 80..165 mm in the sensor frame (declared by sensor type 'nxsensor_i')" in err
    assert irb2400_controllers == [] and not (cfg.parent / "out" / "journal.jsonl").exists()


def test_a_move_that_swings_the_sensor_through_the_sphere_is_refused(sim_config, capsys):
    """Each target keeps its distance; the move from S2 (+60 deg) to S3 (-60 deg) does not.
    The same stations in another order (+60, 0, -60, ...) pass."""
    assert main(["calibrate", str(sim_config(**SWING)), "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert ("nothing was moved:\n  the move from target 19 (station S2) to target 20 (station S3), 60% of the way, "
            "flange at [1137.4, 159.4, 497.3] mm: the sensor's body overlaps the sphere by 4.7 mm\n") in err, err
    assert "  target" not in err  # no target itself is too near
    assert ("On a move between targets: the straight move between them brings the sensor's body and the sphere "
            "together on its way; smaller tilts between consecutive stations or another order of them") in err
    reordered = {r"^profiles_per_station = 10$": "profiles_per_station = 10\ntilts_deg = "
                 "[[0.0, 60.0, 0.0], [0.0, 0.0, 0.0], [0.0, -60.0, 0.0], [45.0, 0.0, 0.0]]"}
    main(["calibrate", str(sim_config(**reordered)), "--dry-run"])  # the IRB 2400 cannot reach +60 deg: exit 3
    err = capsys.readouterr().err
    assert "keep-out: the sensor's body stays 35.4 mm or more from the sphere and its stand" in err
    assert "keep_out.clearance_mm" not in err


def test_eye_to_hand_the_sphere_and_its_stem_against_the_fixed_sensor(sim_config, capsys):
    assert main(["calibrate", str(sim_config("sim-eye-to-hand.toml", **SHORT_STANDOFF)), "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "within keep_out.clearance_mm = 5 mm of the sphere or its stem; nothing was moved" in err
    assert "of station S1, worst target " in err and "its stem a rod of radius 10 mm from its centre to the flange" in err


def test_the_clearance_is_the_configurations(sim_config, capsys):
    """The example's closest approach is 55.4 mm, on the move from S2 to S3 (its nearest
    target 58.9 mm): a clearance of 57 mm refuses it, naming that move alone."""
    assert main(["calibrate", str(sim_config(**_keep_out("clearance_mm = 57.0"))), "--dry-run"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "within keep_out.clearance_mm = 57 mm of the sphere or its stand" in err and "  target" not in err
    assert ("the move from target 19 (station S2) to target 20 (station S3), 79% of the way, flange at "
            "[1069.5, 145.1, 563.5] mm: the sensor's body comes within 55.4 mm of the sphere") in err, err


def test_a_body_box_in_the_configuration_replaces_the_sensor_types(sim_config, capsys):
    """A housing reaching 30 mm lower (z from 50) than the declared one: the example's
    closest approach drops by 30 mm, to 25.4 mm, and is named as the configuration's."""
    body = "[keep_out.sensor_body]\nmin_mm = [-100.0, -35.0, 50.0]\nmax_mm = [30.0, 35.0, 165.0]"
    assert main(["calibrate", str(sim_config(**{r"^\[simulation\]$": f"{body}\n\n[simulation]"})), "--dry-run"]) \
        == EXIT_OK
    assert "keep-out: the sensor's body stays 25.4 mm or more" in capsys.readouterr().err


@pytest.mark.parametrize("box, message", [
    ("min_mm = [-10.0, -10.0, 20.0]\nmax_mm = [10.0, 10.0, 100.0]",
     "[keep_out.sensor_body]: the box [-10.0, -10.0, 20.0]..[10.0, 10.0, 100.0] mm reaches into the sensor's own "
     "measuring range (z -60..40 mm on the laser plane x = 0): the sensor looks towards -z, so its housing lies at z "
     "above z_near_mm = 40"),
    ("min_mm = [-10.0, -10.0, 200.0]\nmax_mm = [10.0, 10.0, 100.0]", "min_mm z = 200.0 must be below max_mm z = 100.0"),
])
def test_a_wrong_body_box_is_a_configuration_error(sim_config, capsys, box, message):
    cfg = sim_config(**{r"^\[simulation\]$": f"[keep_out.sensor_body]\n{box}\n\n[simulation]"})
    assert main(["calibrate", str(cfg), "--dry-run"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert message in err and ("keep_out.sensor_body" in err), err


@pytest.mark.parametrize("name, closest", [
    ("sim-eye-in-hand.toml", "55.4 mm or more from the sphere and its stand"),
    ("sim-eye-to-hand.toml", "58.9 mm or more from the sphere and its stem"),
    ("sim-ur5-urdf-eye-in-hand.toml", "55.4 mm or more from the sphere and its stand"),
    pytest.param("sim-kinematic-eye-in-hand.toml", "23.5 mm or more from the sphere and its stand",
                 marks=pytest.mark.slow),
])
def test_the_example_plans_keep_their_distance(tmp_path, capsys, name, closest):
    assert main(["calibrate", str(EXAMPLES / name), "--dry-run", "--out", str(tmp_path / "out")]) == EXIT_OK
    err = capsys.readouterr().err
    assert f"keep-out: the sensor's body stays {closest}" in err
    # the plan, then again with the devices open, the first move from where the arm stands included
    assert err.count("keep-out: ") == 1 and err.count("keep-out, from where the arm stands (its first move too): ") == 1


def test_validate_checks_its_plan(sim_config, capsys):
    """The validation's closest approach is 67.7 mm (between two sphere views): a
    clearance of 70 mm refuses its plan before anything moves."""
    cfg = sim_config(exact_arm=True, **_keep_out("clearance_mm = 70.0"))
    write_result_with(cfg.parent / "out", cfg, simulated_cell(load_config(cfg).config).true_transform)
    assert main(["validate", str(cfg), "--no-report"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "the validation plan brings the sensor's body within keep_out.clearance_mm = 70 mm" in err, err
    assert "(station P1) to target " in err and "other tilts of consecutive sites" in err
    assert not list((cfg.parent / "out").glob("validation-*.jsonl"))


def test_scan_checks_its_plan(sim_config, capsys):
    """A scan over the sphere's place with the surface at sensor z = 150 mm (inside the
    body) is refused before anything moves."""
    cfg = sim_config(exact_arm=True, **{r"^object_centre_mm = .*$": "object_centre_mm = [1100.0, 150.0, 400.0]\n"
                                                                     "standoff_z_mm = 150.0",
                                        r'^scan_object = .*$': 'scan_object = "none"'})
    write_result_with(cfg.parent / "out", cfg, simulated_cell(load_config(cfg).config).true_transform)
    assert main(["scan", str(cfg)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "the scan plan brings the sensor's body within keep_out.clearance_mm = 5 mm" in err, err
    assert "of station pass1" in err and "At a target: a lower scan.standoff_z_mm" in err
    assert not (cfg.parent / "out" / "scan.ply").exists()


def test_a_sensor_type_without_a_body_is_said_not_checked(sim_config):
    """No declared body and no [keep_out.sensor_body]: no check, and a warning saying so."""
    from types import SimpleNamespace

    from spherecal.app.plan_checks import CALIBRATION_KEEP_OUT_FIX, keep_out_for

    cfg = load_config(sim_config()).config
    host = SimpleNamespace(registry=SimpleNamespace(sensor_type=lambda name: SimpleNamespace(body=None)))
    said = []
    assert keep_out_for(cfg, host, cfg.nominal_transform.pose(), CALIBRATION_KEEP_OUT_FIX, said.append) is None
    assert [str(s) for s in said] == [
        "warning: sensor type 'nxsensor_i' declares no body and [keep_out.sensor_body] is not given: the sensor's body "
        "is not checked against the sphere and its stand before motion; give the housing's box in the sensor frame "
        "(docs/configuration.md, [keep_out])"]
    # the configuration's box is used when the sensor type has none
    boxed = load_config(sim_config(**{r"^\[simulation\]$": "[keep_out.sensor_body]\nmin_mm = [-1.0, -1.0, 50.0]\n"
                                                           "max_mm = [1.0, 1.0, 60.0]\n\n[simulation]"})).config
    keep_out = keep_out_for(boxed, host, cfg.nominal_transform.pose(), CALIBRATION_KEEP_OUT_FIX, said.append)
    assert keep_out.body_source == "[keep_out.sensor_body]" and keep_out.geometry.body.min_mm == (-1.0, -1.0, 50.0)
