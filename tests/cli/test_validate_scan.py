"""spherecal validate and spherecal scan on the simulated cell."""

import json
import re

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.cli import EXIT_DATA, EXIT_OK, EXIT_USAGE, EXIT_VALIDATION, main
from spherecal.config import load_config
from spherecal.core.models import Pose
from spherecal.io.ply import read_ply, read_ply_header
from spherecal.app.cell import sensor_field_of_view
from tests.cli.cells import simulated_cell


def fov_of(cfg):
    """The field of view the run plans in: the configured sensor's."""
    from spherecal.plugins.host import PluginHost

    return sensor_field_of_view(cfg, PluginHost())


def write_result_with(out, cfg_path, transform: Pose):
    """A result.json that claims ``transform`` (built from a quick solve of a simulated
    dataset so that every other field is genuine)."""
    from spherecal.estimation import calibrate
    from spherecal.sim import SweepPlan, simulate_dataset

    cell = simulated_cell(load_config(cfg_path).config)
    result = calibrate(simulate_dataset(cell, SweepPlan(profiles_per_station=6)))
    out.mkdir(parents=True, exist_ok=True)
    dataio.write_result(out / "result.json", result.model_copy(update={"transform": transform}), overwrite=True)
    return cell.true_transform


@pytest.fixture
def cfg_path(sim_config):
    # validation figures against the true calibration: a clean cell (an exact arm)
    return sim_config("sim-eye-in-hand.toml", exact_arm=True)


@pytest.mark.slow
def test_validate_with_the_true_calibration_passes(cfg_path, capsys):
    out = cfg_path.parent / "out"
    cell = simulated_cell(load_config(cfg_path).config)
    write_result_with(out, cfg_path, cell.true_transform)
    assert main(["validate", str(cfg_path), "--no-report"]) == EXIT_OK
    printed = capsys.readouterr().out
    assert "validation passed" in printed and "points used" in printed
    v = json.loads((out / "validation.json").read_text())
    assert v["passed"] is True
    rep = v["report"]
    # P_S and SD within what the noise explains: their spread over many simulated
    # validations (point and pose noise, no calibration error), found by Monte Carlo
    sd_ps, sd_sd = noise_spread(load_config(cfg_path).config, cell.true_transform)
    assert len(rep["probing"]) == 4 and len(rep["sphere_spacing"]) == 3
    assert all(abs(p["probing_size_error_mm"]) < 4 * sd_ps for p in rep["probing"])
    assert all(abs(s["sphere_spacing_error_mm"]) < 4 * sd_sd for s in rep["sphere_spacing"])
    assert sd_ps < 0.03 and sd_sd < 0.03
    assert all(f["flatness_error_mm"] < 0.15 for f in rep["flatness"])
    assert v["figures"]["centre spread"]["max error (mm)"] < 0.05


def noise_spread(cfg, X, seeds=10):
    """RMS of P_S and SD over simulated validations with the true calibration."""
    from spherecal.motion.validation import Measured, evaluate, plan_validation

    ps, sd = [], []
    for seed in range(100, 100 + seeds):
        cell = simulated_cell(cfg.model_copy(update={"simulation": cfg.simulation.model_copy(update={"seed": seed})}))
        cell.noise_per_pose = False
        measured = []
        for sweep in plan_validation(cfg.validation, cfg.acquisition, cfg.mounting, X, cfg.sphere, fov_of(cfg)):
            poses, profiles = cell.scan([t.pose for t in sweep.targets])
            keep = [k for k, p in enumerate(profiles) if len(p)]
            measured.append(Measured(sweep, [poses[k] for k in keep], [profiles[k] for k in keep]))
        report = evaluate(cfg.validation, cfg.mounting, X, cfg.sphere, measured).report
        ps += [p.probing_size_error_mm for p in report.probing]
        sd += [s.sphere_spacing_error_mm for s in report.sphere_spacing]
    return float(np.sqrt(np.mean(np.square(ps)))), float(np.sqrt(np.mean(np.square(sd))))


