"""The result's provenance: what was calibrated, from which files, by whom, when and
with which software (docs/results.md, "Identity and traceability")."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from pydantic import ValidationError

from spherecal import __version__
from spherecal.config.calibration import CalibrationOptions
from spherecal.core.errors import InputError
from spherecal.core.models import Dataset
from spherecal.io.files import sha256_of
from spherecal.io.runlog import progress_log

if TYPE_CHECKING:
    from spherecal.config import LoadedConfig  # (not loaded by solve: tests/cli/test_startup_imports.py)
    from spherecal.core.streams import Recording

#: A journal's or recording's provenance key holding the estimator settings it was taken
#: to be solved with (``calibrate``, stop-and-go and on the fly: its ``[calibration]``
#: with the nominal transform, as ``CalibrationOptions.model_dump(mode="json")``);
#: ``solve`` of it starts from them.
CALIBRATION_OPTIONS_KEY = "calibration_options"


def with_clock_truth(recording: Recording) -> dict:
    """The recording's provenance with the truth of its clock relation added
    (``true_offset_s``, ``true_drift``: docs/conventions.md, "Time: two clocks") when it
    holds the simulated devices' clocks (``simulated_clocks``, written by ``calibrate`` on
    a simulated cell). Computed poses (a programmed line: ``recording.poses_assumption``)
    are stamped by a clock of the robot's program, not the simulated controller's clock
    the truth describes: no truth of the offset is claimed for them."""
    provenance = dict(recording.provenance)
    clocks = provenance.get("simulated_clocks")
    if isinstance(clocks, dict) and recording.poses_assumption is None:
        from spherecal.sim.live import true_time_relation

        offset_s, drift = true_time_relation(clocks, recording.t_sensor0_s)
        provenance.update(true_offset_s=offset_s, true_drift=drift)
    return provenance


def provenance_type(dataset: Dataset, kind: str = "robot") -> str | None:
    """The robot (or, with ``kind="sensor"``, sensor) type a dataset's provenance names
    (``"robot": "abb_irb2400"`` as ``spherecal calibrate`` writes it, or ``"robot":
    {"type": ...}``), or None."""
    robot = dataset.provenance.get(kind)
    if isinstance(robot, dict):
        robot = robot.get("type")
    return robot if isinstance(robot, str) and robot else None


def traceability(dataset: Dataset, dataset_path: Path | None, loaded: LoadedConfig | None = None,
                 operator: str | None = None) -> dict:
    """The result's provenance (docs/results.md, "Identity and traceability"): what was
    calibrated (cell, robot and sensor types with what the devices said they are, the
    sphere and its certificate), by whom, when, with which software, and the SHA-256 of
    the dataset and of the configuration it was calibrated from."""
    prov = dataset.provenance
    cfg = loaded.config if loaded is not None else None
    settings = cfg.report if cfg is not None else None  # (its [report]: operator, cell)

    def device(kind: str) -> dict:
        given = prov.get(kind)
        kind_type = given.get("type") if isinstance(given, dict) else given
        if kind_type is None and cfg is not None:
            kind_type = getattr(cfg, kind).get("type")
        found = prov.get(f"{kind}_identity")
        return {"type": kind_type, **(found if isinstance(found, dict) else {})}

    sphere = {"radius_mm": dataset.sphere_radius_mm}
    if cfg is not None:
        sphere.update(radius_uncertainty_mm_k2=cfg.sphere.radius_uncertainty_mm, certificate=cfg.sphere.certificate)
    return {
        "dataset": prov.get("source", "unknown"),
        "dataset_file": None if dataset_path is None else str(dataset_path),
        "dataset_sha256": None if dataset_path is None else sha256_of(dataset_path),
        "configuration_file": None if loaded is None else str(loaded.path),
        "configuration_sha256": None if loaded is None else sha256_of(loaded.path),
        "software": f"spherecal {__version__}",
        "calibrated_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "operator": operator or (settings.operator if settings is not None else None),
        "cell": settings.cell if settings is not None else None,
        "robot": device("robot"),
        "sensor": device("sensor"),
        "sphere": sphere,
        # simulated devices, or data from the simulator (which holds the truth: the terminal's "simulated truth")
        "simulated": True if prov.get("simulated") or "true_transform" in prov else prov.get("simulated"),
    }


def check_same_devices(before: dict, now: dict, journal: Path, log: Callable[[str], None]) -> None:
    """On --resume: say so when the robot or sensor now connected is not the one the
    journal was started with (a swapped unit changes the transform)."""
    for kind in ("robot", "sensor"):
        was, is_ = before.get(f"{kind}_identity") or {}, now.get(f"{kind}_identity") or {}
        if was.get("serial_number") and is_.get("serial_number") and was["serial_number"] != is_["serial_number"]:
            log(f"warning: {journal} was started with {kind} serial number {was['serial_number']}, now "
                f"{is_['serial_number']} is connected: the journal's provenance keeps the first; if the unit was "
                "swapped, start a new run")


def check_same_settings(before: dict, now: dict, journal: Path, log: Callable[[str], None]) -> None:
    """On --resume: say so when the configuration's estimator settings (``now``'s
    :data:`CALIBRATION_OPTIONS_KEY`) are not those the journal was started with (``before``):
    this run solves with the configuration's, ``solve`` of the journal with the first run's."""
    settings = now[CALIBRATION_OPTIONS_KEY]
    if before.get(CALIBRATION_OPTIONS_KEY, settings) != settings:
        log(f"note: the configuration's [calibration] changed since {journal} was started: this run solves with the "
            "configuration's; the journal keeps the first run's, which `spherecal solve` of it starts from")


def recorded_options(provenance: dict, path: Path | str, log: Callable[[str], None] | None = None,
                     flags: tuple[str, ...] = ("robot_error_model", "fit_radius", "nominal_transform"),
                     what: str = "recording", **given) -> CalibrationOptions:
    """The estimator's settings for solving a journal or recording: those its provenance
    holds (:data:`CALIBRATION_OPTIONS_KEY`, written by ``calibrate``, stop-and-go and on
    the fly: the run's ``[calibration]`` and nominal transform, so that ``solve`` of its
    journal gives the run's answer), each of ``given`` (the command line's) replacing its
    own; the defaults for one that holds none. Says which settings came from the
    ``what`` (those other than the defaults) and which of ``flags`` (the settings the
    command line can give) replace them. A recorded setting this version does not know
    is named and ignored; one it refuses is an InputError naming it."""
    log = log or progress_log("run")
    recorded = provenance.get(CALIBRATION_OPTIONS_KEY)
    if recorded is None:
        return CalibrationOptions(**given)
    if not isinstance(recorded, dict):
        raise InputError(f"{path}: provenance.{CALIBRATION_OPTIONS_KEY} is not an object of settings "
                         f"({type(recorded).__name__})")
    known = CalibrationOptions.model_fields
    unknown = sorted(k for k in recorded if k not in known)
    if unknown:
        log(f"{path}: recorded settings this version does not know, ignored: {', '.join(unknown)}")
    taken = {k: v for k, v in recorded.items() if k in known and k not in given}
    try:
        options = CalibrationOptions.model_validate({**taken, **given})
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(p) for p in e['loc'])} = {e.get('input')!r}: {e['msg']}"
                             for e in exc.errors())
        raise InputError(f"{path}: provenance.{CALIBRATION_OPTIONS_KEY}: a setting this version refuses: {problems} "
                         "(give the option on the command line instead)") from None
    defaults = CalibrationOptions().model_dump(mode="json")
    dumped = options.model_dump(mode="json")
    said = [_setting_text(k, getattr(options, k)) for k in taken if dumped[k] != defaults[k]]
    replaced = [_FLAGS[k] for k in given if k in recorded]
    log(f"settings from the {what} (the run's [calibration]): {', '.join(said) or 'the defaults'}; "
        + (f"{', '.join(replaced)} given instead of the {what}'s" if replaced else
           f"{', '.join(_FLAGS[k] for k in flags)} replace them"))
    return options


#: The command line's options replacing a recorded setting.
_FLAGS = {"robot_error_model": "--robot-error-model", "fit_radius": "--fit-radius", "nominal_transform": "--nominal",
          "station_rotation_tolerance_deg": "--station-rotation-tolerance-deg",
          "identify_kinematics": "--identify-kinematics"}


def _setting_text(name: str, value) -> str:
    if name == "nominal_transform":
        return (f"nominal transform [{', '.join(f'{c:g}' for c in value.translation_mm)}] mm, quaternion_wxyz "
                f"[{', '.join(f'{c:.5f}' for c in value.quaternion_wxyz)}]")
    return f"{name} = {value!r}" if not isinstance(value, str) else f"{name} = \"{value}\""
