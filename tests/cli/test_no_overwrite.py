"""Files are never overwritten or escaped: solve into a calibration run's
folder, calibrate into a folder with an unrelated result, --resume on a finished run,
planted symbolic links, a PLY path outside the output folder, a full disk."""

import errno
import os

import numpy as np
import pytest

from spherecal.io import dataset as dataio, files as safeio
from spherecal.cli import EXIT_DATA, EXIT_OK, EXIT_USAGE, main
from spherecal.core.errors import FileWriteError, InputError
from spherecal.core.models import Observation, Pose, Profile
from spherecal.io.ply import PlyWriter
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def dataset_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "data.jsonl"
    cell = standard_cell("eye_in_hand", seed=5, fov=reference_fov(n_columns=160))
    dataio.write_dataset(path, simulate_dataset(cell, SweepPlan(profiles_per_station=6)))
    return path


def snapshot(folder):
    return {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in folder.iterdir() if p.is_file()}


@pytest.mark.parametrize("planted", ["result.json", "report.html", "flange_from_sensor_4x4.txt", "journal.jsonl+result.json"])
def test_solve_refuses_a_folder_holding_a_result_and_names_the_file(tmp_path, dataset_file, capsys, planted):
    out = tmp_path / "run"
    out.mkdir()
    for name in planted.split("+"):
        (out / name).write_text("someone else's\n")
    before = snapshot(out)
    assert main(["solve", str(dataset_file), "--out", str(out), "--no-report"]) == EXIT_DATA
    err = capsys.readouterr().err
    named = planted.split("+")[-1]
    assert str(out / named) in err and "--overwrite" in err and "new folder" in err
    if "journal" in planted:
        assert "a calibration run" in err
    assert snapshot(out) == before


@pytest.mark.parametrize("where", ["read-only folder", "under a file"])
def test_an_output_folder_that_cannot_be_written_is_refused_before_any_work(tmp_path, dataset_file, monkeypatch,
                                                                           capsys, sim_config, where):
    """solve before it reads the dataset, calibrate before it connects to a device: a
    folder the run could not write its files into fails at once, named, with what to do."""
    if where == "read-only folder":
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            pytest.skip("root writes into a read-only folder")
        out = tmp_path / "locked"
        out.mkdir()
        out.chmod(0o500)
    else:
        (tmp_path / "a-file").write_text("not a folder\n")
        out = tmp_path / "a-file" / "run"
    import spherecal.cli.calibrate as calibrate_command

    def no_work(*args, **kwargs):
        raise AssertionError("the work began")

    monkeypatch.setattr(dataio, "read_dataset", no_work)
    monkeypatch.setattr(calibrate_command, "run_calibrate", no_work)
    try:
        for argv in (["solve", str(dataset_file)], ["calibrate", str(sim_config())]):
            assert main([*argv, "--out", str(out), "--no-report"]) == EXIT_DATA
            err = capsys.readouterr().err
            assert f"spherecal: error: {out}" in err and "give another folder with --out" in err
    finally:
        if where == "read-only folder":
            out.chmod(0o700)


def test_the_folder_check_writes_where_permissions_do_not_tell(tmp_path):
    """An existing folder is probed by creating a file in it, which also catches what
    permission bits do not (root in a folder the kernel will not let anyone write: /sys);
    the probe leaves nothing behind where it can write."""
    import pathlib

    safeio.check_output_folder_writable(tmp_path)
    assert list(tmp_path.iterdir()) == []
    sysfs = pathlib.Path("/sys")
    if not sysfs.is_dir():
        pytest.skip("no /sys on this system")
    with pytest.raises(FileWriteError, match=r"^/sys: cannot write into this folder \("):
        safeio.check_output_folder_writable(sysfs)


def test_solve_overwrite_replaces_on_request(tmp_path, dataset_file):
    out = tmp_path / "run"
    assert main(["solve", str(dataset_file), "--out", str(out), "--no-report"]) == EXIT_OK
    assert main(["solve", str(dataset_file), "--out", str(out), "--no-report"]) == EXIT_DATA
    assert main(["solve", str(dataset_file), "--out", str(out), "--no-report", "--overwrite"]) == EXIT_OK