@pytest.mark.slow
def test_an_offset_calibration_is_caught_with_the_expected_figures(cfg_path, capsys):
    """X off by 0.3 mm: each view sees the sphere shifted by R0_k dt, so the fitted
    centres spread and the ball bar (balls seen from different views) changes length by
    the predicted amounts."""
    out = cfg_path.parent / "out"
    cfg = load_config(cfg_path).config
    true = simulated_cell(cfg).true_transform
    dt = np.array([0.3, 0.0, 0.0])
    write_result_with(out, cfg_path, Pose.from_rt(true.rotation_matrix, true.translation + dt))
    assert main(["validate", str(cfg_path), "--no-report"]) == EXIT_VALIDATION
    printed = capsys.readouterr().out
    # the calibration's own verdict did not name the robot: a failure is the calibration's
    assert "FAILED" in printed and "Do not use this calibration" in printed and "Likely cause" not in printed
    v = json.loads((out / "validation.json").read_text())
    assert v["cause"] is None

    from spherecal.motion.validation import plan_validation

    sweeps = plan_validation(cfg.validation, cfg.acquisition, cfg.mounting, true, cfg.sphere, fov_of(cfg))
    R0 = {s.label + s.kind: s.targets[0].pose.rotation_matrix for s in sweeps}
    shifts = np.array([R0[f"P{k}sphere"] @ dt for k in range(1, 5)])
    predicted_spread = np.linalg.norm(shifts - shifts.mean(axis=0), axis=1).max()
    assert v["figures"]["centre spread"]["max error (mm)"] == pytest.approx(predicted_spread, abs=0.02)
    assert predicted_spread > 0.1
    bb = cfg.validation.ball_bar
    u = np.subtract(bb.centre_b_mm, bb.centre_a_mm)
    u /= np.linalg.norm(u)
    for s in v["report"]["sphere_spacing"]:
        k = s["position"]
        predicted = (R0[k + "ball_b"] @ dt - R0[k + "ball_a"] @ dt) @ u
        assert s["sphere_spacing_error_mm"] == pytest.approx(predicted, abs=0.02)

    # a scan with the calibration that failed: it says so before anything moves, writes
    # the points all the same, and exits 5 (a doubtful product never exits 0)
    assert main(["scan", str(cfg_path)]) == EXIT_VALIDATION
    cap = capsys.readouterr()
    first = cap.err.index("warning: this calibration failed its latest validation")
    assert first < cap.err.index("scan: ") and "centre spread" in cap.err[first:].splitlines()[0]
    assert "the points were mapped with it (exit 5); re-calibrate" in cap.err and (out / "scan.ply").exists()


@pytest.mark.slow
def test_a_rotated_calibration_is_caught(cfg_path):
    """X off by 0.5 deg about the sensor's y. A laser-plane point (0, y, z) is then mapped
    off by delta * z along the sensor's x, so each view sees the sphere moved by about
    R0_k X (delta * mean z, 0, 0), mean z over the points that view sees; the views'
    centres spread accordingly."""
    out = cfg_path.parent / "out"
    cfg = load_config(cfg_path).config
    cell = simulated_cell(cfg)
    true = cell.true_transform
    delta = np.radians(0.5)
    wrong = Pose.from_rt(true.rotation_matrix @ geo.matrix_from_rotvec([0, delta, 0]), true.translation)
    write_result_with(out, cfg_path, wrong)
    assert main(["validate", str(cfg_path), "--no-report"]) == EXIT_VALIDATION
    v = json.loads((out / "validation.json").read_text())

    from spherecal.motion.validation import plan_validation

    shifts = []
    sweeps = plan_validation(cfg.validation, cfg.acquisition, cfg.mounting, true, cfg.sphere, fov_of(cfg))
    for sweep in [s for s in sweeps if s.kind == "sphere"]:
        mean_z = np.concatenate([cell.ideal_profile(t.pose)[:, 1] for t in sweep.targets]).mean()
        shifts.append(sweep.targets[0].pose.rotation_matrix @ true.rotation_matrix @ [delta * mean_z, 0.0, 0.0])
    shifts = np.array(shifts)
    predicted = np.linalg.norm(shifts - shifts.mean(axis=0), axis=1).max()
    assert predicted > 0.1
    assert v["figures"]["centre spread"]["max error (mm)"] == pytest.approx(predicted, abs=0.03)
    assert v["figures"]["centre spread"]["passed"] is False


def test_a_partial_mpe_section_keeps_the_other_defaults():
    from spherecal.config import ValidationConfig

    v = ValidationConfig.model_validate({"mpe": {"probing_form_mm": 0.3}})
    m = v.mpe
    assert (m.probing_form_mm, m.probing_size_mm, m.sphere_spacing_mm, m.flatness_mm) == (0.3, 0.06, 0.1, 0.15)


ETH_EXTRA = """
[validation]
profiles_per_sweep = 16

[validation.mpe]
probing_size_mm = 0.1  # |P_S| of 16-profile sweeps reaches 0.07 mm here with a 0.003 mm calibration

[scan]
object_centre_mm = [0.0, 150.0, 250.0]
length_mm = 40.0
step_mm = 1.0
"""


