"""``scan`` on the fly on the embedded default: the sphere scanned in passes at 400
profiles a second with the true transform and the true clock relation (an exact arm), and
the fault run: lost pose samples, a stalled pose stream, lost and late sensor frames, a
step of the sensor's clock and a jump of the controller's during a pass. Each is survived
or stops the scan naming it, and no point in the PLY comes from a profile whose pose was
not bracketed by samples: every point lies on the true sphere within a tolerance."""

import contextlib
import json
import re

import numpy as np
import pytest

from spherecal.app import plugin_host, scan_on_the_fly as otf_scan
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.plugin_host import robot_arm
from spherecal.app.scan import run_scan
from spherecal.config import load_config
from spherecal.core.errors import InputError
from spherecal.core.models import TimingEstimate
from spherecal.io import dataset as dataio
from spherecal.io.ply import read_ply, read_ply_header
from spherecal.motion.scan_on_the_fly import ClockRelationLost, ScanStreamError
from spherecal.sim.live import clock_truth, true_time_relation
from tests.cli.conftest import ROBOT_ERROR_SECTION

EXAMPLE = "sim-on-the-fly-eye-in-hand.toml"
#: Every point within this of the true sphere (point noise 0.01 mm, the arm's smooth
#: repeatability 0.02 mm per axis, the sphere's curvature over a profile's pose error).
SURFACE_TOLERANCE_MM = 0.12


@pytest.fixture
def cell_truth(sim_config):
    """The example (an exact arm), with a result.json holding the true transform and the
    true clock relation; gives (config path, true sphere centre, its radius, the clocks'
    truth as :func:`spherecal.sim.live.clock_truth` gives it)."""
    from spherecal.estimation import calibrate
    from spherecal.sim import SweepPlan, simulate_dataset

    # an exact arm (the example already has "station"); the simulated sensor draws a pass's frames in wall time
    # after the simulated move and its driver waits stall_timeout_ms + 1 s of wall time for them at the stop:
    # 3 s keeps a loaded machine from ending a pass there (no test here relies on the sensor's stall limit)
    cfg = sim_config(EXAMPLE, **{ROBOT_ERROR_SECTION: "",
                                 r'^type = "nxsensor_i"$': 'type = "nxsensor_i"\nstall_timeout_ms = 3000'})
    loaded = load_config(cfg)
    host = plugin_host.make_host()
    loaded, fov = configured_for_sensor(loaded, host)
    cell = make_cell(loaded.config, robot_arm(loaded, host), fov)
    t_sensor0 = 100.0
    offset_s, drift = true_time_relation(clock_truth(cell), t_sensor0)
    timing = TimingEstimate(offset_ms=1e3 * offset_s, offset_std_ms=0.02, drift_ppm=1e6 * drift, drift_std_ppm=0.5,
                            drift_estimated=True, t_sensor0_s=t_sensor0, identifiable=True, identifiability="test")
    result = calibrate(simulate_dataset(cell, SweepPlan(profiles_per_station=6)))
    out = cfg.parent / "out"
    out.mkdir(parents=True, exist_ok=True)
    dataio.write_result(out / "result.json", result.model_copy(update={"transform": cell.true_transform,
                                                                       "timing": timing}))
    return cfg, cell.sphere_centre_mm, loaded.config.sphere.radius_mm, clock_truth(cell)


@pytest.fixture
def opened(monkeypatch):
    devices = []
    real = otf_scan.open_devices

    @contextlib.contextmanager
    def spy(*args, **kwargs):
        with real(*args, **kwargs) as pair:
            devices.append(pair)
            yield pair

    monkeypatch.setattr(otf_scan, "open_devices", spy)
    return devices


def after_pass(k, action):
    lines = []

    def log(msg):
        lines.append(str(msg))
        if str(msg).startswith(f"pass {k} ("):
            action()

    log.lines = lines
    return log


def scanned(cfg, log=lambda _: None):
    path, summary = run_scan(load_config(cfg), log=log, yes=True)
    return path, summary


def surface_error_mm(path, centre, radius):
    v = read_ply(path)
    p = np.c_[v["x"], v["y"], v["z"]].astype(float)
    return np.abs(np.linalg.norm(p - centre, axis=1) - radius), v


