"""A full disk while the journal is written: the run stops with exit 3, naming the
journal and saying that --resume continues, never an internal error; the lines written
before are kept, and the run resumes once there is space again."""

import errno

import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_DATA, EXIT_OK, main
from spherecal.core.errors import FileWriteError
from reference_sensor import reference_fov


class FullDisk:
    """A journal file on a disk that filled up: every write and flush fails (ENOSPC), as
    buffered data can no longer reach the disk."""

    def __init__(self, file):
        self._file = file

    def write(self, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    def flush(self):
        raise OSError(errno.ENOSPC, "No space left on device")

    def __getattr__(self, name):
        return getattr(self._file, name)


def test_the_writer_names_the_file_and_closes_on_a_full_disk(tmp_path):
    import pytest

    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    obs = simulate_dataset(standard_cell("eye_in_hand", seed=1, fov=reference_fov()),
                           SweepPlan(profiles_per_station=4)).observations
    path = tmp_path / "j.jsonl"
    with pytest.raises(FileWriteError, match=r"j\.jsonl: cannot write \(No space left on device\); the lines "
                                             r"written before are kept"):
        with dataio.DatasetWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05, fsync=True) as w:
            w.append(obs[0])
            w._file = FullDisk(w._file)
            w.append(obs[1])
    assert w.closed
    assert len(dataio.read_dataset(path).observations) == 1
    # the failure shows at close too (buffered lines that cannot be flushed)
    w2 = dataio.DatasetWriter(tmp_path / "k.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.05)
    w2._file = FullDisk(w2._file)
    with pytest.raises(FileWriteError, match=r"k\.jsonl: cannot write"):
        w2.close()


@pytest.mark.slow
def test_calibrate_on_a_full_disk_exits_3_naming_the_journal_and_resumes(sim_config, monkeypatch, capsys):
    path = sim_config()
    append = dataio.DatasetWriter.append
    calls = {"n": 0}

    def filling_up(self, observation):
        calls["n"] += 1
        if calls["n"] == 6:
            self._file = FullDisk(self._file)
        return append(self, observation)

    monkeypatch.setattr(dataio.DatasetWriter, "append", filling_up)
    assert main(["calibrate", str(path)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "journal.jsonl: cannot write (No space left on device)" in err and "--resume" in err
    assert "internal error" not in err
    journal = path.parent / "out" / "journal.jsonl"
    assert len(dataio.read_dataset(journal).observations) == 5
    monkeypatch.setattr(dataio.DatasetWriter, "append", append)  # space again
    assert main(["calibrate", str(path), "--resume"]) == EXIT_OK
