"""The API reference (docs/build_api.py) builds offline from the docstrings: its first page
is the plugin API, ``spherecal.plugins``, holding every name a plugin may rely on with
its documentation and what a robot author's pieces unlock, and the modules behind those
names have pages of their own (the arm's kinematics and URDF, the workspace box, the
streaming contracts, the simulated cell's arm, time and random streams, the simulated
controller's pieces, the device server)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

import spherecal.plugins

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _has(page: str, name: str) -> bool:
    return bool(re.search(rf'id="{re.escape(name)}"|>{re.escape(name)}<', page))


@pytest.mark.slow
def test_the_api_reference_documents_the_plugin_api(tmp_path):
    spec = importlib.util.spec_from_file_location("build_api", DOCS / "build_api.py")
    build_api = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_api)
    assert build_api.API_MODULES[0] == "spherecal.plugins"
    out = build_api.build(tmp_path / "api")
    pages = {p.relative_to(out).as_posix(): p.read_text(encoding="utf-8") for p in out.rglob("*.html")}
    api = pages["spherecal/plugins.html"]
    # every name of the plugin API, on its page
    missing = [name for name in spherecal.plugins.__all__ if not _has(api, name)]
    assert not missing, f"not on spherecal/plugins.html: {missing}"
    # with its documentation, not only its name: the contract, the safety checks, the hooks' registries
    for text in ("base_from_flange", "check_target", "path_check_samples", "registry.add_robot",
                 "robot safety whatever the protocol", "plugin API", "kinematic calibration", "reach checks",
                 "on-the-fly acquisition"):
        assert text in api, text
    expected = {
        "spherecal/core/models.html": ["Pose", "Profile", "Observation", "Dataset"],
        "spherecal/devices/contract.html": ["Robot", "Sensor", "RobotType", "SensorType", "SensorFieldOfView",
                                            "DeviceContext", "ProfileStreamingSensor", "POSE_STREAM_SOURCE_KEY",
                                            "SIM_CLOCK_KEY", "SIM_CONTROLLER_CLOCK_KEY", "SIM_NOW_KEY",
                                            "SIM_SENSOR_CLOCK_KEY", "SIM_PROFILE_SOURCE_KEY"],
        "spherecal/devices/pose_streaming.html": ["PoseStreamingRobot", "PoseStreamCounts", "PoseStreamError"],
        "spherecal/core/streams.html": ["PoseStream", "ProfileStream"],
        "spherecal/core/kinematics.html": ["ArmKinematics", "SerialChain", "chain_reach_mm"],
        "spherecal/core/urdf.html": ["read_urdf_chain", "UrdfChain", "chain_inverse_kinematics", "IkNotConverged"],
        "spherecal/devices/motion_safety.html": ["MotionSafety", "MotionLimits", "FrameOffset"],
        "spherecal/core/field_of_view.html": ["SensorFieldOfView"],
        "spherecal/core/workspace.html": ["WorkspaceBox"],
        "spherecal/devices/line_robot.html": ["LineRobot", "LineLinkSettings", "TcpLink"],
        "spherecal/sim.html": ["SimulatedCell", "standard_cell", "NoiseModel"],
        "spherecal/sim/cell.html": ["SimulatedCell", "attach_arm", "standstill_rng", "device_rng"],
        "spherecal/sim/robot_error.html": ["SimulatedArm", "true_flange_pose"],
        "spherecal/sim/timeline.html": ["SimClock", "MotionTimeline", "DeviceClock", "move_linear"],
        "spherecal/sim/rngs.html": ["device_rng"],
        "spherecal/sim/controller.html": ["SimulatedController", "ControllerServer", "Faults", "start_controller"],
        "spherecal/sim/settings.html": ["SimulatedControllerSettings"],
        "spherecal/sim/device_server.html": ["SimulatedDeviceServer", "line_frames"],
        "spherecal/motion/planning.html": ["SweepPlan", "plan_stations", "with_standoff"],
        "spherecal/plugins/testing.html": ["spherecal_cell", "make_cell", "RobotHarness", "SensorHarness",
                                           "acquire_dataset"],
        "spherecal/plugins/hookspecs.html": ["spherecal_register_devices", "spherecal_register_exporters"],
        "spherecal/plugins/registry.html": ["DeviceRegistry", "ExporterRegistry"],
        "spherecal/io/exporters.html": ["Exporter"],
        "spherecal/core/geometry.html": ["matrix_from_rotvec"],
    }
    for page, names in expected.items():
        assert page in pages, sorted(pages)
        for name in names:
            assert _has(pages[page], name), f"{name} not in {page}"
    assert "base_from_flange" in pages["spherecal/devices/contract.html"]
    assert "check_target" in pages["spherecal/devices/contract.html"]
    # the extras keys with what each gives a simulated streaming device
    contract = pages["spherecal/devices/contract.html"]
    key = contract[contract.index('<section id="POSE_STREAM_SOURCE_KEY"'):]
    key = key[:key.index("</section>")]
    assert '<div class="docstring">' in key and "what the robot's controller reports at simulated true times" in key
    assert "true_transform" in pages["spherecal/plugins/testing.html"]
    # the simulated cell's pieces a simulated controller uses, named on its page
    for text in ("timeline.move_linear", "controller_clock", "true_flange_pose"):
        assert text in pages["spherecal/sim/cell.html"], text