def test_the_sphere_scanned_at_400_hz_lies_on_its_true_surface(cell_truth):
    cfg, centre, r, _ = cell_truth
    log = after_pass(0, lambda: None)
    path, summary = scanned(cfg, log)
    err, v = surface_error_mm(path, centre, r)
    assert summary.mode == "on_the_fly" and summary.profiles > 300 and len(v) == summary.points
    assert err.max() < SURFACE_TOLERANCE_MM and np.sqrt(np.mean(err ** 2)) < 0.03
    said = "\n".join(log.lines)
    assert re.search(r"\(\d+\.\d a second; 400\.0 a second while streaming", said)
    assert "mapped with the calibration's timing" in said
    passes = [json.loads(x) for x in path.with_name(path.name + ".passes.jsonl").read_text().splitlines()]
    assert len(passes) == 3 and sum(p["mapped"] for p in passes) == summary.profiles
    assert all(p["timing_error_k2_mm"] < 0.02 for p in passes)
    assert "clock relation: the calibration's timing" in " ".join(read_ply_header(path).comments)


def test_a_calibration_without_a_clock_relation_cannot_scan_on_the_fly(cell_truth, opened):
    cfg, *_ = cell_truth
    out = cfg.parent / "out"
    result = dataio.read_result(out / "result.json")
    dataio.write_result(out / "result.json", result.model_copy(update={"timing": None}), overwrite=True)
    with pytest.raises(InputError, match=r"holds no clock relation .* the time between the sensor's stamps and the "
                                         r"robot's is unknown.*nothing was moved"):
        scanned(cfg)
    assert not opened and not (out / "scan.ply").exists()


def test_a_given_clock_offset_is_said_loudly_and_written_in_the_ply(cell_truth):
    cfg, centre, r, clocks = cell_truth
    out = cfg.parent / "out"
    result = dataio.read_result(out / "result.json")
    dataio.write_result(out / "result.json", result.model_copy(update={"timing": None}), overwrite=True)
    # the true offset at the scan's time (the sensor clock 5 s after the simulated world's start): the drift
    # left out moves the profiles of the 10 s scan by at most 0.7 ms, 0.07 mm at 100 mm/s
    sensor = clocks["sensor"]
    offset_s, _ = true_time_relation(clocks, sensor["offset_s"] + 5.0 * sensor["rate"])
    cfg.write_text(cfg.read_text().replace("[scan]\n", f"[scan]\nclock_offset_ms = {1e3 * offset_s!r}\n"))
    log = after_pass(0, lambda: None)
    path, _ = scanned(cfg, log)
    assert any("WARNING: scanning on the fly with a clock offset GIVEN" in x for x in log.lines)
    assert "GIVEN, not estimated" in " ".join(read_ply_header(path).comments)
    assert surface_error_mm(path, centre, r)[0].max() < SURFACE_TOLERANCE_MM


def test_lost_pose_samples_and_lost_or_late_frames_are_survived_and_counted(cell_truth, opened):
    cfg, centre, r, _ = cell_truth

    def faults():
        robot, sensor = opened[0]
        sensor._backend.drop_frames(4, after=60)
        sensor._backend.delay_exposures(0.0015, n=2, after=120)  # 0.6 periods late, then on schedule
        start = robot.start_pose_stream

        def start_then_drop():
            start()
            robot.simulator.controller.egm.set_faults(drop_next=1)  # one sample: interpolated across
            robot.start_pose_stream = start

        robot.start_pose_stream = start_then_drop

    path, summary = scanned(cfg, after_pass(1, faults))
    passes = [json.loads(x) for x in path.with_name(path.name + ".passes.jsonl").read_text().splitlines()]
    assert (passes[1]["frames_lost"], passes[1]["frames_late"], passes[1]["pose_lost"]) == (4, 1, 1)
    assert "off_grid" not in passes[1]["unmapped"]  # late frames keep their stamps
    assert surface_error_mm(path, centre, r)[0].max() < SURFACE_TOLERANCE_MM


def test_a_burst_of_lost_pose_samples_leaves_its_profiles_unmapped(cell_truth, opened):
    cfg, centre, r, _ = cell_truth

    def burst():
        robot, _ = opened[0]
        start = robot.start_pose_stream

        def start_then_drop():
            start()
            robot.simulator.controller.egm.set_faults(drop_next=25)  # 100 ms without a sample
            robot.start_pose_stream = start

        robot.start_pose_stream = start_then_drop

    log = after_pass(1, burst)
    path, summary = scanned(cfg, log)
    assert summary.unmapped.get("gap", 0) >= 30
    assert any("exposed in a gap of the pose stream" in x for x in log.lines)
    assert surface_error_mm(path, centre, r)[0].max() < SURFACE_TOLERANCE_MM


