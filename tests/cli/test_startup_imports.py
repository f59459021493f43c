"""Start-up: commands do not import the heavy modules they do not use.
``spherecal --help`` and ``spherecal plugins`` load neither matplotlib, SciPy's spatial
module nor Pinocchio (the robot plugin's kinematics import it on first use), and a
``solve`` without a report loads neither matplotlib nor Pinocchio, nor what only runs
with a configuration file and devices (the other commands,
the acquisition, the planners, the metrology of `validate`, the sensor's USB driver).
Each command runs in a fresh interpreter, which then lists what it imported."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from reference_sensor import reference_fov

HEAVY = ("matplotlib", "scipy.spatial", "pinocchio")
#: What `solve` (a dataset file, no configuration, no devices) has no use for.
RUN_ONLY = ("spherecal.motion.acquisition", "spherecal.motion.kinematic_plan",
            "spherecal.core.metrology", "spherecal.motion.validation", "spherecal.motion.scanning",
            "spherecal.app.calibrate", "spherecal.app.simulate", "spherecal.app.validate", "spherecal.app.scan",
            "spherecal.app.compare", "spherecal.app.cell", "spherecal.app.plan_checks",  # (the other commands)
            "spherecal.cli.calibrate", "spherecal.cli.simulate", "spherecal.cli.validate", "spherecal.cli.scan",
            "spherecal.cli.compare", "spherecal.report.compare",  # (comparing two calibrations)
            "spherecal.config.load", "tomllib",  # (reading a configuration: a solve does with --robot-config only)
            "spherecal.config.sections",  # (the run's sections: a solve needs the estimator's and the report's only)
            "spherecal.sensors.nxsensor_i.driver", "usb",
            "numpy.ma",  # (np.median's NaN check imports it: the estimator's own median does not)
            "spherecal.sim.cell", "spherecal.sim.controller", "xml.etree.ElementTree",  # (the simulated world, URDF)
            "spherecal.robots.abb_irb2400.frames",  # (reading a tooldata line: compare and validate)
            "statistics")  # (the verdict's medians are the estimator's)
#: At most this many ``spherecal`` modules (the built-in plugins' included) for a ``solve``
#: without report: 100 now (the devices' contract brings the pose-streaming one; the flags
#: name clipped or quantised profiles: profile_artefacts; the advice's words for stop-and-go
#: data and for recordings: report.advice_wording). A new one on its path raises the bound
#: knowingly.
MAX_SOLVE_MODULES = 100


def _modules_after(argv: list[str]) -> set[str]:
    code = ("import json, sys\nfrom spherecal import cli\ntry:\n    code = cli.main(json.loads(sys.argv[1]))\n"
            "except SystemExit as exc:\n    code = exc.code\nsys.stdout.flush()\n"
            "print('\\nMODULES ' + json.dumps([code, sorted(sys.modules)]))")
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(argv)], capture_output=True, text=True, timeout=300)
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("MODULES ")]
    assert line, proc.stderr
    exit_code, modules = json.loads(line[-1][len("MODULES "):])
    assert exit_code in (0, None), proc.stderr
    return set(modules)


@pytest.mark.slow
@pytest.mark.parametrize("argv", [["--help"], ["plugins"]])
def test_help_and_plugins_do_not_import_plotting_scipy_spatial_or_pinocchio(argv):
    modules = _modules_after(argv)
    assert "spherecal.cli" in modules  # the check sees the command's own imports
    assert not [m for m in HEAVY if m in modules]


@pytest.mark.slow
def test_a_small_solve_without_report_imports_neither_matplotlib_nor_pinocchio(tmp_path):
    from spherecal.io import dataset as dataio
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    path = tmp_path / "small.jsonl"
    dataio.write_dataset(path, simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=reference_fov()),
                                                SweepPlan(profiles_per_station=6)))
    modules = _modules_after(["solve", str(path), "--no-report", "--out", str(tmp_path / "out")])
    assert (tmp_path / "out" / "result.json").exists()  # it did solve
    assert "spherecal.estimation.refine" in modules and "spherecal.app.solve" in modules
    assert "matplotlib" not in modules and "pinocchio" not in modules
    assert not [m for m in RUN_ONLY if m in modules]
    # a dataset's solve loads neither the recordings' readers nor their time model
    recording_only = ("rosbags", "spherecal.io.rosbag", "spherecal.io.streams", "spherecal.io.stream_writer",
                      "spherecal.core.streams",
                      "spherecal.estimation.on_the_fly", "spherecal.app.solve_recording")
    assert not [m for m in recording_only if m in modules]
    assert len([m for m in modules if m == "spherecal" or m.startswith("spherecal.")]) <= MAX_SOLVE_MODULES


@pytest.mark.slow
def test_the_plugin_list_loads_the_context_key_but_neither_the_sections_nor_the_file_loader():
    """``spherecal plugins`` checks the plugins' sections (with the ``base_dir`` context
    key of :mod:`spherecal.config.base`), and reads no configuration file: the run's
    section models and the loader stay unloaded."""
    modules = _modules_after(["plugins"])
    assert "spherecal.config.base" in modules
    assert "spherecal.config.sections" not in modules
    assert "spherecal.config.load" not in modules and "tomllib" not in modules


def test_the_robot_plugin_still_builds_its_kinematics_when_asked():
    """Loading pinocchio on first use: the plugin's arm model works all the same."""
    from spherecal.plugins.host import PluginHost

    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    pose = kin.flange_pose_from_joints([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
    assert "pinocchio" in sys.modules
    assert 500.0 < pose.translation_mm[0] < 1500.0 and abs(pose.translation_mm[1]) < 1e-9  # ahead, in the x-z plane


def test_the_program_holds_the_garbage_collector_off_for_its_imports_only(tmp_path):
    """The ``spherecal`` program keeps Python's cyclic garbage collector off while the
    command's modules are imported and on, with the start-up frozen, from before the data
    is read; ``cli.main``, the library's entry, leaves the collector as it found it."""
    from spherecal.io import dataset as dataio
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    path = tmp_path / "small.jsonl"
    dataio.write_dataset(path, simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=reference_fov()),
                                                SweepPlan(profiles_per_station=6)))
    code = (
        "import gc, json, sys\n"
        "from spherecal import cli\n"
        "from spherecal.io import dataset\n"
        "seen = {}\n"
        "real_read = dataset.read_dataset\n"
        "def read(p):\n"
        "    seen['read'] = gc.isenabled()\n"
        "    return real_read(p)\n"
        "dataset.read_dataset = read\n"
        "argv = json.loads(sys.argv[1])\n"
        "if sys.argv[2] == 'console':\n"
        "    sys.argv = ['spherecal', *argv]\n"
        "    exit_code = cli.console()\n"
        "else:\n"
        "    exit_code = cli.main(argv)\n"
        "print('SEEN ' + json.dumps([exit_code, seen, gc.isenabled(), gc.get_freeze_count() > 0]))\n"
    )
    outcomes = {}
    for entry in ("console", "main"):
        argv = ["solve", str(path), "--no-report", "--out", str(tmp_path / entry)]
        proc = subprocess.run([sys.executable, "-c", code, json.dumps(argv), entry], capture_output=True, text=True,
                              timeout=300)
        line = [ln for ln in proc.stdout.splitlines() if ln.startswith("SEEN ")]
        assert line, proc.stderr
        outcomes[entry] = json.loads(line[-1][len("SEEN "):])
    assert outcomes["console"] == [0, {"read": True}, True, True]  # on for the data, start-up frozen
    assert outcomes["main"] == [0, {"read": True}, True, False]  # the library: never off, nothing frozen
