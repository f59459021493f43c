"""The exports of a run through the CLI: [export] chooses the exporters and sets them
up, a bad [export] stops before anything moves, `spherecal solve` writes the exporters
of the dataset's robot, and calibration_finished hands plugins the output folder and
the robot type."""

import pytest

from spherecal.io import dataset as dataio

from spherecal.app import plugin_host
from spherecal.cli import EXIT_OK, EXIT_USAGE, main
from spherecal.plugins.host import PluginHost
from spherecal.report import export as ex
from spherecal.robots.abb_irb2400.export import read_rapid
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

from tests.cli.test_no_overwrite import REPLAY
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def dataset():
    cell = standard_cell("eye_in_hand", seed=5, fov=reference_fov(n_columns=160))
    return simulate_dataset(cell, SweepPlan(profiles_per_station=6))


@pytest.fixture
def dataset_file(tmp_path, dataset):
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, dataset)
    return path


class Recorder:
    """A plugin of another robot brand and one written for the hook's two-argument form."""

    def __init__(self):
        self.calls = []

    def spherecal_calibration_finished(self, result, out_dir, exports_written, robot_type, sensor_type):
        self.calls.append((robot_type, sensor_type, out_dir, exports_written))
        if robot_type == "abb_irb2400" and exports_written:  # its own runs only, no provenance parsing
            (out_dir / "abb_extra.txt").write_text(result.transform_name + "\n")


class OldStyle:
    def __init__(self):
        self.got = []

    def spherecal_calibration_finished(self, result, dataset):
        self.got.append((result.transform_name, len(dataset.observations)))


@pytest.fixture
def plugins(monkeypatch):
    rec, old = Recorder(), OldStyle()
    monkeypatch.setattr(plugin_host, "make_host", lambda enable=None: PluginHost(plugins=[("recorder", rec),
                                                                                     ("old_style", old)]))
    return rec, old


EXPORT = """
[export]
run = ["abb_rapid", "ros2"]
[export.abb_rapid]
tool_name = "tLaser"
module_name = "Cell3"
mass_kg = 1.85
cog_mm = [0.0, -10.0, 70.0]
[export.ros2]
frame_id = "robot1/tool0"
child_frame_id = "laser"
"""


def test_export_section_chooses_and_sets_up_the_exporters(tmp_path, dataset_file, plugins, capsys):
    cfg = tmp_path / "replay.toml"
    cfg.write_text(REPLAY.format(data=dataset_file) + EXPORT)
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_OK
    out = tmp_path / "out"
    written = {p.name for p in out.iterdir()}
    # no matrices: not in run; run.log is the record of the run
    assert written == {"Cell3.mod", *ex.ROS2_FILES, "result.json", "abb_extra.txt", "run.log"}
    result = dataio.read_result(out / "result.json")
    d = read_rapid((out / "Cell3.mod").read_text())
    assert (d["kind"], d["name"], d["mass_kg"]) == ("tooldata", "tLaser", 1.85)
    assert list(d["cog_mm"]) == [0.0, -10.0, 70.0]
    ros = ex.read_ros_launch((out / "ros_static_transform.launch.py").read_text())
    assert (ros["frame_id"], ros["child_frame_id"]) == ("robot1/tool0", "laser")
    assert ex.read_ros_urdf_joint((out / "ros_sensor_joint.urdf.xacro").read_text())["frame_id"] == "robot1/tool0"
    rec, old = plugins
    assert rec.calls == [("abb_irb2400", "nxsensor_i", out, True)]
    assert (out / "abb_extra.txt").read_text() == f"{result.transform_name}\n"
    assert old.got == [("flange_from_sensor", len(dataio.read_dataset(dataset_file).observations))]


@pytest.mark.parametrize("export, message", [
    ("[export.abb_rapid]\nmass_kg = 0\n", "export.abb_rapid.mass_kg: Input should be greater than 0"),
    ("[export.abb_rapid]\ntool_nam = 'tLaser'\n", "export.abb_rapid.tool_nam: unknown key"),
    ("[export]\nrun = ['matrices']\n", "export.run[0]: unknown exporter 'matrices'"),
    ("[export.ros2]\nframe_id = 'tool 0'\n", "export.ros2.frame_id: frame_id 'tool 0' is not a valid tf2"),
])
def test_a_bad_export_section_stops_before_anything_moves(sim_config, capsys, export, message):
    cfg = sim_config()
    cfg.write_text(cfg.read_text() + "\n" + export)
    assert main(["calibrate", str(cfg)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert str(cfg) in err and message in err, err
    assert not (cfg.parent / "out").exists()


def test_solve_writes_the_exporters_of_the_datasets_robot(tmp_path, dataset, plugins):
    exported = {}
    for robot in ("abb_irb2400", "another_robot"):
        path = tmp_path / f"{robot}.jsonl"
        dataio.write_dataset(path, dataset.model_copy(update={"provenance": {**dataset.provenance, "robot": robot}}))
        out = tmp_path / f"{robot}.out"
        assert main(["solve", str(path), "--out", str(out), "--no-report"]) == EXIT_OK
        exported[robot] = {p.name for p in out.iterdir()}
    assert exported["abb_irb2400"] - exported["another_robot"] == {"SpherecalSensor.mod", "abb_extra.txt"}
    assert {"flange_from_sensor_4x4.txt", "ros_static_transform.launch.py"} <= exported["another_robot"]
    assert [c[0] for c in plugins[0].calls] == ["abb_irb2400", "another_robot"]