def test_calibrate_refuses_a_folder_with_an_unrelated_result_before_moving(sim_config, capsys):
    cfg = sim_config()
    out = cfg.parent / "out"
    out.mkdir()
    (out / "result.json").write_text("{}\n")
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_DATA
    assert str(out / "result.json") in capsys.readouterr().err
    assert not (out / "journal.jsonl").exists()  # nothing acquired
    assert (out / "result.json").read_text() == "{}\n"


REPLAY = """mounting = "eye_in_hand"
output_dir = "out"
replay = "{data}"
[nominal_transform]
translation_mm = [44.5, -19.8, 166.2]
quaternion_wxyz = [0.02714, -0.96565, 0.25663, 0.03026]
[sphere]
radius_mm = 19.1
[robot]
type = "abb_irb2400"
[sensor]
type = "nxsensor_i"
"""


def test_resume_of_a_finished_run_rewrites_nothing(tmp_path, dataset_file, capsys):
    cfg = tmp_path / "replay.toml"
    cfg.write_text(REPLAY.format(data=dataset_file))
    assert main(["calibrate", str(cfg)]) == EXIT_OK
    out = tmp_path / "out"
    before = snapshot(out)
    assert "result.json" in before and "report.html" in before
    capsys.readouterr()
    assert main(["calibrate", str(cfg), "--resume"]) == EXIT_OK
    cap = capsys.readouterr()
    assert f"holds a finished run ({out / 'result.json'}): nothing to resume" in cap.out
    assert (cap.out + cap.err).count("finished run") == 1  # said once
    log = before.pop("run.log")[0]
    after = snapshot(out)
    # only the record of runs grows (appended, never rewritten): it says what the command did
    assert after.pop("run.log")[0].startswith(log) and after == before
    assert main(["calibrate", str(cfg)]) == EXIT_DATA  # a second run into the same folder is refused
    after = snapshot(out)
    assert b"already holds a result" in after.pop("run.log")[0] and after == before  # the refusal, recorded