def test_a_stalled_pose_stream_stops_the_scan_after_the_move_mapping_only_what_it_brackets(cell_truth, opened):
    cfg, centre, r, _ = cell_truth

    def stall():
        opened[0][0].simulator.controller.egm.set_faults(stall_after=60)

    with pytest.raises(ScanStreamError, match=r"pass 2 \(back at 100 mm/s\): the pose stream failed") as err:
        scanned(cfg, after_pass(1, stall))
    out = cfg.parent / "out"
    passes = [json.loads(x) for x in (out / "scan.ply.passes.jsonl").read_text().splitlines()]
    assert len(passes) == 2 and passes[1]["fault"] and passes[1]["unmapped"]["after"] > 50
    assert err.value.taken.mapped == passes[1]["mapped"]
    assert surface_error_mm(out / "scan.ply", centre, r)[0].max() < SURFACE_TOLERANCE_MM


def test_a_step_of_the_sensor_clock_mid_pass_stops_the_scan_leaving_what_follows_unmapped(cell_truth, opened):
    cfg, centre, r, _ = cell_truth

    def step():
        opened[0][1]._backend.step_clock(0.005, after=100)  # 2 periods ahead: within the driver's "late"

    with pytest.raises(ClockRelationLost, match=r"pass 2 \(back at 100 mm/s\): the sensor's clock stepped during the "
                                                r"pass: \d+ profiles stamped after the step"):
        scanned(cfg, after_pass(1, step))
    out = cfg.parent / "out"
    passes = [json.loads(x) for x in (out / "scan.ply.passes.jsonl").read_text().splitlines()]
    assert len(passes) == 2 and passes[1]["unmapped"]["off_grid"] >= 100  # from the step to the pass's end
    assert surface_error_mm(out / "scan.ply", centre, r)[0].max() < SURFACE_TOLERANCE_MM


def test_without_the_frame_grid_check_the_stepped_clock_would_misplace_points(cell_truth, opened, monkeypatch):
    """The fault run's tolerance can fail: the same step, its profiles mapped by their
    stamps, puts points 0.5 mm along the pass, off the sphere."""
    from spherecal.motion import scan_on_the_fly as mod

    cfg, centre, r, _ = cell_truth
    monkeypatch.setattr(mod, "off_frame_grid", lambda t, f, *a, **k: np.zeros(len(t), dtype=bool))
    path, _ = scanned(cfg, after_pass(1, lambda: opened[0][1]._backend.step_clock(0.005, after=100)))
    assert surface_error_mm(path, centre, r)[0].max() > 2 * SURFACE_TOLERANCE_MM


def test_a_jump_of_the_controllers_clock_stops_the_scan_naming_the_pass(cell_truth, opened):
    cfg, centre, r, _ = cell_truth

    def jump():
        robot = opened[0][0]
        start = robot.start_pose_stream

        def start_then_jump():
            start()
            robot.simulator.controller.egm.set_faults(clock_jump_s=0.5)
            robot.start_pose_stream = start

        robot.start_pose_stream = start_then_jump

    with pytest.raises(ScanStreamError, match=r"pass 2 .*the pose stream failed during the pass"):
        scanned(cfg, after_pass(1, jump))
    assert surface_error_mm(cfg.parent / "out" / "scan.ply", centre, r)[0].max() < SURFACE_TOLERANCE_MM


@pytest.mark.slow
def test_validate_measures_on_the_fly_and_the_sphere_passes_within_the_limits(cell_truth):
    """The sphere at four new views, each one pass at the scan's speed and rate, mapped
    through the true clock relation: P_F, P_S and the centres' spread within their MPEs."""
    from spherecal.app.validate import run_validate

    cfg, *_ = cell_truth
    lines = []
    outcome = run_validate(load_config(cfg), report=False, yes=True, log=lambda m: lines.append(str(m)))
    assert any(x.startswith("validating on the fly: 4 passes at 100 mm/s") for x in lines)
    assert any("398." in x or "400.0 a second while streaming" in x for x in lines)
    rows = outcome.table()
    assert outcome.passed and rows["P_F"]["max error (mm)"] < 0.25 and abs(rows["P_S"]["max error (mm)"]) < 0.06
    assert rows["centre spread"]["max error (mm)"] < 0.1
    assert all(len(pr.fit.centre_mm) == 3 and pr.fit.n_points_used > 10_000 for pr in outcome.report.probing)
    shots = dataio.read_dataset(next((cfg.parent / "out").glob("validation-*.jsonl")))
    assert {o.station for o in shots.observations} == {"P1-sphere", "P2-sphere", "P3-sphere", "P4-sphere"}
    assert len(shots.observations) == sum(pr.n_shots for pr in outcome.report.probing)
