"""An acquisition whose sensor sees nothing where the plan puts the sphere stops early,
keeps the shots taken, and names the likely causes."""

import pytest

from spherecal.app import calibrate
from spherecal.cli import EXIT_DATA, EXIT_DEVICE, main
from spherecal.io import dataset as dataio
from spherecal.motion import acquisition

#: The nominal quaternion written (x, y, z, w) instead of (w, x, y, z).
SWAPPED = {r"^quaternion_wxyz = \[([^,]+), ([^,]+), ([^,]+), ([^\]]+)\]": r"quaternion_wxyz = [\2, \3, \4, \1]"}


@pytest.mark.parametrize("name, taken, kept", [("sim-eye-in-hand.toml", 11, [*range(8), 10]),
                                               ("sim-eye-to-hand.toml", 13, list(range(10)))])
def test_a_nominal_quaternion_in_the_wrong_order_stops_the_run_early(sim_config, capsys, monkeypatch, name, taken,
                                                                     kept):
    # eye-in-hand: S1's targets 8, 9 and S2's first, 10, see 0, 0 and 6 points;
    # eye-to-hand: S2's targets 10, 11, 12 see nothing (the whole plan: 15 and 4 blind shots).
    # Eye-in-hand the keep-out check refuses this plan before it moves (the next test): the
    # blind stop is seen here without it
    monkeypatch.setattr(calibrate, "keep_out_for", lambda *a, **k: None)
    cfg = sim_config(name, **SWAPPED)
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_DEVICE
    err = capsys.readouterr().err
    assert f"the acquisition stopped after {taken} of 40 targets" in err, err
    assert "sensor saw nothing on 3 targets in a row" in err
    assert "quaternion_wxyz is (w, x, y, z), w first" in err and "acquisition.sphere_centre_mm" in err
    assert "the mounting (eye_in_hand or eye_to_hand)" in err and 'mounting = "' in err
    journal = dataio.read_dataset(cfg.parent / "out" / "journal.jsonl")
    assert [o.target for o in journal.observations] == kept, "every shot with points is kept"
    assert f"the {len(kept)} shots taken this run are kept in the journal" in err
    assert not (cfg.parent / "out" / "result.json").exists()


def test_eye_in_hand_the_keep_out_check_refuses_that_plan_before_any_motion(sim_config, capsys):
    """Read with the nominal quaternion written (x, y, z, w), the plan turns the sensor to
    look at the sphere from the side: its body runs into the sphere's stand at station S2.
    The plan is refused before anything moves, naming the nominal transform."""
    cfg = sim_config(**SWAPPED)
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "the plan brings the sensor's body within keep_out.clearance_mm = 5 mm of the sphere or its stand" in err
    assert ("targets 10, 11, 12, 13, 14, 15, 16, 17, 18, 19 (10 of 10) of station S2, worst target 10, flange at "
            "[1131.9, 238.0, 493.5] mm: the sensor's body overlaps the stand by 34.2 mm") in err, err
    assert "check [nominal_transform]" in err and "nothing was moved" in err
    assert not (cfg.parent / "out" / "journal.jsonl").exists()


class _Writer:
    next_index = 0

    def __init__(self):
        self.rows = []

    def append(self, obs):
        self.rows.append(obs)
        self.next_index += 1


def test_two_blind_shots_in_a_row_do_not_stop_the_run(monkeypatch):
    """A couple of empty profiles at the edge of the view (not three in a row) are skipped,
    as before; the run goes on to its end."""
    from spherecal.core.models import Pose, Profile
    import numpy as np

    seen = iter([None, None, 30, None, 5, 30, None, None])
    profile = lambda n: None if n is None else Profile(y_mm=np.linspace(-5, 5, n), z_mm=np.full(n, 100.0))  # noqa: E731
    monkeypatch.setattr(acquisition, "move_and_shoot", lambda *a: (Pose.identity(), None, profile(next(seen)), 0))
    targets = [acquisition.Target(k, "S1", Pose.identity(), k == 0, 10.0) for k in range(8)]

    class Acq:
        sphere_centre_mm = (0.0, 0.0, 0.0)

    rep = acquisition.acquire(None, None, targets, _Writer(), Acq(), log=lambda s: None,
                              progress=acquisition.Progress(8, open("/dev/null", "w")))
    assert rep.taken == 3 and len(rep.skipped) == 5
