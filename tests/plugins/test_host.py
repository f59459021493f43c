"""The plugin host: discovery, hook checking, error reporting, registry, configuration."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import re
from typing import Literal, Optional

import pytest
from pydantic import BaseModel, ConfigDict, Field

from spherecal.devices.contract import DeviceContext, RobotType
from spherecal.core.errors import ConfigError, DeviceError, PluginError
from spherecal.core.models import Observation, Pose, Profile
from spherecal.core.workspace import WorkspaceBox
from spherecal.plugins import hookimpl
from spherecal.plugins.host import DISABLE_AUTOLOAD_ENV, PluginHost, autoload_disabled

from plugin_host_helpers import ToyRobotConfig, make_plugin

BUILTINS = {
    "abb_irb2400": ("robot", "spherecal.robots.abb_irb2400.plugin"),
    "nxsensor_i": ("sensor", "spherecal.sensors.nxsensor_i.plugin"),
}


def _missing_builtins() -> list[str]:
    return [mod for _, mod in BUILTINS.values() if importlib.util.find_spec(mod) is None]


# --- discovery ----------------------------------------------------------------------------
def test_builtins_are_declared_as_entry_points():
    eps = {ep.name: ep.value for ep in importlib.metadata.entry_points(group="spherecal")}
    for name, (_, module) in BUILTINS.items():
        assert eps.get(name) == module


@pytest.mark.skipif(bool(_missing_builtins()), reason=f"built-in plugin modules not written yet: {_missing_builtins()}")
def test_builtins_are_discovered_from_entry_points_even_without_autoload():
    host = PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"})
    assert not host.autoload
    by_name = {info.name: info for info in host.plugins}
    for name, (kind, module) in BUILTINS.items():
        assert by_name[name].source == "built-in"
        assert by_name[name].module == module
        table = host.registry.robots if kind == "robot" else host.registry.sensors
        provided = [t for t in table if host.registry.provider(kind, t) == name]
        assert provided, f"built-in plugin {name} registered no {kind} type"
    assert all(info.source == "built-in" for info in host.plugins)


@pytest.mark.parametrize(
    "value, disabled",
    [(None, False), ("", False), ("0", False), ("false", False), ("1", True), ("yes", True), ("TRUE", True)],
)
def test_autoload_switch_reads_the_environment(value, disabled):
    env = {} if value is None else {DISABLE_AUTOLOAD_ENV: value}
    assert autoload_disabled(env) is disabled


def test_env_var_disables_third_party_autoload_but_keeps_builtins(fake_entry_points):
    builtin = make_plugin("spherecal.fake_builtin", robots=["fake_robot"])
    third = make_plugin("acme_plugins.sensor", sensors=["acme_sensor"])
    fake_entry_points({"fake_builtin": ("spherecal.fake_builtin", builtin), "acme": ("acme_plugins.sensor", third)})

    everything = PluginHost(environ={})
    assert everything.plugin_names() == ["fake_builtin", "acme"]
    assert [i.source for i in everything.plugins] == ["built-in", "entry point"]
    assert set(everything.registry.sensors) == {"acme_sensor"}

    builtins_only = PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"})
    assert builtins_only.plugin_names() == ["fake_builtin"]
    assert set(builtins_only.registry.robots) == {"fake_robot"}
    assert set(builtins_only.registry.sensors) == set()
    assert f"{DISABLE_AUTOLOAD_ENV} is set" in builtins_only.format_description()

    enabled = PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"}, enable=["acme"])
    assert enabled.plugin_names() == ["fake_builtin", "acme"]

    with pytest.raises(PluginError, match=r"cannot enable plugin\(s\) \['acme_typo'\].*installed: acme, fake_builtin"):
        PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"}, enable=["acme_typo"])


def test_hosts_are_independent(fake_entry_points):
    fake_entry_points({})
    a = PluginHost(plugins=[("one", make_plugin("one", robots=["r1"]))])
    b = PluginHost()
    assert set(a.registry.robots) == {"r1"}
    assert set(b.registry.robots) == set()


# --- plugins that are wrong -----------------------------------------------------------------
def test_unimportable_entry_point_is_a_plugin_error_naming_it(fake_entry_points):
    fake_entry_points({"broken": ("acme_missing_module", None)})
    with pytest.raises(PluginError, match=r"plugin 'broken' \(entry point, module acme_missing_module\) "
                                          r"failed to import: ModuleNotFoundError") as info:
        PluginHost(environ={})
    assert f"{DISABLE_AUTOLOAD_ENV}=1" in str(info.value)
    assert isinstance(info.value.__cause__, ModuleNotFoundError)


def test_plugin_raising_on_import_is_a_plugin_error(fake_entry_points, monkeypatch):
    import sys
    import types

    class Exploding(types.ModuleType):
        def __getattr__(self, name):
            raise RuntimeError("no licence key")

    # An object whose import "succeeds" but whose load raises: EntryPoint.load for a
    # 'module:attr' value looks the attribute up, which raises.
    monkeypatch.setitem(sys.modules, "acme_exploding", Exploding("acme_exploding"))
    eps = [importlib.metadata.EntryPoint(name="exploding", value="acme_exploding:plugin", group="spherecal")]
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda **kw: eps)
    with pytest.raises(PluginError, match=r"plugin 'exploding' .* failed to import: RuntimeError: no licence key"):
        PluginHost(environ={})


def test_misspelled_unmarked_hook_is_an_error_naming_plugin_and_hook():
    def spherecal_register_device(registry):  # missing "s"
        pass

    plugin = make_plugin("acme.typo", spherecal_register_device=spherecal_register_device)
    with pytest.raises(PluginError, match=r"plugin 'typo' .* defines 'spherecal_register_device', which is not "
                                          r"a spherecal hook\. Did you mean 'spherecal_register_devices'\?"):
        PluginHost(plugins=[("typo", plugin)], load_entry_points=False)


def test_misspelled_marked_hook_is_an_error_too():
    @hookimpl
    def spherecal_observaton_taken(observation):
        pass

    plugin = make_plugin("acme.typo2", spherecal_observaton_taken=spherecal_observaton_taken)
    with pytest.raises(PluginError, match=r"'spherecal_observaton_taken'.*Did you mean 'spherecal_observation_taken'"):
        PluginHost(plugins=[("typo2", plugin)], load_entry_points=False)


def test_functions_without_the_prefix_are_ignored():
    def register_devices(registry):
        raise AssertionError("must not be called")

    host = PluginHost(plugins=[("plain", make_plugin("plain", register_devices=register_devices))],
                      load_entry_points=False)
    assert host.plugin_names() == ["plain"]


def test_hook_with_an_unknown_argument_is_a_plugin_error():
    def spherecal_register_devices(registry, cell):
        pass

    plugin = make_plugin("acme.args", spherecal_register_devices=spherecal_register_devices)
    with pytest.raises(PluginError, match=r"plugin 'args' .* is invalid: .*spherecal_register_devices.*cell"):
        PluginHost(plugins=[("args", plugin)], load_entry_points=False)


def test_plugin_raising_in_register_devices_is_named():
    def spherecal_register_devices(registry):
        raise KeyError("robot_model")

    good = make_plugin("good", robots=["good_robot"])
    bad = make_plugin("acme.bad", spherecal_register_devices=spherecal_register_devices)
    with pytest.raises(PluginError, match=r"plugin 'bad' .* raised in spherecal_register_devices: "
                                          r"KeyError: 'robot_model'") as info:
        PluginHost(plugins=[("good", good), ("bad", bad)], load_entry_points=False)
    assert isinstance(info.value.__cause__, KeyError)


def test_duplicate_type_names_name_both_plugins():
    first = make_plugin("first", robots=["shared_name"])
    second = make_plugin("second", robots=["shared_name"])
    with pytest.raises(PluginError, match=r"robot type 'shared_name' is registered twice: by plugin 'first' "
                                          r"and by plugin 'second'"):
        PluginHost(plugins=[("first", first), ("second", second)], load_entry_points=False)


def test_duplicate_plugin_names_are_errors():
    with pytest.raises(PluginError, match=r"two plugins are named 'same'"):
        PluginHost(plugins=[("same", make_plugin("a")), ("same", make_plugin("b"))], load_entry_points=False)


class LooseConfig(BaseModel):
    speed_mm_s: float = 1.0


class TypeFieldConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    type: str = "x"


@pytest.mark.parametrize(
    "robot_type, message",
    [
        ("not a RobotType", r"plugin 'p' passed str to registry\.add_robot\(\); expected a spherecal\.plugins\.RobotType"),
        (RobotType(name="Bad-Name", config_model=ToyRobotConfig, factory=print),
         r"robot type named 'Bad-Name'; a type name must be lower case"),
        (RobotType(name="loose", config_model=LooseConfig, factory=print),
         r"config_model LooseConfig of robot type 'loose' must set model_config = ConfigDict\(extra='forbid'"),
        (RobotType(name="typed", config_model=TypeFieldConfig, factory=print),
         r"has a field 'type', which is reserved"),
        (RobotType(name="nomodel", config_model=dict, factory=print), r"expected a pydantic BaseModel subclass"),
    ],
)
def test_bad_device_types_are_refused(robot_type, message):
    def spherecal_register_devices(registry):
        registry.add_robot(robot_type)

    plugin = make_plugin("p", spherecal_register_devices=spherecal_register_devices)
    with pytest.raises(PluginError, match=message):
        PluginHost(plugins=[("p", plugin)], load_entry_points=False)


def test_a_sensor_body_that_is_not_a_sensor_body_is_refused():
    """The keep-out check reads ``SensorType.body`` as a box: a tuple in its place is
    refused when the plugin registers, not found when a run starts."""
    from spherecal.devices.contract import SensorType

    def spherecal_register_devices(registry):
        registry.add_sensor(SensorType(name="boxy", config_model=ToyRobotConfig, factory=print,
                                       body=((-10, -10, 50), (10, 10, 90))))

    plugin = make_plugin("p", spherecal_register_devices=spherecal_register_devices)
    with pytest.raises(PluginError, match=r"plugin 'p': sensor type 'boxy' has body \(\(-10, -10, 50\), .*; expected a "
                                          r"spherecal\.plugins\.SensorBody \(a box in the sensor frame, mm\) or None"):
        PluginHost(plugins=[("p", plugin)], load_entry_points=False)


# --- lifecycle hooks -------------------------------------------------------------------------
def _observation() -> Observation:
    return Observation(index=0, station="S1", base_from_flange=Pose.identity(),
                       profile=Profile.from_points([[0.0, 1.0], [1.0, 1.5]]))


def test_lifecycle_hooks_get_keyword_arguments_and_errors_name_the_plugin():
    seen = []

    def spherecal_observation_taken(observation):
        seen.append(observation.station)

    def failing_observation_taken(observation):
        raise OSError("disk full")

    listener = make_plugin("listener", spherecal_observation_taken=spherecal_observation_taken)
    failing = make_plugin("recorder", spherecal_observation_taken=failing_observation_taken)

    host = PluginHost(plugins=[("listener", listener)], load_entry_points=False)
    host.observation_taken(observation=_observation())
    assert seen == ["S1"]
    with pytest.raises(TypeError):
        host.observation_taken(_observation())  # keyword arguments only

    host = PluginHost(plugins=[("listener", listener), ("recorder", failing)], load_entry_points=False)
    with pytest.raises(PluginError, match=r"plugin 'recorder' \(registered, .*\) raised in "
                                          r"spherecal_observation_taken: OSError: disk full"):
        host.observation_taken(observation=_observation())


def test_calibration_finished_receives_result_and_dataset():
    got = {}

    def spherecal_calibration_finished(dataset, result):  # any order, any subset
        got["result"], got["dataset"] = result, dataset

    host = PluginHost(plugins=[("exporter", make_plugin("exporter", spherecal_calibration_finished=
                                                        spherecal_calibration_finished))], load_entry_points=False)
    host.calibration_finished(result="R", dataset="D")
    assert got == {"result": "R", "dataset": "D"}


def test_lifecycle_hooks_tell_a_plugin_which_devices_ran():
    """A robot plugin tells its own runs apart by the type name, not the provenance."""
    got = []

    def spherecal_observation_taken(observation, robot_type, sensor_type):
        got.append(("observation", robot_type, sensor_type))

    def spherecal_acquisition_finished(robot_type):
        got.append(("acquisition", robot_type))

    def spherecal_calibration_finished(out_dir, exports_written, robot_type):
        got.append(("calibration", out_dir, exports_written, robot_type))

    host = PluginHost(plugins=[("mine", make_plugin(
        "mine", spherecal_observation_taken=spherecal_observation_taken,
        spherecal_acquisition_finished=spherecal_acquisition_finished,
        spherecal_calibration_finished=spherecal_calibration_finished))], load_entry_points=False)
    host.observation_taken(observation=_observation(), robot_type="toy_robot", sensor_type="toy_sensor")
    host.acquisition_finished(dataset="D", robot_type="toy_robot", sensor_type="toy_sensor")
    host.calibration_finished(result="R", dataset="D", out_dir="/out", exports_written=True, robot_type="toy_robot")
    host.calibration_finished(result="R", dataset="D", exports_written=True)  # no folder: nothing was written
    assert got == [("observation", "toy_robot", "toy_sensor"), ("acquisition", "toy_robot"),
                   ("calibration", "/out", True, "toy_robot"), ("calibration", None, False, None)]


def test_with_autoload_off_an_unknown_type_does_not_say_install(fake_entry_points):
    builtin = make_plugin("spherecal.fake_builtin", robots=["fake_robot"])
    third = make_plugin("acme_plugins.robot", robots=["acme_arm"])
    fake_entry_points({"fake_builtin": ("spherecal.fake_builtin", builtin), "acme": ("acme_plugins.robot", third)})
    host = PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"})
    with pytest.raises(ConfigError) as info:
        host.create_robot({"type": "acme_arm"})
    text = str(info.value)
    assert text.startswith("robot.type: unknown robot type 'acme_arm'; installed robot types: fake_robot.")
    assert "install the plugin" not in text
    assert f"not loaded because {DISABLE_AUTOLOAD_ENV} is set (installed but not loaded: acme)" in text


def test_with_autoload_off_an_unknown_exporter_says_which_plugins_are_not_loaded(fake_entry_points):
    third = make_plugin("acme_plugins.robot", robots=["acme_arm"])
    fake_entry_points({"acme": ("acme_plugins.robot", third)})
    host = PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"})
    with pytest.raises(ConfigError) as info:
        host.export_plan({"run": ["acme_tooldata"], "acme_tooldata": {}}, "eye_in_hand", "abb_irb2400")
    text = str(info.value)
    assert text.startswith("export.acme_tooldata: unknown exporter 'acme_tooldata'; installed exporters: ")
    assert "install the plugin" not in text
    assert f"not loaded because {DISABLE_AUTOLOAD_ENV} is set (installed but not loaded: acme)" in text
    # with autoload on, nothing is said about loading
    with pytest.raises(ConfigError) as info:
        PluginHost(environ={}).export_plan({"acme_tooldata": {}}, "eye_in_hand", None)
    assert "not loaded" not in str(info.value)
    assert f"unset {DISABLE_AUTOLOAD_ENV} or enable that plugin by name" in text
    # with autoload on, a type nobody provides still says to install its plugin
    with pytest.raises(ConfigError, match="install the plugin that provides it"):
        PluginHost(environ={}).create_robot({"type": "nobodys_arm"})


# --- registry lookups and configuration --------------------------------------------------------
@pytest.fixture
def toy_host():
    return PluginHost(plugins=[("toys", make_plugin("toys", robots=["toy_robot", "toy_gantry"], sensors=["toy_sensor"]))],
                      load_entry_points=False)


class Limits(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    max_x_mm: float = Field(2000.0, gt=0, description="largest x, mm")


class NestedConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    address: str = Field(description="controller address, host:port")
    workspace: Limits = Field(default_factory=Limits, description="limits")
    tilts_deg: list[float] = Field(default_factory=list, description="tilts, deg")


@pytest.fixture
def nested_host():
    def spherecal_register_devices(registry):
        registry.add_robot(RobotType(name="nested", config_model=NestedConfig,
                                     factory=lambda c, ctx: ctx.extras["make"](c),
                                     flange_pose_from_joints=lambda c, j: Pose.from_rt(
                                         [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [float(j[0]), 0.0, 0.0]),
                                     description="robot with nested settings"))

    return PluginHost(plugins=[("nest", make_plugin("nest", spherecal_register_devices=spherecal_register_devices))],
                      load_entry_points=False)


def test_unknown_type_lists_the_installed_ones(toy_host):
    with pytest.raises(ConfigError, match=r"robot\.type: unknown robot type 'toy_robt'; installed robot types: "
                                          r"toy_gantry, toy_robot\. Did you mean 'toy_robot'\?"):
        toy_host.create_robot({"type": "toy_robt"})
    with pytest.raises(ConfigError, match=r"sensor\.type: unknown sensor type 'laser'; installed sensor types: toy_sensor"):
        toy_host.validate_sensor_config("laser", {})


def test_missing_type_key_is_a_config_error(toy_host):
    with pytest.raises(ConfigError, match=r"robot\.type: missing; say which robot this is, one of: toy_gantry, toy_robot"):
        toy_host.create_robot({"speed_mm_s": 5})


def test_config_errors_list_every_error_with_its_dotted_path(nested_host):
    section = {"workspace": {"max_x_mm": -3, "max_y": 1}, "tilts_deg": [1.0, "steep"], "speed": 4}
    with pytest.raises(ConfigError) as info:
        nested_host.validate_robot_config("nested", section, path="cell.robot")
    lines = str(info.value).splitlines()
    assert lines[0] == "invalid configuration for robot type 'nested' (plugin 'nest'), 5 errors:"
    body = [line.strip() for line in lines[1:]]
    assert "cell.robot.address: missing (required)" in body
    assert "cell.robot.workspace.max_x_mm: Input should be greater than 0 (got -3)" in body
    assert ("cell.robot.workspace.max_y: unknown key (allowed here: max_x_mm; "
            "did you mean 'max_x_mm'?)") in body
    assert any(line.startswith("cell.robot.tilts_deg[1]: Input should be a valid number") for line in body)
    assert "cell.robot.speed: unknown key (allowed here: address, workspace, tilts_deg)" in body


def test_valid_config_gives_the_model_instance(nested_host):
    config = nested_host.validate_robot_config("nested", {"type": "nested", "address": "10.0.0.2:1025",
                                                          "workspace": {"max_x_mm": 1500}})
    assert isinstance(config, NestedConfig)
    assert config.workspace.max_x_mm == 1500.0


def test_section_type_must_match_and_be_a_table(nested_host):
    with pytest.raises(ConfigError, match=r"robot\.type: the section says 'other' but is being validated as 'nested'"):
        nested_host.validate_robot_config("nested", {"type": "other", "address": "a"})
    with pytest.raises(ConfigError, match=r"robot: expected a table of robot settings, got list"):
        nested_host.validate_robot_config("nested", ["address"])


def test_create_robot_passes_validated_config_and_context(nested_host):
    made = []
    context = DeviceContext(extras={"make": lambda c: made.append(c) or made_robot})
    from plugin_host_helpers import ToyRobot

    made_robot = ToyRobot(None)
    robot = nested_host.create_robot({"type": "nested", "address": "10.0.0.2:1025"}, context)
    assert robot is made_robot
    assert made[0].address == "10.0.0.2:1025"


@pytest.mark.parametrize(
    "make, error, message",
    [
        (lambda c: (_ for _ in ()).throw(DeviceError("controller 10.0.0.2:1025 refused the connection")),
         DeviceError, r"controller 10\.0\.0\.2:1025 refused"),
        (lambda c: 1 / 0, PluginError, r"plugin 'nest': the factory of robot type 'nested' raised ZeroDivisionError"),
        (lambda c: object(), PluginError, r"returned a object, which lacks read_flange_pose, read_joints_deg, "
                                          r"move_linear, close of the Robot protocol"),
    ],
)
def test_factory_failures(nested_host, make, error, message):
    with pytest.raises(error, match=message):
        nested_host.create_robot({"type": "nested", "address": "a"}, DeviceContext(extras={"make": make}))


def test_robot_kinematics_is_bound_to_the_config(nested_host, toy_host):
    fk = nested_host.robot_kinematics({"type": "nested", "address": "a"})
    assert fk([12.5, 0, 0, 0, 0, 0]).translation_mm == (12.5, 0.0, 0.0)
    assert toy_host.robot_kinematics({"type": "toy_robot"}) is None


def test_describe_lists_types_and_fields(nested_host, toy_host):
    (d,) = nested_host.describe()
    assert (d.kind, d.name, d.plugin, d.description, d.has_kinematics) == (
        "robot", "nested", "nest", "robot with nested settings", True)
    fields = {f.name: f for f in d.fields}
    assert list(fields) == ["address", "workspace.max_x_mm", "tilts_deg"]
    assert fields["address"].required and fields["address"].type == "str"
    assert fields["address"].description == "controller address, host:port"
    assert (fields["workspace.max_x_mm"].default, fields["workspace.max_x_mm"].constraints) == (2000.0, "> 0")
    assert fields["tilts_deg"].default == [] and fields["tilts_deg"].type == "list[float]"

    kinds = [(d.kind, d.name) for d in toy_host.describe()]
    assert kinds == [("robot", "toy_gantry"), ("robot", "toy_robot"), ("sensor", "toy_sensor")]
    text = toy_host.format_description()
    assert "robot type 'toy_robot' (plugin 'toys'): toy robot toy_robot" in text
    assert "speed_mm_s (float, default 100.0, > 0): speed, mm/s" in text


class Frame(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    origin_mm: tuple[float, float, float] = Field(description="origin, mm")
    turns: int = Field(0, ge=0, description="turns")


class OptionalNestedConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    box: WorkspaceBox | None = Field(None, description="allowed flange positions; absent: the arm's reach")
    frame: Frame = Field(default_factory=lambda: Frame(origin_mm=(1.0, 2.0, 3.0)), description="a frame")
    pose: Pose = Field(description="a pose")


def test_describe_opens_optional_models_and_names_types_without_modules():
    """``X | None`` opens like X (the urdf robot's ``workspace``); a table that may be left
    out, or has a default, has no required fields and gives its fields their defaults; no
    type name carries a module path."""
    def spherecal_register_devices(registry):
        registry.add_robot(RobotType(name="opt", config_model=OptionalNestedConfig, factory=lambda c, ctx: None))

    host = PluginHost(plugins=[("opt", make_plugin("opt", spherecal_register_devices=spherecal_register_devices))],
                      load_entry_points=False)
    (d,) = host.describe()
    fields = {f.name: f for f in d.fields}
    assert list(fields) == ["box.min_mm", "box.max_mm", "frame.origin_mm", "frame.turns",
                            "pose.translation_mm", "pose.quaternion_wxyz"]
    box_min = fields["box.min_mm"]
    assert (box_min.type, box_min.required, box_min.default) == ("tuple[float, float, float]", False, None)
    assert box_min.description == ("lower corner (x, y, z) in base, mm; "
                                   "box: allowed flange positions; absent: the arm's reach")
    assert fields["box.max_mm"].description == "upper corner (x, y, z) in base, mm"
    assert (fields["frame.origin_mm"].required, fields["frame.origin_mm"].default) == (False, (1.0, 2.0, 3.0))
    assert fields["pose.translation_mm"].required  # a required table keeps its required fields
    text = host.format_description()
    assert "    box.min_mm (tuple[float, float, float], default None): lower corner" in text
    assert "    frame.origin_mm (tuple[float, float, float], default (1.0, 2.0, 3.0)): origin, mm" in text
    assert "spherecal." not in text and "WorkspaceBox" not in text

    # the built-in urdf robot, the reviewer's case; and no module path anywhere in the listing
    listing = PluginHost(environ={DISABLE_AUTOLOAD_ENV: "1"}).format_description()
    assert "    workspace.min_mm (tuple[float, float, float], default None): lower corner" in listing
    assert "workspace (" not in listing
    types_shown = re.findall(r"^    \S+ \(([^,]*)", listing, re.M)
    assert types_shown and not [t for t in types_shown if "spherecal." in t]
    assert "geometry.joints (tuple[JointSpec, JointSpec" in listing


def test_type_names_keep_literal_values_with_dots():
    from spherecal.plugins.host import _field_type_name

    assert _field_type_name(Literal["a.b", "c"]) == "Literal['a.b', 'c']"
    assert _field_type_name(WorkspaceBox | None) == "WorkspaceBox | None"
    assert _field_type_name(Optional[WorkspaceBox]) == "Optional[WorkspaceBox]"


@pytest.mark.parametrize("option, read_frame, message", [
    ("Tool_Frame", True, "has frame_option 'Tool_Frame'; it must be lower case letters, digits and '-'"),
    ("--tool", True, "has frame_option '--tool'; it must be"),
    ("transform", True, "has frame_option 'transform', an option spherecal compare or validate already has"),
    ("out", True, "has frame_option 'out', an option"),
    ("tool-frame", False, "has frame_option 'tool-frame' but no read_frame"),
])
def test_a_robot_types_frame_option_is_checked(option, read_frame, message):
    @hookimpl
    def spherecal_register_devices(registry):
        registry.add_robot(RobotType(name="acme_arm", config_model=ToyRobotConfig, factory=lambda c, ctx: None,
                                     read_frame=(lambda text: None) if read_frame else None, frame_option=option))

    plugin = make_plugin("acme_frames", spherecal_register_devices=spherecal_register_devices)
    with pytest.raises(PluginError, match=r"plugin 'acme_frames'.*robot type 'acme_arm' " + re.escape(message)):
        PluginHost(plugins=[("acme_frames", plugin)], load_entry_points=False)


def test_a_robot_types_frame_option_is_accepted():
    @hookimpl
    def spherecal_register_devices(registry):
        registry.add_robot(RobotType(name="acme_arm", config_model=ToyRobotConfig, factory=lambda c, ctx: None,
                                     read_frame=lambda text: None, frame_option="tool-frame"))

    plugin = make_plugin("acme_frames", spherecal_register_devices=spherecal_register_devices)
    host = PluginHost(plugins=[("acme_frames", plugin)], load_entry_points=False)
    assert host.registry.robot_type("acme_arm").frame_option == "tool-frame"
