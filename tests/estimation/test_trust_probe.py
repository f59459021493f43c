"""Inputs a user can give by mistake, or a published table gives as it is, that today end
in a crash, a silent wrong answer or a wrong cause blamed. Each test states what the tool
should do instead: a clear error naming the cause (and the row, the field, the file), or a
result that says what it cannot exclude."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.cli import EXIT_DATA, EXIT_RED, EXIT_USAGE, main
from spherecal.io import dataset as dataio
from spherecal.sim import NoiseModel, SweepPlan, simulate_centre_dataset, standard_cell
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
#: Stations tilted about 20 deg from each other, as a hand-held teach pendant session gives them.
TILTS_20 = [(0.0, 0.0, 0.0), (20.0, 0.0, 0.0), (0.0, 20.0, 0.0), (0.0, 0.0, 20.0), (-20.0, 0.0, 0.0)]


def _solve(tmp_path, capsys, ds, *extra):
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, ds)
    out = tmp_path / "res"
    code = main(["solve", str(path), "--out", str(out), "--no-report", *extra])
    cap = capsys.readouterr()
    return code, cap.out, cap.err, out


# --- quaternions written (x, y, z, w) in a sphere-centre table --------------------------------------

def _quaternions_xyzw(ds):
    """The poses as a tool writing quaternions scalar last gives them, read w first."""
    return ds.model_copy(update={"observations": [
        o.model_copy(update={"base_from_flange": o.base_from_flange.model_copy(update={
            "quaternion_wxyz": np.roll(np.asarray(o.base_from_flange.quaternion_wxyz), -1)})})
        for o in ds.observations]})


def _xyzw_centre_table(mounting: str):
    cell = standard_cell(mounting, seed=1, noise=NOISE, fov=reference_fov())
    plan = SweepPlan(profiles_per_station=4, tilts_deg=TILTS_20[:4])
    return _quaternions_xyzw(simulate_centre_dataset(cell, plan, kind="sphere_centre", centre_noise_mm=0.02))


def test_quaternions_written_scalar_last_are_named_before_the_robot_is_blamed(tmp_path, capsys):
    """A sphere-centre table (no joints) whose quaternions are written (x, y, z, w). The
    default robot error model takes the misfit into per-station effects, so the result is
    not absurd and the quaternion-order check never runs; the stations then 'disagree by
    5.0000 deg' (the bound of the station rotation scale, not a measurement) and the
    advice is to calibrate the robot's kinematics. A disagreement of degrees, or of
    millimetres beyond any arm's error, is a data error: the quaternion-order check (and
    the mounting and radius checks) must run before the robot is blamed, here name the
    order, and kinematic calibration must not be advised."""
    code, out, err, _ = _solve(tmp_path, capsys, _xyzw_centre_table("eye_in_hand"))
    text = out + err
    assert code in (EXIT_DATA, EXIT_RED), (code, text)
    assert "the poses' quaternions are probably written (x, y, z, w)" in text, text
    assert "calibrate the robot's kinematics" not in text, text


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_kinematic_calibration_is_never_advised_for_an_implausible_disagreement(mounting):
    """The advice to calibrate the robot's kinematics fits an arm whose stations disagree
    by what an arm's geometry can do (tenths of a millimetre to a few, hundredths of a
    degree to tenths). Stations of one table disagreeing by degrees (eye-in-hand: the
    5 deg bound) or by tens of millimetres (eye-to-hand: 19 mm) point at the data, not
    the arm: the advice must not send the user to calibrate the robot for it."""
    from spherecal.estimation import CalibrationOptions, solve
    from spherecal.report.assess import advice

    result = solve(_xyzw_centre_table(mounting), CalibrationOptions()).result
    err = result.robot_error
    assert err is not None and (err.station_rotation_deg > 1.0 or err.station_translation_mm > 10.0), err
    said = " ".join(a.text for a in advice(result))
    assert "calibrate the robot's kinematics" not in said, said
