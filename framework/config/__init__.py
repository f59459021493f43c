"""The run configuration: one TOML file validated by pydantic. Imports only
:mod:`spherecal.core` and :mod:`spherecal.io`.

:mod:`.sections` holds the section models and the root :class:`RunConfig`, with the
estimator's settings in :mod:`.calibration`, the report's in :mod:`.report` and what
they share in :mod:`.base`;
:mod:`.load` reads and checks a file (:func:`load_config`). The robot and sensor sections
belong to their plugins: the plugin host validates them against the plugin's own model,
with the file's folder under :data:`BASE_DIR_CONTEXT_KEY` in the validation context.
See docs/configuration.md.

The names below load on first use (PEP 562): a module that needs a section model does
not load the file loader and its TOML parser.
"""

from spherecal.core.lazy import lazy_attributes

#: name -> the module that defines it
_WHERE = {
    # reading a file
    "MAX_ABS_NUMBER": ".load",
    "MAX_CONFIG_BYTES": ".load",
    "LoadedConfig": ".load",
    "load_config": ".load",
    "not_numbers": ".load",
    "read_toml": ".load",
    # the section models and their constants
    "BASE_DIR_CONTEXT_KEY": ".base",
    "CHI2_3DOF_1E4": ".base",
    "DEFAULT_LIMITS_DEG": ".sections",
    "MAX_SCAN_PROFILES": ".sections",
    "POINT_DISTANCE_MM": ".base",
    "AcquisitionConfig": ".sections",
    "BallBarConfig": ".sections",
    "CalibrationOptions": ".calibration",
    "ClockSettings": ".sections",
    "ExportConfig": ".sections",
    "FieldOfViewOverride": ".sections",
    "FlatConfig": ".sections",
    "KeepOutConfig": ".sections",
    "KinematicPlanSettings": ".sections",
    "MpeConfig": ".sections",
    "NoiseModel": ".sections",
    "OnTheFlyPlan": ".sections",
    "PoseStreamSettings": ".sections",
    "ReportConfig": ".report",
    "RobotErrorModel": ".sections",
    "RunConfig": ".sections",
    "ScanConfig": ".sections",
    "SensorStreamSettings": ".sections",
    "SimulationConfig": ".sections",
    "SphereConfig": ".sections",
    "StreamSimSettings": ".sections",
    "SweepPlan": ".sections",
    "SweepSite": ".sections",
    "TransformConfig": ".sections",
    "UnitQuaternion": ".sections",
    "ValidationConfig": ".sections",
    "Vec3": ".sections",
    "Vec4": ".sections",
    "WorkspaceConfig": ".sections",
}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_attributes(__name__, _WHERE)