@pytest.mark.slow
def test_eye_to_hand_calibrate_validate_and_scan(sim_config, capsys):
    """Eye-to-hand end to end: the sphere and a plate ride on the flange; validation
    and scan map points into the flange frame."""
    cfg_path = sim_config("sim-eye-to-hand.toml", exact_arm=True,
                          **{r"^seed = 2$": 'seed = 2\nscan_object = "flat_plate"'})
    cfg_path.write_text(cfg_path.read_text() + ETH_EXTRA)
    out = cfg_path.parent / "out"
    assert main(["calibrate", str(cfg_path), "--no-report"]) == EXIT_OK
    assert main(["validate", str(cfg_path), "--no-report"]) == EXIT_OK
    capsys.readouterr()
    assert main(["validate", str(cfg_path)]) == EXIT_OK  # this one writes a report: the calibration wrote none
    assert len(list(out.glob("validation-*.jsonl"))) == 2  # a re-run keeps the earlier run's shots
    v = json.loads((out / "validation.json").read_text())
    # the terminal prints the verdict the report shows: the calibration's with the validation's figures
    printed = capsys.readouterr().out
    (line,) = [x for x in printed.splitlines() if x.startswith("verdict: ")]
    level, headline = line[len("verdict: "):].split(": ", 1)
    assert headline.endswith("Validation passed: every judged figure within its MPE.")
    assert v["verdict"] == {"level": level.lower(), "headline": headline}
    import html

    assert f"report: {out / 'report-2.html'}, a new version with this validation" in printed
    assert not (out / "report.html").exists()  # the calibration's name stays the calibration's
    page = (out / "report-2.html").read_text()
    assert "No earlier report of this calibration was found beside it" in page
    assert f"Verdict: {level} &mdash; {html.escape(headline)}" in page
    positions = page[page.index('id="validation"'):page.index('id="details"')]
    assert positions[positions.index("Per position"):].count("<td>P_F</td>") == 4  # one row per view
    assert v["passed"] and len(v["report"]["probing"]) == 4
    assert v["figures"]["centre spread"]["max error (mm)"] < 0.05
    assert main(["scan", str(cfg_path)]) == EXIT_OK
    ply = read_ply(out / "scan.ply")
    assert read_ply_header(out / "scan.ply").comments  # says which frame
    z = np.asarray(ply["z"], dtype=float)
    # the plate is the plane z = 250 mm of the flange frame
    assert len(z) > 5000 and np.median(np.abs(z - 250.0)) < 0.03


@pytest.mark.slow
def test_validate_and_scan_name_the_arms_geometry_and_leave_the_calibration_as_written(sim_config, capsys):
    """The plain example (the simulated arm's geometric error, robot error model auto):
    the calibration's verdict is AMBER (the robot's error dominates) and its validation
    fails on the absolute figures. The verdict names the arm as the likely cause with the
    remedy (the arm's calibration, or accepting the figures) instead of "do not use",
    says which figures are absolute and which relative; the scan says the same instead of
    "re-calibrate". The calibration's report.html and result.json are left byte for byte
    as written: the validation's report is report-2.html, which names what it supersedes."""
    import hashlib

    cfg_path = sim_config("sim-eye-in-hand.toml")
    out = cfg_path.parent / "out"
    assert main(["calibrate", str(cfg_path)]) == EXIT_OK
    assert "verdict: AMBER: Robot error dominates" in capsys.readouterr().out
    written = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "run.log"}
    assert {"report.html", "result.json"} <= set(written)

    assert main(["validate", str(cfg_path)]) == EXIT_VALIDATION
    printed = capsys.readouterr().out
    (line,) = [x for x in printed.splitlines() if x.startswith("verdict: ")]
    assert line.startswith("verdict: RED: Validation failed: ") and "Do not use" not in line
    assert "Likely cause: the arm's own geometry, as the calibration's verdict said" in line
    assert "remedy: either calibrate the arm's geometry with spherecal ([calibration] identify_kinematics = true" in printed
    assert re.search(r"(?m)^SD +\d\.\d{4} +B\d +0\.1000  FAIL +absolute$", printed)
    assert re.search(r"(?m)^P_F +\d\.\d{4} +P\d +0\.2500  pass +relative$", printed)
    assert f"report: {out / 'report-2.html'}, a new version" in printed
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in written} == written
    page = (out / "report-2.html").read_text()
    assert (f"It supersedes <code>report.html</code> (SHA-256 <code class=\"hash\">"
            f"{hashlib.sha256(written['report.html']).hexdigest()}</code>)") in page
    assert 'class="simulated-banner"' in page and "Likely cause: the arm&#x27;s own geometry" in page
    v = json.loads((out / "validation.json").read_text())
    assert "identify_kinematics" in v["cause"]["remedy"] and v["figures"]["SD"]["scope"] == "absolute"

    assert main(["scan", str(cfg_path)]) == EXIT_VALIDATION
    err = capsys.readouterr().err
    assert "likely cause: the arm's own geometry" in err and "re-calibrate" not in err
    assert "the points were mapped with it (exit 5); either calibrate the arm's geometry" in err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in written} == written


