"""examples/sim-ur5-urdf-eye-in-hand.toml end to end: `spherecal calibrate` with a UR5
described only by its URDF (the built-in urdf robot type) on a cell laid out for its
reach, through the line protocol to the simulated controller; the result agrees with the
simulated truth and the error against it is printed."""

import re

from spherecal.cli import EXIT_OK, main

from .conftest import EXAMPLES
from .test_calibrate import check_against_truth


def test_ur5_from_its_urdf_calibrates_end_to_end(sim_config, capsys):
    urdf = (EXAMPLES / "robots" / "ur5.urdf").as_posix()
    cfg = sim_config("sim-ur5-urdf-eye-in-hand.toml", **{
        r'^urdf = "robots/ur5.urdf"': f'urdf = "{urdf}"',
        r"^profiles_per_station = 10$": "profiles_per_station = 6",  # a smaller plan keeps the test short
    })
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_OK
    journal, result = check_against_truth(cfg.parent / "out")
    assert journal.provenance["robot"] == "urdf" and len(journal.observations) == 24
    assert all(len(o.joints_deg) == 6 for o in journal.observations)
    # the cell is the UR5's, not the IRB 2400's: the sphere within its reach of ~940 mm
    assert journal.provenance["true_sphere_centre_mm"] == [605.0, -45.0, -41.0]
    printed = capsys.readouterr().out
    m = re.search(r"simulated truth: error ([0-9.]+) deg, ([0-9.]+) mm", printed)
    assert m, printed[-2000:]
    assert float(m.group(1)) < 0.1 and float(m.group(2)) < 0.5
