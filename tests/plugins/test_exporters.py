"""Exporters as plugins: spherecal_register_exporters, the checks on a registered
exporter, the export plan of a run ([export]: which exporters, their settings, clear
errors naming the key), and writing their files."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict, Field

from spherecal.core.errors import ConfigError, InputError, PluginError
from spherecal.io.exporters import ExportNote, Exporter, write_exports
from spherecal.core.models import CalibrationResult, Pose
from spherecal.plugins.host import PluginHost

from plugin_host_helpers import make_plugin
from reference_sensor import reference_fov


class ToolSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    tool_number: int = Field(ge=1, le=16, description="tool slot on the controller, 1-16")
    label: str = Field("laser", description="tool label")


class Loose(BaseModel):
    tool_number: int = 1


def _toy_tool(r: CalibrationResult, s: ToolSettings) -> dict[str, str]:
    x, y, z = r.transform.translation_mm
    return {f"tool{s.tool_number}.txt": f"TOOL {s.tool_number} {s.label} {x!r} {y!r} {z!r}\n"}


#: A robot plugin's own exporter: a required setting, file name from the settings, a note.
TOY_TOOL = Exporter(
    name="toy_tool", description="the toy controller's tool table", files=("tool{tool_number}.txt",),
    write=_toy_tool, settings_model=ToolSettings, robot_types=("toy_robot",), mountings=("eye_in_hand",),
    note=lambda r, s: ExportNote("Toy controller", f"Select tool {s.tool_number}."),
)
#: A brand-free exporter without settings.
PLAIN = Exporter(name="plain", description="the translation, mm", files=("{transform_name}.plain",),
                 write=lambda r, s: {f"{r.transform_name}.plain": " ".join(map(repr, r.transform.translation_mm))})


def _host(*exporters: Exporter, name: str = "toys", extra=()) -> PluginHost:
    def spherecal_register_exporters(registry):
        for e in exporters:
            registry.add_exporter(e)

    plugins = [(name, make_plugin(name, robots=["toy_robot"], spherecal_register_exporters=spherecal_register_exporters))]
    return PluginHost(plugins=[*plugins, *extra], load_entry_points=False)


@pytest.fixture(scope="module")
def result() -> CalibrationResult:
    from spherecal.estimation import solve
    from spherecal.sim import SweepPlan, simulate_dataset, standard_cell

    return solve(simulate_dataset(standard_cell("eye_in_hand", seed=4, fov=reference_fov()),
                                  SweepPlan(profiles_per_station=4))).result


# --- registration ------------------------------------------------------------------------------------------
def test_builtin_exporters_are_registered_through_entry_points():
    host = PluginHost(environ={})
    assert {n: host.exporters.provider(n) for n in ("matrix", "xyz_quaternion", "ros2")} == dict.fromkeys(
        ("matrix", "xyz_quaternion", "ros2"), "core_exports")
    assert host.exporters.provider("abb_rapid") == "abb_irb2400"
    text = host.format_description()
    assert "exporter 'ros2' (plugin 'core_exports')" in text and "export.ros2.child_frame_id (str | None, default None" in text


@pytest.mark.parametrize("exporter, message", [
    (Exporter(name="Bad-Name", description="", files=("a.txt",), write=lambda r, s: {}), "exporter named 'Bad-Name'"),
    (Exporter(name="run", description="", files=("a.txt",), write=lambda r, s: {}), "not 'run'"),
    (Exporter(name="loose", description="", files=("a.txt",), write=lambda r, s: {}, settings_model=Loose),
     "settings_model Loose of exporter 'loose' must set model_config = ConfigDict\\(extra='forbid'"),
    (Exporter(name="nofiles", description="", files=(), write=lambda r, s: {}), "non-empty tuple of file-name"),
    (Exporter(name="tmpl", description="", files=("{tool}.txt",), write=lambda r, s: {}), r"use \['tool'\]"),
    (Exporter(name="mnt", description="", files=("a.txt",), write=lambda r, s: {}, mountings=("on_the_floor",)),
     "mountings \\('on_the_floor',\\)"),
    (Exporter(name="rt", description="", files=("a.txt",), write=lambda r, s: {}, robot_types="toy_robot"),
     "robot_types 'toy_robot'"),
    ("not an exporter", "passed str to registry.add_exporter"),
])
def test_bad_exporters_are_refused_naming_the_plugin(exporter, message):
    with pytest.raises(PluginError, match=r"plugin 'toys'.*" + message):
        _host(exporter)


def test_an_exporter_name_registered_twice_names_both_plugins():
    def spherecal_register_exporters(registry):
        registry.add_exporter(PLAIN)

    other = ("other", make_plugin("other", spherecal_register_exporters=spherecal_register_exporters))
    with pytest.raises(PluginError, match="exporter 'plain' is registered twice: by plugin 'toys' and by plugin 'other'"):
        _host(PLAIN, extra=[other])


# --- the plan of a run -----------------------------------------------------------------------------------
def test_by_default_every_exporter_that_applies_runs_the_robots_own_first():
    host = _host(TOY_TOOL, PLAIN)
    plan = host.export_plan({"toy_tool": {"tool_number": 3}}, "eye_in_hand", "toy_robot")
    assert plan.names == ["toy_tool", "plain"] and plan.robot_type == "toy_robot"
    assert host.export_plan(None, "eye_in_hand", "other_robot").names == ["plain"]
    assert host.export_plan(None, "eye_to_hand", "toy_robot").names == ["plain"]  # toy_tool: eye_in_hand only
    assert host.export_plan({"run": []}, "eye_in_hand", "toy_robot").names == []


def test_a_missing_required_setting_names_the_key():
    host = _host(TOY_TOOL, PLAIN)
    # asked for: an error before anything moves
    with pytest.raises(ConfigError, match=r"exporter 'toy_tool' \(plugin 'toys'\) needs settings: "
                                          r"export\.toy_tool\.tool_number \(tool slot on the controller, 1-16\)\. "
                                          r"Set them in \[export\.toy_tool\]"):
        host.export_plan({"run": ["toy_tool", "plain"]}, "eye_in_hand", "toy_robot")
    # by default: left out, and the plan says why (the runner logs it)
    plan = host.export_plan(None, "eye_in_hand", "toy_robot")
    assert plan.names == ["plain"]
    assert "export.toy_tool.tool_number" in plan.left_out["toy_tool"] and "export.run" in plan.left_out["toy_tool"]


@pytest.mark.parametrize("section, message", [
    ({"run": ["plian"]}, r"export\.run\[0\]: unknown exporter 'plian'; installed exporters: plain, toy_tool\. "
                         r"Did you mean 'plain'\?"),
    ({"run": ["plain", "plain"]}, r"export\.run: plain listed twice"),
    ({"run": "plain"}, r"export\.run: expected a list of exporter names"),
    ({"plian": {}}, r"export\.plian: unknown exporter 'plian'"),
    ({"plain": 3}, r"export\.plain: expected a table \[export\.plain\]"),
    ({"plain": {"x": 1}}, r"export\.plain\.x: unknown key"),
    ({"toy_tool": {"tool_number": 17}}, r"export\.toy_tool\.tool_number: Input should be less than or equal to 16"),
    ({"toy_tool": {"tool_number": "3"}}, r"export\.toy_tool\.tool_number: '3' is a string; give a number"),
    ({"run": ["toy_tool"], "toy_tool": {"tool_number": 1}}, r"export\.run\[0\]: exporter 'toy_tool' does not apply"),
])
def test_bad_export_sections_name_the_key(section, message):
    with pytest.raises(ConfigError, match=message):
        _host(TOY_TOOL, PLAIN).export_plan(section, "eye_to_hand", "toy_robot")


def test_the_configuration_reads_an_export_section(tmp_path):
    from spherecal.config import ExportConfig

    cfg = ExportConfig.model_validate({"run": ["plain"], "toy_tool": {"tool_number": 2}})
    plan = _host(TOY_TOOL, PLAIN).export_plan(cfg, "eye_in_hand", "toy_robot")
    assert plan.names == ["plain"]
    with pytest.raises(ValueError, match=r"toy_tool: expected a table \[export\.toy_tool\]"):
        ExportConfig.model_validate({"toy_tool": 2})


# --- writing ---------------------------------------------------------------------------------------------
def test_files_are_written_as_declared_and_notes_come_from_the_exporters(result, tmp_path):
    host = _host(TOY_TOOL, PLAIN)
    plan = host.export_plan({"toy_tool": {"tool_number": 7}}, "eye_in_hand", "toy_robot")
    paths = write_exports(result, tmp_path, plan)
    assert set(paths) == {"tool7.txt", "flange_from_sensor.plain", "result.json"}
    words = paths["tool7.txt"].read_text().split()
    assert words[:3] == ["TOOL", "7", "laser"]
    np.testing.assert_array_equal([float(v) for v in words[3:]], result.transform.translation_mm)
    assert plan.notes(result) == [ExportNote("Toy controller", "Select tool 7.")]
    assert plan.file_patterns() == ("tool*.txt", "*.plain")


@pytest.mark.parametrize("write, error, message", [
    (lambda r, s: {"other.txt": ""}, PluginError, r"plugin 'toys': exporter 'plain' returned \['other.txt'\]; it "
                                                  r"declared \['flange_from_sensor.plain'\]"),
    (lambda r, s: {"flange_from_sensor.plain": 3}, PluginError, "returned a int for flange_from_sensor.plain"),
    (lambda r, s: 1 / 0, PluginError, "exporter 'plain' raised ZeroDivisionError"),
    (lambda r, s: (_ for _ in ()).throw(InputError("no room")), InputError, "no room"),
])
def test_a_misbehaving_exporter_writes_nothing(result, tmp_path, write, error, message):
    bad = Exporter(name="plain", description="", files=("{transform_name}.plain",), write=write)
    plan = _host(bad).export_plan(None, "eye_in_hand", "toy_robot")
    with pytest.raises(error, match=message):
        write_exports(result, tmp_path, plan)
    assert list(tmp_path.iterdir()) == []


def test_two_exporters_writing_one_file_is_an_error(result, tmp_path):
    twin = Exporter(name="twin", description="", files=("{transform_name}.plain",), write=PLAIN.write)
    plan = _host(PLAIN, twin).export_plan(None, "eye_in_hand", None)
    with pytest.raises(InputError, match="exporters 'plain' and 'twin' both write flange_from_sensor.plain"):
        write_exports(result, tmp_path, plan)


@pytest.mark.parametrize("label", ["../escape", "result", "a/b"])
def test_a_file_name_from_settings_stays_a_plain_name(result, tmp_path, label):
    class Named(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        label: str = "x"

    e = Exporter(name="named", description="", files=("{label}.json",), settings_model=Named,
                 write=lambda r, s: {f"{s.label}.json": "{}"})
    plan = _host(e).export_plan({"named": {"label": label}}, "eye_in_hand", None)
    with pytest.raises(InputError, match=r"exporter 'named': file '\{label\}.json' resolves to"):
        write_exports(result, tmp_path, plan)
    assert not (tmp_path.parent / "escape.json").exists()