def test_writers_refuse_a_planted_symbolic_link(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    out = tmp_path / "out"
    out.mkdir()
    link = out / "report.html"
    link.symlink_to(victim)
    with pytest.raises(InputError, match="symbolic link") as exc:
        safeio.write_text(link, "<html>")
    assert str(link) in str(exc.value)
    dangling = out / "x.png"
    dangling.symlink_to(tmp_path / "nowhere.png")
    with pytest.raises(InputError, match="symbolic link"):
        safeio.write_bytes(dangling, b"png")
    assert not (tmp_path / "nowhere.png").exists()
    ply = out / "scan.ply"
    ply.symlink_to(victim)
    with pytest.raises(InputError, match="symbolic link"):
        PlyWriter(ply)
    assert victim.read_text() == "precious\n"


@pytest.mark.slow
def test_the_report_and_exports_refuse_a_link(tmp_path, dataset_file):
    from spherecal.estimation import solve
    from spherecal.plugins.host import PluginHost
    from spherecal.report.export import write_exports
    from spherecal.plugins.host import PluginHost
    from spherecal.report.html import write_report

    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    sol = solve(dataio.read_dataset(dataset_file))
    out = tmp_path / "out"
    out.mkdir()
    (out / "report_sphere_3d.png").symlink_to(victim)
    with pytest.raises(InputError, match="report_sphere_3d.png is a symbolic link"):
        write_report(sol, out)
    (out / "SpherecalSensor.mod").symlink_to(victim)
    with pytest.raises(InputError, match="SpherecalSensor.mod is a symbolic link"):
        write_exports(sol.result, out, PluginHost().export_plan(None, sol.result.mounting, None), overwrite=True)
    assert not (out / "result.json").exists()  # nothing written when one is refused
    assert victim.read_text() == "precious\n"


@pytest.mark.parametrize("ply", ["../escaped.ply", "sub/../../escaped.ply", "/tmp/spherecal-escaped.ply"])
def test_a_ply_path_outside_the_output_folder_is_refused(sim_config, capsys, ply):
    from tests.cli.test_validate_scan import write_result_with

    cfg = sim_config(exact_arm=True, **{r"^passes = 2$": f"passes = 2\nply = '{ply}'"})
    write_result_with(cfg.parent / "out", cfg, Pose.identity())
    assert main(["scan", str(cfg)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "scan.ply" in err and ply in err and "ply_outside_output_dir" in err
    assert not (cfg.parent / "escaped.ply").exists()


def test_a_full_disk_names_the_journal_and_says_resume(tmp_path, monkeypatch):
    w = dataio.DatasetWriter(tmp_path / "journal.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.1)

    def full(*a):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(w._file, "write", full)
    obs = Observation(index=0, station="S1", timestamp="2024-01-01T00:00:00+00:00",
                      base_from_flange=Pose.from_xyz_quat_wxyz((1, 2, 3), (1, 0, 0, 0)),
                      profile=Profile(y_mm=np.zeros(3), z_mm=np.zeros(3)))
    with pytest.raises(FileWriteError, match="journal.jsonl: cannot write .No space left on device") as exc:
        w.append(obs)
    assert "kept" in str(exc.value)


def test_a_full_disk_in_calibrate_says_resume(tmp_path, monkeypatch, dataset_file, capsys):
    from spherecal.app import calibrate

    def full(*a, **k):
        raise FileWriteError(f"{tmp_path}/out/journal.jsonl: cannot write (No space left on device)")

    monkeypatch.setattr(calibrate, "solve_and_write", full)
    cfg = tmp_path / "replay.toml"
    cfg.write_text(REPLAY.format(data=dataset_file))
    assert main(["calibrate", str(cfg)]) == EXIT_DATA
    err = capsys.readouterr().err
    # a replay keeps no journal of shots in its output folder: nothing to resume there
    assert "journal.jsonl: cannot write" in err and "nothing to resume, run the same command again" in err


def test_a_full_disk_while_scanning_names_the_ply(tmp_path, monkeypatch):
    w = PlyWriter(tmp_path / "scan.ply", with_profile=True)

    def full(*a):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(w._file, "write", full)
    with pytest.raises(FileWriteError, match=r"scan.ply: cannot write .No space left on device"):
        w.write(np.zeros((3, 3)), profile=np.zeros(3, dtype=int))


@pytest.mark.slow
@pytest.mark.parametrize("planted", ["report.html", "report_sphere_3d.png", "flange_from_sensor_4x4.txt"])
def test_overwrite_with_a_planted_link_writes_nothing_at_all(tmp_path, dataset_file, capsys, planted):
    """--overwrite replaces a result's files, never through a link: the run is refused
    before anything is written, not after writing the files that precede the link."""
    out = tmp_path / "res"
    assert main(["solve", str(dataset_file), "--out", str(out)]) == EXIT_OK
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (out / planted).unlink()
    (out / planted).symlink_to(victim)
    before = snapshot(out)
    capsys.readouterr()
    assert main(["solve", str(dataset_file), "--out", str(out), "--overwrite"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert f"{out / planted} is a symbolic link" in err
    after = snapshot(out)
    assert after.pop("run.log")[0].startswith(before.pop("run.log")[0])  # run.log: this run's record added
    assert after == before  # not one file rewritten
    assert victim.read_text() == "precious\n"


def test_a_ply_planted_as_a_link_is_named_as_a_link(sim_config, capsys, tmp_path):
    from tests.cli.test_validate_scan import write_result_with

    cfg = sim_config(exact_arm=True)
    write_result_with(cfg.parent / "out", cfg, Pose.identity())
    victim = tmp_path / "victim.ply"
    victim.write_text("precious\n")
    (cfg.parent / "out" / "scan.ply").symlink_to(victim)
    assert main(["scan", str(cfg)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "scan.ply is a symbolic link" in err and "outside the output folder" not in err
    assert victim.read_text() == "precious\n"


def test_a_planted_link_is_named_as_a_link_without_overwrite_too(tmp_path, dataset_file, capsys):
    out = tmp_path / "res"
    out.mkdir()
    victim = tmp_path / "victim.html"
    victim.write_text("precious\n")
    (out / "report.html").symlink_to(victim)
    assert main(["solve", str(dataset_file), "--out", str(out)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert f"{out / 'report.html'} is a symbolic link" in err and "--overwrite" not in err
    assert victim.read_text() == "precious\n"
