"""The verdict on a kinematic calibration judges what the user relies on: a point at a new
pose placed through the calibrated arm and the transform together, measured by
predicting each station from the others. Not the transform's own uncertainty: with the
arm's geometry identified it trades with the arm's parameters (a gauge), and in
eye-to-hand it is tenths of a millimetre where the prediction is hundredths. Known
answers from the simulator: its true transform and the sphere seen from fresh stations."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.models import Pose
from spherecal.estimation import solve
from spherecal.io import dataset as dataio
from spherecal.motion.kinematic_plan import plan_kinematic_stations
from spherecal.plugins.host import PluginHost
from spherecal.report.assess import advice, verdict
from spherecal.sim import RobotErrorModel, SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov
from test_kinematic_model import NOISE, OPTIONS, PLANS, _fresh_centres, planned_config

KINEMATIC = OPTIONS.model_copy(update={"identify_kinematics": True})


@pytest.fixture(scope="module")
def kin():
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


@pytest.fixture(scope="module")
def planned_e2h(kin, tmp_path_factory):
    """The kinematic planner's 20 stations for the eye-to-hand example cell."""
    return _plan(planned_config(tmp_path_factory.mktemp("plan"), "eye_to_hand"), kin).sweep


def _calibrate(kin, sweep, transform=None, seed=11):
    """A kinematic calibration of the simulated eye-to-hand cell, its arm off its nominal
    geometry (flange 0.5-2 mm off); ``transform(dataset)`` alters the data first."""
    cell = standard_cell("eye_to_hand", seed=seed, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    ds = simulate_dataset(cell, sweep)
    sol = solve(transform(ds) if transform else ds, KINEMATIC, kinematics=kin)
    identified = np.array(sol.refined.diagnostics["kinematic_effects"]["identified"])
    fresh = _fresh_centres(cell, kin, sol, np.where(identified, sol.refined.kinematic_errors, 0.0),
                           PLANS["eye_to_hand"][1])
    fresh_rms = float(np.sqrt(np.mean(np.sum((fresh - sol.refined.centre) ** 2, axis=1))))
    return cell, sol, fresh_rms


def test_a_right_eye_to_hand_kinematic_calibration_is_not_red(kin, planned_e2h, tmp_path):
    """Right by the truth: the true transform within 3 reported standard deviations, and
    the sphere seen from 4 fresh stations, placed through the calibrated arm and the
    transform, within 0.05 mm RMS of where the calibration puts it. The transform's own
    translation 1-sigma relative to the robot's frame is above the red limit (it trades
    with the arm's parameters); the verdict grades the prediction at left-out stations
    instead, which agrees with the fresh stations and with what the noise explains, and
    gives the transform's figures labelled as gauge-dependent, ungraded. The figures
    survive result.json."""
    cell, sol, fresh_rms = _calibrate(kin, planned_e2h)
    X = cell.true_transform
    e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
    assert np.all(np.abs(e) < 3 * np.sqrt(np.diag(sol.refined.covariance)[:6])), e
    assert fresh_rms < 0.05, fresh_rms
    re = sol.result.robot_error
    assert max(re.std_translation_mm_robot_frame) > 0.3  # what made it RED
    pred = re.station_prediction
    assert pred is not None and not pred.unpredictable_stations and len(pred.per_station_mm) == 20
    assert pred.rms_mm < 0.05 and pred.rms_mm < 2.5 * fresh_rms + 0.01
    assert 0.6 < pred.rms_mm / pred.expected_rms_mm < 1.5
    v = verdict(sol.result)
    assert v.level == "green", v.reasons
    assert v.headline.startswith("Good: residuals as expected, and a point at a new pose placed through the calibrated")
    assert any(text.startswith("a point at a new pose, through the calibrated arm and the transform: the sphere at "
                               f"each station, predicted from the other stations, lies {pred.rms_mm:.4f} mm RMS")
               for _, text in v.reasons)
    (gauge,) = [text for _, text in v.reasons if text.startswith("the transform alone")]
    assert "not graded, gauge-dependent" in gauge and f"{max(re.std_translation_mm_robot_frame):.4f} mm" in gauge
    assert not [a for a in advice(sol.result) if a.key.startswith(("translation", "rotation", "prediction"))]
    dataio.write_result(tmp_path / "result.json", sol.result)
    back = dataio.read_result(tmp_path / "result.json")
    assert back.robot_error.station_prediction == pred and verdict(back).level == "green"


def _shift_stations(size_mm: float, seed: int):
    """Each station's reported poses moved by one random offset (``size_mm`` per axis):
    an arm error no geometric model holds (thermal drift between stations, say)."""
    def transform(ds):
        rng = np.random.default_rng(seed)
        offsets: dict[str, np.ndarray] = {}
        obs = []
        for o in ds.observations:
            d = offsets.setdefault(o.station, rng.normal(size=3) * size_mm)
            p = o.base_from_flange
            obs.append(o.model_copy(update={"base_from_flange": Pose.from_rt(p.rotation_matrix, p.translation + d)}))
        return ds.model_copy(update={"observations": obs})
    return transform


def _radius_off(mm: float):
    return lambda ds: ds.model_copy(update={"sphere_radius_mm": ds.sphere_radius_mm + mm})


@pytest.mark.slow
@pytest.mark.parametrize("case, level", [("four stations", "red"), ("arm error not geometric", "amber"),
                                         ("radius 0.2 mm off", "red")])
def test_a_wrong_kinematic_calibration_is_not_green(kin, planned_e2h, case, level):
    """Wrong answers, by the truth (the sphere at fresh stations more than 0.05 mm off
    where the calibration puts it), are not accepted, the prediction at left-out
    stations saying why: a plan that does not identify the arm's geometry (the default
    four stations, each fitted well by the others' model and predicted tenths of a
    millimetre off without it: RED), an arm error that no geometric model holds (each
    station's poses off by 0.08 mm per axis: predictions 0.17 mm off, 2.5 x what the
    noise explains: AMBER, the residuals alone 1.6 x) and a wrong radius (the transform
    tens of millimetres off: RED)."""
    sweep, transform = {
        "four stations": (SweepPlan(profiles_per_station=5), None),
        "arm error not geometric": (planned_e2h, _shift_stations(0.08, 12)),
        "radius 0.2 mm off": (planned_e2h, _radius_off(0.2)),
    }[case]
    _, sol, fresh_rms = _calibrate(kin, sweep, transform, seed=12)
    assert fresh_rms > 0.05, fresh_rms
    v = verdict(sol.result)
    assert v.level == level, v.reasons
    pred = sol.result.robot_error.station_prediction
    flagged = [text for lv, text in v.reasons if lv != "green"]
    assert [t for t in flagged if t.startswith("a point at a new pose, through the calibrated arm")], flagged
    (adv,) = [a for a in advice(sol.result) if a.key == "prediction_poor"]
    if case == "four stations":
        assert pred.rms_mm > 0.3 and "The stations do not determine the arm's geometry" in adv.text
    if case == "arm error not geometric":
        assert pred.rms_mm > 0.1 and pred.rms_mm / pred.expected_rms_mm > 2
        assert "the arm's error is not all geometric" in adv.text


def _plan(cfg, kin):
    """The kinematic planner's stations for the configuration ``cfg``, on the arm ``kin``."""
    return plan_kinematic_stations(cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere,
                                   kin)
