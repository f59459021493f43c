"""examples/sim-ur5-urdf-eye-in-hand.toml end to end: `spherecal calibrate` with a UR5
described only by its URDF (the built-in urdf robot type) on a cell laid out for its
reach, through the line protocol to the simulated controller; the result agrees with the
simulated truth and the error against it is printed."""

import re
from pathlib import Path

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.cli import EXIT_OK, main
from spherecal.core.models import Pose

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.slow
def test_ur5_from_its_urdf_calibrates_end_to_end(sim_config, capsys):
    urdf = (EXAMPLES / "robots" / "ur5.urdf").as_posix()
    cfg = sim_config("sim-ur5-urdf-eye-in-hand.toml", exact_arm=True, **{
        r'^urdf = "robots/ur5.urdf"': f'urdf = "{urdf}"',
        r"^profiles_per_station = 10$": "profiles_per_station = 6",  # a smaller plan (and an exact arm) keeps the test short
    })
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_OK
    out = cfg.parent / "out"
    journal, result = dataio.read_dataset(out / "journal.jsonl"), dataio.read_result(out / "result.json")
    true = Pose.model_validate(journal.provenance["true_transform"])
    # within 5 standard deviations of the truth
    assert geo.rotation_angle_deg(true.rotation_matrix, result.transform.rotation_matrix) < \
        5 * np.linalg.norm(result.std_rotation_deg)
    assert np.linalg.norm(true.translation - result.transform.translation) < 5 * np.linalg.norm(result.std_translation_mm)
    assert journal.provenance["robot"] == "urdf" and len(journal.observations) == 24
    assert all(len(o.joints_deg) == 6 for o in journal.observations)
    # the cell is the UR5's, not the IRB 2400's: the sphere within its reach of ~940 mm
    assert journal.provenance["true_sphere_centre_mm"] == [605.0, -45.0, -41.0]
    printed = capsys.readouterr().out
    m = re.search(r"simulated truth: error ([0-9.]+) deg, ([0-9.]+) mm", printed)
    assert m, printed[-2000:]
    assert float(m.group(1)) < 0.1 and float(m.group(2)) < 0.5