def test_validate_needs_a_result(cfg_path, capsys):
    assert main(["validate", str(cfg_path)]) == EXIT_DATA
    assert "result.json" in capsys.readouterr().err


def test_validate_needs_its_section(sim_config, capsys):
    cfg = sim_config("sim-eye-to-hand.toml")
    assert "[validation]" not in cfg.read_text()
    assert main(["validate", str(cfg)]) == EXIT_USAGE
    assert "no [validation] section" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_scan_a_flat_plate_into_ply(sim_config, fmt, capsys):
    cfg_path = sim_config("sim-eye-in-hand.toml", exact_arm=True, **{
        r'^scan_object = "car_door_panel".*$': 'scan_object = "flat_plate"',
        r"^passes = 2$": f'passes = 2\nformat = "{fmt}"',
    })
    out = cfg_path.parent / "out"
    true = simulated_cell(load_config(cfg_path).config).true_transform
    write_result_with(out, cfg_path, true)
    assert main(["scan", str(cfg_path)]) == EXIT_OK
    printed = capsys.readouterr().out
    n = int(printed.split()[1])
    header = read_ply_header(out / "scan.ply")
    assert header.vertex_count == n and header.format == fmt
    v = read_ply(out / "scan.ply")
    xyz = np.column_stack([v["x"], v["y"], v["z"]]).astype(float)
    assert len(xyz) == n > 50_000
    # the plate's surface is the plane z = 380 mm in base: points land on it within noise,
    # but for the simulated stray points (reflections on 10 % of the profiles, 4 each)
    off = np.abs(xyz[:, 2] - 380.0) > 0.12
    assert off.sum() <= 0.1 * 162 * 4 * 3
    assert abs(np.median(xyz[:, 2]) - 380.0) < 0.01
    assert set(np.unique(v["profile"])) == set(range(162))
    assert main(["scan", str(cfg_path)]) == EXIT_DATA  # never overwrites


@pytest.mark.slow
def test_scan_the_car_door_panel(cfg_path, capsys):
    out = cfg_path.parent / "out"
    true = simulated_cell(load_config(cfg_path).config).true_transform
    write_result_with(out, cfg_path, true)
    assert main(["scan", str(cfg_path)]) == EXIT_OK
    v = read_ply(out / "scan.ply")
    z = np.asarray(v["z"], dtype=float)
    # a curved panel: its height varies across the scanned area by more than the noise
    assert len(z) > 50_000 and np.ptp(z) > 0.5


def test_why_the_report_is_not_updated_names_the_changed_configuration(tmp_path):
    """validate updates the calibration's report only when solving its journal again gives
    the result validated. When it does not, the reason says which: another dataset, or
    the same journal under a configuration that changed since (a calibrated robot model
    added, other settings), not "not the calibration" of a journal that is its own."""
    from types import SimpleNamespace

    from spherecal.app.provenance import sha256_of
    from spherecal.app.validate import not_the_calibration

    journal, cfg_then, cfg_now = tmp_path / "journal.jsonl", tmp_path / "a.toml", tmp_path / "b.toml"
    journal.write_text("the shots\n")
    cfg_then.write_text("[robot]\n")
    cfg_now.write_text("[robot]\ncalibrated_model = 'robot_calibrated.urdf'\n")
    result = SimpleNamespace(provenance={"dataset_sha256": sha256_of(journal), "configuration_file": str(cfg_then),
                                         "configuration_sha256": sha256_of(cfg_then)})
    why = not_the_calibration(result, tmp_path / "result.json", journal, SimpleNamespace(path=cfg_now))
    assert why.startswith(f"{tmp_path / 'result.json'} is the calibration of {journal}, but solving that journal "
                          f"again with this configuration gives another transform: {cfg_now} is not the "
                          f"configuration it was calibrated with ({cfg_then})")
    same = not_the_calibration(result, tmp_path / "result.json", journal, SimpleNamespace(path=cfg_then))
    assert "the configuration is the one it was calibrated with, so a file it names (a robot model)" in same
    journal.write_text("other shots\n")
    assert not_the_calibration(result, tmp_path / "result.json", journal, SimpleNamespace(path=cfg_now)) == (
        f"{tmp_path / 'result.json'} is not the calibration of {journal}")
