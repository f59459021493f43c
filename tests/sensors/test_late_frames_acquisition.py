"""Late sensor frames in a full simulated acquisition never pair a profile with
another shot's pose.

The example eye-in-hand cell, its devices behind their real protocols (the IRB 2400
driver over the simulated controller, the nxSensor-I driver over the simulated pyusb
device), the acquisition of the ``calibrate`` command and the solver. Late frames are
injected at random triggers: the device then makes the next read time out although the
frame is on its way, and delivers it to a later read. Every profile kept must be the
one the device measured at the pose of its own shot (the device's record, looked up by
the profile's shot id, the frame counter), and the result must be that of a run without
faults: the simulated cell draws its noise per pose, so the same shots give the same
numbers.

The case that matters most is two late frames in one shot: a frame left queued would
make every later profile the previous shot's, a silent error (exit 0, 2.07 deg and
2.75 mm off the truth in this cell).
"""

import io
import re
from pathlib import Path

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.motion.acquisition import Progress, acquire, plan_targets
from spherecal.config import load_config
from spherecal.estimation import solve
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.plugin_host import make_host, open_devices
from spherecal.app.solving import calibration_options
from spherecal.sensors.nxsensor_i import SimulatedNxSensorBackend

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sim-eye-in-hand.toml"
HALF_COUNT_MM = 0.005 / 2 + 1e-9
SHOTS = 20


@pytest.fixture(scope="module")
def config_path(tmp_path_factory):
    """The example cell with an exact arm (the station robot error model, fast to solve),
    five shots per station, and up to five attempts per profile (five late frames may
    hit one shot; with fewer retries that shot stops the run with a DeviceError)."""
    text = EXAMPLE.read_text()
    text, n = re.subn(r"(?m)^\[simulation\.robot_error\]\n(?:[a-z_]+ = .*\n)+", "", text)
    assert n == 1
    text = text.replace("[calibration]\n", '[calibration]\nrobot_error_model = "station"\n')
    text = text.replace("profiles_per_station = 10", "profiles_per_station = 5")
    text = text.replace('[sensor]\ntype = "nxsensor_i"\n', '[sensor]\ntype = "nxsensor_i"\nretries = 5\ntimeout_ms = 20\n')
    path = tmp_path_factory.mktemp("late") / "cell.toml"
    path.write_text(text)
    return path


def acquire_with_late_frames(config_path: Path, journal: Path, late_at_triggers: list[int]):
    """Run the acquisition, with a late frame after each trigger numbered in
    ``late_at_triggers`` (0-based, counting every trigger sent, re-triggers included),
    and audit every observation against the device's record. Returns (dataset, the
    configuration, the cell, the sensor driver, log lines)."""
    host = make_host()
    loaded, fov = configured_for_sensor(load_config(config_path), host)  # the sweep's standoff: the sensor's
    cfg = loaded.config
    cell = make_cell(cfg, field_of_view=fov)
    targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere)
    assert len(targets) == SHOTS
    logs, true_poses = [], []
    with open_devices(loaded, host, cell, logs.append) as (robot, sensor):
        backend = sensor._dev.backend
        assert isinstance(backend, SimulatedNxSensorBackend)
        execute, triggers = backend._execute, [0]

        def execute_with_faults(command):
            execute(command)
            if command.name == "trigger":
                backend.inject_late_frames(late_at_triggers.count(triggers[0]))
                triggers[0] += 1

        backend._execute = execute_with_faults
        with dataio.DatasetWriter(journal, mounting=cfg.mounting, sphere_radius_mm=cfg.sphere.radius_mm) as writer:
            # at each observation the simulated robot still stands where the shot was taken
            acquire(robot, sensor, targets, writer, cfg.acquisition, log=logs.append,
                    on_observation=lambda obs: true_poses.append(cell.current_base_from_flange),
                    progress=Progress(SHOTS, io.StringIO()))
    dataset = dataio.read_dataset(journal)
    assert len(dataset.observations) == SHOTS
    for obs, true_pose in zip(dataset.observations, true_poses):
        counter = int(obs.profile.shot_id)
        records = [i for i, (c, _) in enumerate(backend.measured) if c == counter]
        assert len(records) == 1
        measured_points, measured_at = backend.measured[records[0]][1], backend.measured_poses[records[0]]
        assert measured_at is true_pose, f"observation {obs.index}: profile {counter} measured at another pose"
        assert np.max(np.abs(obs.profile.points_mm - measured_points)) <= HALF_COUNT_MM
    return dataset, cfg, cell, sensor, logs


@pytest.fixture(scope="module")
def clean(config_path, tmp_path_factory):
    dataset, cfg, cell, sensor, _ = acquire_with_late_frames(config_path, tmp_path_factory.mktemp("clean") / "j.jsonl", [])
    assert sensor.frames_discarded == 0
    return dataset, solve(dataset, calibration_options(cfg)).result


def late_triggers(n_late: int, seed: int) -> list[int]:
    """``n_late`` random triggers among the first SHOTS; they may repeat (several late
    reads in one shot)."""
    return sorted(np.random.default_rng(seed).integers(0, SHOTS, n_late).tolist())


def same_observations(a, b) -> bool:
    return all(x.base_from_flange == y.base_from_flange and np.array_equal(x.profile.points_mm, y.profile.points_mm)
               for x, y in zip(a.observations, b.observations, strict=True))


@pytest.mark.parametrize("n_late", [1, 2, 5])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_profile_is_paired_with_its_own_pose(config_path, clean, tmp_path, n_late, seed):
    dataset, _cfg, _cell, sensor, logs = acquire_with_late_frames(
        config_path, tmp_path / "j.jsonl", late_triggers(n_late, seed))
    # each late frame was its shot's first: the shot's re-triggered frames were discarded by number
    assert sensor.frames_discarded == n_late
    assert sum("measured for an earlier shot" in m for m in logs) == n_late
    # so the dataset is the fault-free run's, to the last bit
    assert same_observations(dataset, clean[0])


def test_the_result_is_the_fault_free_one(config_path, clean, tmp_path):
    late = late_triggers(5, seed=3)
    assert len(set(late)) < len(late)  # two late reads in one shot: the case that can leave a frame queued
    dataset, cfg, cell, _sensor, _ = acquire_with_late_frames(config_path, tmp_path / "j.jsonl", late)
    result = solve(dataset, calibration_options(cfg)).result
    assert np.array_equal(result.transform.as_matrix(), clean[1].transform.as_matrix())
    true = cell.true_transform
    angle_deg = geo.rotation_angle_deg(true.rotation_matrix, result.transform.rotation_matrix)
    offset_mm = np.linalg.norm(true.translation - result.transform.translation)
    assert angle_deg < 5 * np.linalg.norm(result.std_rotation_deg)
    assert offset_mm < 5 * np.linalg.norm(result.std_translation_mm)
