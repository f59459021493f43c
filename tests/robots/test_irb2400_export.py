"""The ABB RAPID export (exporter 'abb_rapid' of the abb_irb2400 plugin): every
declaration parsed back and checked against the result it came from, in both mounting
modes; its settings ([export.abb_rapid]), files and note, and that it runs only for this
robot type."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spherecal.core.errors import ConfigError, InputError
from spherecal.estimation import solve
from spherecal.io.exporters import write_exports
from spherecal.plugins.host import PluginHost
from spherecal.report import export as ex
from spherecal.report.html import write_report
from spherecal.robots.abb_irb2400 import export as rapid
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

MM_TOL = 0.5 * 10 ** -ex.MM_DECIMALS + 1e-12
Q_TOL = 0.5 * 10 ** -ex.QUAT_DECIMALS + 1e-15


@pytest.fixture(scope="module")
def solutions():
    plan = SweepPlan(profiles_per_station=6)
    return {m: solve(simulate_dataset(standard_cell(m, seed=4, fov=reference_fov()),
                                      plan)) for m in ("eye_in_hand", "eye_to_hand")}


@pytest.fixture(scope="module")
def results(solutions):
    return {m: s.result for m, s in solutions.items()}


@pytest.fixture(params=["eye_in_hand", "eye_to_hand"])
def mounting(request):
    return request.param


@pytest.fixture(scope="module")
def host():
    return PluginHost()


def _R_from_wxyz(q):
    """Independent of spherecal.core.geometry: SciPy wants (x, y, z, w)."""
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w]).as_matrix()


# --- RAPID --------------------------------------------------------------------------------------------
def test_rapid_tooldata_eye_in_hand(results):
    r = results["eye_in_hand"]
    text = rapid.rapid_declaration(r)
    d = rapid.read_rapid(text)
    assert d["kind"] == "tooldata" and d["name"] == "tSensor" and d["robhold"] is True
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    np.testing.assert_allclose(d["quaternion_wxyz"], r.transform.quaternion_wxyz, atol=Q_TOL)
    assert abs(np.linalg.norm(d["quaternion_wxyz"]) - 1) < 1e-7
    # the tool frame is flange_from_sensor: orient [q1..q4] is (w, x, y, z)
    np.testing.assert_allclose(_R_from_wxyz(d["quaternion_wxyz"]), r.transform.rotation_matrix, atol=1e-7)
    # no load given: none invented; mass 0 (refused by the controller) until it is filled in, and said
    assert d["mass_kg"] == 0.0 and list(d["cog_mm"]) == [0.0, 0.0, 0.0]
    assert "load NOT GIVEN" in text
    assert f"{r.std_rotation_deg[1]:.4f}" in text and f"{r.std_translation_mm[0]:.4f}" in text


def test_rapid_wobjdata_eye_to_hand(results):
    r = results["eye_to_hand"]
    text = rapid.rapid_declaration(r)
    d = rapid.read_rapid(text)
    assert d["kind"] == "wobjdata" and d["name"] == "wobjSensor"
    assert d["robhold"] is False and d["ufprog"] is True  # fixed user frame, not robot-held
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    np.testing.assert_allclose(d["quaternion_wxyz"], r.transform.quaternion_wxyz, atol=Q_TOL)
    assert '[FALSE, TRUE, "",' in text and "[[0, 0, 0], [1, 0, 0, 0]]];" in text


def test_rapid_options_and_module(results, mounting):
    r = results[mounting]
    text = rapid.rapid_module(r, "tLaser_2", module_name="CalibData", mass_kg=2.25, cog_mm=(1.0, -2.0, 55.5))
    assert text.startswith("MODULE CalibData\n") and text.rstrip().endswith("ENDMODULE")
    d = rapid.read_rapid(text)
    assert d["name"] == "tLaser_2"
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    if mounting == "eye_in_hand":
        assert d["mass_kg"] == 2.25
        np.testing.assert_allclose(d["cog_mm"], [1.0, -2.0, 55.5])
    for line in text.splitlines():
        assert len(line) <= rapid.RAPID_MAX_LINE, line


@pytest.mark.parametrize(
    "name, message",
    [
        ("1tool", "not a valid RAPID identifier"),
        ("my tool", "not a valid RAPID identifier"),
        ("tSensor-1", "not a valid RAPID identifier"),
        ("t" * 33, "at most 32"),
        ("PERS", "reserved word"),
        ("endmodule", "reserved word"),
        ("tool0", "predefined"),
    ],
)
def test_rapid_names_must_be_identifiers(results, name, message):
    with pytest.raises(InputError, match=message):
        rapid.rapid_declaration(results["eye_in_hand"], name)
    with pytest.raises(InputError, match=message):
        rapid.rapid_module(results["eye_to_hand"], module_name=name)


def test_rapid_tool_load_must_have_mass(results):
    with pytest.raises(InputError, match="mass > 0"):
        rapid.rapid_declaration(results["eye_in_hand"], mass_kg=0.0, cog_mm=(0.0, 0.0, 50.0))
    with pytest.raises(InputError, match="cog_mm must be 3 finite numbers"):
        rapid.rapid_declaration(results["eye_in_hand"], mass_kg=1.2, cog_mm=(1.0, 2.0))
    with pytest.raises(InputError, match="needs both mass_kg and cog_mm"):
        rapid.rapid_declaration(results["eye_in_hand"], mass_kg=1.2)


def test_a_tooldata_without_its_load_is_said_in_the_terminal(results):
    """The export does not invent a load: the note the run prints when it writes the files
    says the tooldata is unusable until the mass and centre of gravity are given, and a
    load given whole is written as given, with no warning."""
    from spherecal.robots.abb_irb2400.export import AbbRapidExportSettings, _note

    r = results["eye_in_hand"]
    note = _note(r, AbbRapidExportSettings())
    assert "load (mass, centre of gravity) is not given" in note.warning and "does not invent" in note.warning
    given = AbbRapidExportSettings(mass_kg=1.85, cog_mm=(0.0, 5.0, 60.0))
    assert _note(r, given).warning == ""
    d = rapid.read_rapid(_note(r, given).code)
    assert d["mass_kg"] == 1.85 and list(d["cog_mm"]) == [0.0, 5.0, 60.0]
    with pytest.raises(ValueError, match="mass_kg without cog_mm"):
        AbbRapidExportSettings(mass_kg=1.85)


def test_rapid_reader_ignores_comments_and_finds_nothing_else():
    with pytest.raises(InputError, match="no 'PERS tooldata' or 'PERS wobjdata'"):
        rapid.read_rapid("! PERS tooldata t := [TRUE, [[0,0,0],[1,0,0,0]], [1,[0,0,0],[1,0,0,0],0,0,0]];\n")


# --- as an exporter ----------------------------------------------------------------------------------------
def test_the_exporter_runs_for_this_robot_only(host):
    assert host.exporters.provider("abb_rapid") == "abb_irb2400"
    for mounting in ("eye_in_hand", "eye_to_hand"):
        assert "abb_rapid" in host.export_plan(None, mounting, "abb_irb2400").names
        assert "abb_rapid" not in host.export_plan(None, mounting, "ur5_urdf").names
        # the robot's own exporter comes first: its note leads the report's controller section
        assert host.export_plan(None, mounting, "abb_irb2400").names[0] == "abb_rapid"
    with pytest.raises(ConfigError, match=r"export\.run\[1\]: exporter 'abb_rapid' does not apply to this run "
                                          r"\(it is for eye_in_hand and eye_to_hand, robot types abb_irb2400; the "
                                          r"run is eye_to_hand with robot type ur5_urdf\)"):
        host.export_plan({"run": ["matrix", "abb_rapid"]}, "eye_to_hand", "ur5_urdf")


def test_settings_reach_the_file(results, host, mounting, tmp_path):
    r = results[mounting]
    section = {"abb_rapid": {"tool_name": "tLaser", "wobj_name": "wLaser", "module_name": "CalibData",
                             "mass_kg": 2.25, "cog_mm": [1.0, -2.0, 55.5]}}
    plan = host.export_plan(section, mounting, "abb_irb2400")
    paths = write_exports(r, tmp_path, plan)
    d = rapid.read_rapid(paths["CalibData.mod"].read_text())
    assert d["name"] == ("tLaser" if mounting == "eye_in_hand" else "wLaser")
    np.testing.assert_allclose(d["xyz_mm"], r.transform.translation_mm, atol=MM_TOL)
    np.testing.assert_allclose(d["quaternion_wxyz"], r.transform.quaternion_wxyz, atol=Q_TOL)
    if mounting == "eye_in_hand":
        assert d["mass_kg"] == 2.25
        np.testing.assert_allclose(d["cog_mm"], [1.0, -2.0, 55.5])
    (note,) = [n for n in plan.notes(r) if n.title.startswith("ABB")]
    kind = "tooldata.tframe" if mounting == "eye_in_hand" else "wobjdata.uframe"
    assert f"On an ABB controller this is {kind}" in note.text and "CalibData.mod" in note.text
    assert rapid.read_rapid(note.code)["name"] == d["name"]


@pytest.mark.parametrize("settings, message", [
    ({"mass_kg": 0}, r"export\.abb_rapid\.mass_kg: Input should be greater than 0"),
    ({"mass_kg": 1e4}, r"export\.abb_rapid\.mass_kg: Input should be less than or equal to 2000"),
    ({"mass_kg": True}, r"export\.abb_rapid\.mass_kg: true is a boolean; give a number"),
    ({"cog_mm": [0.0, 0.0, 1e5]}, r"export\.abb_rapid\.cog_mm: .*within \+-5000 mm"),
    ({"cog_mm": [0.0, 0.0]}, r"export\.abb_rapid\.cog_mm"),
    ({"tool_name": "PERS"}, r"export\.abb_rapid\.tool_name: .*reserved word"),
    ({"module_name": "1mod"}, r"export\.abb_rapid\.module_name: .*not a valid RAPID identifier"),
    ({"toolname": "t"}, r"export\.abb_rapid\.toolname: unknown key .*did you mean 'tool_name'"),
])
def test_bad_settings_name_the_key(host, settings, message):
    with pytest.raises(ConfigError, match=message):
        host.export_plan({"abb_rapid": settings}, "eye_in_hand", "abb_irb2400")
    # checked even when the run's robot is another: a typo never waits for the day it matters
    with pytest.raises(ConfigError, match=message):
        host.export_plan({"abb_rapid": settings}, "eye_in_hand", "ur5_urdf")


@pytest.mark.slow
def test_the_report_speaks_of_the_abb_controller_only_for_this_robot(solutions, host, tmp_path):
    solution = solutions["eye_to_hand"]
    texts = {}
    for robot in ("abb_irb2400", "ur5_urdf"):
        notes = host.export_plan(None, "eye_to_hand", robot).notes(solution.result)
        texts[robot] = write_report(solution, tmp_path / robot, notes=notes).read_text()
    assert "On an ABB controller this is wobjdata.uframe" in texts["abb_irb2400"]
    assert "PERS wobjdata wobjSensor" in texts["abb_irb2400"]
    assert "ABB controller" not in texts["ur5_urdf"] and "wobjdata" not in texts["ur5_urdf"]
    assert "static_transform_publisher" in texts["ur5_urdf"]  # the brand-free ROS note stays


def test_a_kinematic_calibration_s_module_says_it_holds_only_through_the_calibrated_model(results, mounting):
    """A transform calibrated with the arm's geometry: the module's first comment says it
    goes with robot_calibrated.urdf, within which accuracy, and what to expect on the
    controller's nominal model (or that the result file does not say); within 80
    characters a line, the declaration still read back; the report's note says how to give
    the robot the model. A plain calibration's module says nothing of it."""
    from kinematic_results import as_kinematic_calibration

    assert "KINEMATIC" not in rapid.rapid_module(results[mounting])
    kinematic = as_kinematic_calibration(results[mounting])
    text = rapid.rapid_module(kinematic)
    head = " ".join(line.strip().lstrip("!").strip() for line in text.splitlines()[1:5])
    assert head.startswith("KINEMATIC CALIBRATION: this transform goes with spherecal's calibrated arm model "
                           "(robot_calibrated.urdf); a point measured at a new pose is within 0.075 mm (k = 2) only "
                           "where poses go through that model; on the controller's nominal model expect 0.362 mm "
                           "(k = 2)"), head
    assert max(len(line) for line in text.splitlines()) <= rapid.RAPID_MAX_LINE
    np.testing.assert_allclose(rapid.read_rapid(text)["xyz_mm"], kinematic.transform.translation_mm, atol=MM_TOL)
    note = rapid.RAPID_EXPORTER.note(kinematic, rapid.AbbRapidExportSettings())
    assert "[robot] calibrated_model" in note.text
    older = rapid.rapid_module(as_kinematic_calibration(results[mounting], nominal_k2_mm=None))
    assert "expect more (this result file does not say how much)" in " ".join(older.split())
