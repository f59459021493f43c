"""What the core expects of an exporter, and how the selected exporters' files are written.

An exporter turns a :class:`~spherecal.core.models.CalibrationResult` into the files some
controller or tool loads. The core knows no robot brand: every export, the core's own
included, is an :class:`Exporter` that a plugin registers through the
``spherecal_register_exporters`` hook (:mod:`spherecal.plugins.hookspecs`); the core's
brand-free ones (4x4 matrices, xyz + quaternion, ROS 2, :mod:`spherecal.report.export`)
are registered by the built-in plugin :mod:`spherecal.plugins.core_exports`, a robot
plugin registers its controller's format (docs/results.md lists the built-in robot's).

An exporter is pure: ``write(result, settings)`` returns the text (or bytes) of each file
it declared, and :func:`write_exports` here, at the edge, writes them. Which exporters run
and with which settings comes from the ``[export]`` section of the configuration
(:meth:`spherecal.plugins.host.PluginHost.export_plan`, docs/configuration.md).

``result.json`` (the result itself, :func:`spherecal.io.dataset.write_result`) is always
written with the exports: ``spherecal validate`` and ``scan`` read it.
"""

from __future__ import annotations

import re
import string
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

from pydantic import BaseModel, ConfigDict, ValidationError

from spherecal.io import files as safeio
from spherecal.core.errors import InputError, PluginError, SpherecalError
from spherecal.core.models import CalibrationResult, MountingMode

__all__ = [
    "MOUNTINGS",
    "RESERVED_FILE_NAMES",
    "TEMPLATE_FIELDS",
    "ExportNote",
    "Exporter",
    "NoSettings",
    "SelectedExporter",
    "calibrated_model_warning",
    "sensor_frame_warning",
    "check_file_name",
    "ExportPlan",
    "write_exports",
]

#: Both mounting modes, the default of :attr:`Exporter.mountings`.
MOUNTINGS: tuple[MountingMode, ...] = ("eye_in_hand", "eye_to_hand")
#: Files of a calibration folder no exporter may write.
RESERVED_FILE_NAMES = frozenset({"result.json", "journal.jsonl", "report.html", "robot_calibrated.urdf"})
#: The result, the acquisition journal and the identified robot model of a calibration folder.
RESULT_NAME, JOURNAL_NAME, CALIBRATED_URDF_NAME = "result.json", "journal.jsonl", "robot_calibrated.urdf"
#: Names a file-name template may use besides the exporter's own settings fields.
TEMPLATE_FIELDS = ("transform_name", "mounting")

_FILE_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+-]*$")


class NoSettings(BaseModel):
    """The settings model of an exporter that takes none: ``[export.<name>]`` must then
    be absent or empty."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)


@dataclass(frozen=True)
class ExportNote:
    """What an exporter tells the reader of the report: ``text``, a short paragraph on how
    to use its files on the controller (or in the tool they are for), and ``code``, an
    optional snippet shown as preformatted text under it (a declaration to paste, a
    command to run), and ``warning``, a line the terminal prints when the files are
    written: what the files still lack before they can be used. Plain text; the report
    escapes it."""

    title: str
    text: str
    code: str = ""
    warning: str = ""


#: The first comment line of every exported file of a result rated RED (written only
#: because --force was given). Plain words, no '--' (not allowed in an XML comment), no
#: line break: it fits any file's comment syntax.
RED_WARNING = ("WARNING: spherecal rated this result RED and wrote it only because it was forced; "
               "do not use it in production (see result.json diagnostics.verdict and the report)")


def red_warning(result: CalibrationResult) -> str:
    """:data:`RED_WARNING` when ``result`` was rated RED (its ``diagnostics.verdict``),
    else "". An exporter puts it, when not empty, in a comment at the top of each file it
    writes, so that a RED result written with ``--force`` says so wherever it is copied."""
    verdict = result.diagnostics.verdict
    return RED_WARNING if isinstance(verdict, dict) and verdict.get("level") == "red" else ""


def sensor_frame_warning(result: CalibrationResult) -> str:
    """When the calibrated sensor frame is not the frame the data's profiles came in (a
    ROS 2 bag's clouds with the laser line along their x: ``result.data_frames``), that it
    is not, and the fixed rotation between them (``sensor_from_cloud``); else "". One line
    of plain words without '--', like :data:`RED_WARNING`, for a comment of each file an
    exporter writes, so that the sensor frame is not taken for the clouds' frame."""
    frames = result.data_frames
    if frames is None or frames.cloud_is_sensor:
        return ""
    cloud = f"'{frames.cloud_frame_id}'" if frames.cloud_frame_id else "(not named)"
    return (f"SENSOR FRAME: 'sensor' here is spherecal's calibrated sensor frame, not the frame the clouds came in "
            f"{cloud}: sensor_from_cloud = {frames.sensor_from_cloud_text or 'not the identity'} (result.json "
            "data_frames)")


def calibrated_model_warning(result: CalibrationResult) -> str:
    """For a kinematic calibration (the arm's geometry identified with the transform):
    that the transform goes with spherecal's calibrated arm model, the accuracy it holds
    there (``robot_error.point_error_k2_mm``) and what to expect on the controller's
    nominal model (``robot_error.point_error_nominal_arm_k2_mm``); else "". One line of
    plain words without '--', like :data:`RED_WARNING`: an exporter puts it in a comment
    of each file it writes, so that the transform is not taken for one that holds on the
    nominal model wherever it is copied."""
    err = result.robot_error
    if err is None or not any(p.identified for p in err.kinematic_parameters or []):
        return ""
    nominal = err.point_error_nominal_arm_k2_mm
    on_nominal = (f"on the controller's nominal model expect {nominal:.3f} mm (k = 2)" if nominal is not None else
                  "on the controller's nominal model expect more (this result file does not say how much)")
    return (f"KINEMATIC CALIBRATION: this transform goes with spherecal's calibrated arm model "
            f"({CALIBRATED_URDF_NAME}); a point measured at a new pose is within {err.point_error_k2_mm:.3f} mm "
            f"(k = 2) only where poses go through that model; {on_nominal}")


@dataclass(frozen=True)
class Exporter:
    """One export, registered by a plugin with ``registry.add_exporter(Exporter(...))``.

    :param name: unique among the installed exporters, lower case letters, digits and
        underscores (``"abb_rapid"``); the key of its settings table ``[export.<name>]``
        and what ``[export] run`` lists. ``run`` itself is not a valid name.
    :param description: one line for ``spherecal plugins`` and the docs.
    :param files: the file names it writes, as templates: ``{transform_name}``
        (``flange_from_sensor`` or ``base_from_sensor``), ``{mounting}`` and any field of
        its settings may appear (``"{module_name}.mod"``). Each resolves to a plain file
        name in the output folder (no folder part, not one of :data:`RESERVED_FILE_NAMES`).
    :param write: ``write(result, settings) -> {file name: text or bytes}``, one entry per
        resolved file name, nothing else; pure (no I/O). ``settings`` is an instance of
        ``settings_model``. A :class:`~spherecal.core.errors.SpherecalError` it raises passes
        through; anything else is a :class:`~spherecal.core.errors.PluginError` naming the plugin.
    :param settings_model: a pydantic model with ``extra="forbid"`` (a typo is an error)
        validating ``[export.<name>]``; a field without a default is a setting the user
        must give, and a run that selects the exporter without it stops before anything
        moves with an error naming ``export.<name>.<field>``. Default: :class:`NoSettings`.
    :param mountings: the mounting modes it applies to (default both).
    :param robot_types: the robot type names it applies to, or None for any robot (a
        brand-free export). When the robot type is not known (``spherecal solve`` of a
        dataset that does not name its robot), every exporter applies.
    A result rated RED is exported only when the user forces it; each file's first
    comment should then be :func:`red_warning` (the core's exporters and the ABB one do).

    :param note: ``note(result, settings) -> ExportNote | None``: how to use the files on
        the controller, for the report (:class:`ExportNote`); None: the exporter says
        nothing there. The note of the robot's own exporter comes first in the report.
    """

    name: str
    description: str
    files: tuple[str, ...]
    write: Callable[[CalibrationResult, BaseModel], Mapping[str, str | bytes]]
    settings_model: type[BaseModel] = NoSettings
    mountings: tuple[MountingMode, ...] = MOUNTINGS
    robot_types: tuple[str, ...] | None = None
    note: Callable[[CalibrationResult, BaseModel], ExportNote | None] | None = None

    def applies_to(self, mounting: str, robot_type: str | None) -> bool:
        """Whether the exporter is for this mounting and robot type (None: not known,
        which any robot type matches)."""
        if mounting not in self.mountings:
            return False
        return self.robot_types is None or robot_type is None or robot_type in self.robot_types

    def template_fields(self) -> set[str]:
        """The names the file-name templates use."""
        names: set[str] = set()
        for template in self.files:
            for _, name, _, _ in string.Formatter().parse(template):
                if name is not None:
                    names.add(name)
        return names

    def file_names(self, result: CalibrationResult, settings: BaseModel) -> tuple[str, ...]:
        """The files it writes for ``result`` with ``settings``, resolved; an
        :class:`InputError` naming the template when one does not give a plain file name."""
        values = {"transform_name": result.transform_name, "mounting": result.mounting}
        values.update(settings.model_dump())
        out = []
        for template in self.files:
            name = template.format(**values)
            check_file_name(name, f"exporter '{self.name}': file {template!r}")
            out.append(name)
        return tuple(out)

    def file_patterns(self) -> tuple[str, ...]:
        """Glob patterns of the files it may write (each template field becomes ``*``),
        to find an earlier run's files in a folder."""
        out = []
        for template in self.files:
            parts = []
            for literal, name, _, _ in string.Formatter().parse(template):
                parts.append(literal)
                if name is not None:
                    parts.append("*")
            out.append("".join(parts))
        return tuple(out)


def check_file_name(name: str, what: str) -> str:
    """``name`` if it is a plain file name an exporter may write; InputError otherwise."""
    if not isinstance(name, str) or not _FILE_NAME_RE.match(name) or name in (".", ".."):
        raise InputError(f"{what} resolves to {name!r}, not a plain file name (letters, digits, '_', '.', '+', "
                         "'-'; no folder part)")
    if name in RESERVED_FILE_NAMES:
        raise InputError(f"{what} resolves to {name!r}, which spherecal writes itself")
    return name


@dataclass(frozen=True)
class SelectedExporter:
    """An exporter chosen for a run, with its validated settings and the plugin that
    registered it."""

    exporter: Exporter
    settings: BaseModel
    plugin: str = "<unknown plugin>"

    @property
    def name(self) -> str:
        return self.exporter.name

    def render(self, result: CalibrationResult) -> dict[str, str | bytes]:
        """The exporter's files for ``result``: ``{file name: text or bytes}``, checked
        against the names it declared."""
        expected = self.exporter.file_names(result, self.settings)
        try:
            files = self.exporter.write(result, self.settings)
        except Exception as exc:
            if isinstance(exc, SpherecalError):
                raise
            raise PluginError(f"plugin '{self.plugin}': exporter '{self.name}' raised {type(exc).__name__}: {exc}") from exc
        if not isinstance(files, Mapping) or set(files) != set(expected):
            got = sorted(files) if isinstance(files, Mapping) else type(files).__name__
            raise PluginError(f"plugin '{self.plugin}': exporter '{self.name}' returned {got}; it declared "
                              f"{sorted(expected)}")
        for fname, content in files.items():
            if not isinstance(content, (str, bytes)):
                raise PluginError(f"plugin '{self.plugin}': exporter '{self.name}' returned a "
                                  f"{type(content).__name__} for {fname}; expected str or bytes")
        return dict(files)

    def note(self, result: CalibrationResult) -> ExportNote | None:
        if self.exporter.note is None:
            return None
        note = self.exporter.note(result, self.settings)
        if note is not None and not isinstance(note, ExportNote):
            raise PluginError(f"plugin '{self.plugin}': exporter '{self.name}' note returned a "
                              f"{type(note).__name__}; expected spherecal.io.exporters.ExportNote or None")
        return note


@dataclass(frozen=True)
class ExportPlan:
    """The exporters a run uses, in order (the robot's own first), and those left out
    with the reason (``{name: why}``), for the log."""

    selected: tuple[SelectedExporter, ...] = ()
    left_out: Mapping[str, str] = field(default_factory=dict)
    robot_type: str | None = None

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.selected]

    def file_patterns(self) -> tuple[str, ...]:
        return tuple(p for s in self.selected for p in s.exporter.file_patterns())

    def notes(self, result: CalibrationResult) -> list[ExportNote]:
        """The notes of the selected exporters for ``result`` (the robot's own first)."""
        return [n for s in self.selected if (n := s.note(result)) is not None]


def write_exports(
    result: CalibrationResult,
    out_dir: str | Path,
    exporters: ExportPlan | Sequence[SelectedExporter | Exporter],
    *,
    overwrite: bool = False,
) -> dict[str, Path]:
    """Write ``result.json`` and every file of ``exporters`` into ``out_dir`` (created if
    needed); return ``{file name: path}``.

    ``exporters``: an :class:`ExportPlan` (what a run uses: the plugin host's
    :meth:`~spherecal.plugins.host.PluginHost.export_plan`), or exporters (an
    :class:`Exporter` runs with its default settings).
    Existing files are replaced only with ``overwrite=True``; every file is rendered and
    checked before the first is written, so nothing is written if any would be refused.
    """
    if not isinstance(result, CalibrationResult):
        raise InputError(f"expected a CalibrationResult, got {type(result).__name__}")
    selected = _selection(exporters)
    out = Path(out_dir)
    files: dict[str, str | bytes] = {}
    owner: dict[str, str] = {}
    for s in selected:
        for fname, content in s.render(result).items():
            if fname in files:
                raise InputError(f"exporters '{owner[fname]}' and '{s.name}' both write {fname}; give one of them "
                                 "another file name in its [export.<name>] settings, or run only one")
            files[fname], owner[fname] = content, s.name
    paths = {fname: out / fname for fname in [*files, "result.json"]}
    if not overwrite:
        existing = [str(p) for p in paths.values() if p.exists()]
        if existing:
            raise InputError(f"{existing[0]} exists; pass overwrite=True to replace the exports")
    out.mkdir(parents=True, exist_ok=True)
    for p in paths.values():  # no link nor device among them: nothing is written if one is refused
        safeio.check_writable_target(p)
    for fname, content in files.items():
        if isinstance(content, bytes):
            safeio.write_bytes(paths[fname], content)
        else:
            safeio.write_text(paths[fname], content)
    from spherecal.io.dataset import write_result

    write_result(paths["result.json"], result, overwrite=True)
    return paths


def _selection(exporters) -> tuple[SelectedExporter, ...]:
    if isinstance(exporters, ExportPlan):
        return exporters.selected
    out = []
    for e in exporters:
        if isinstance(e, SelectedExporter):
            out.append(e)
        elif isinstance(e, Exporter):
            try:
                settings = e.settings_model()
            except ValidationError as exc:
                missing = ", ".join(f"export.{e.name}." + ".".join(map(str, err["loc"])) for err in exc.errors())
                raise InputError(f"exporter '{e.name}' needs settings: {missing}") from None
            out.append(SelectedExporter(e, settings))
        else:
            raise InputError(f"expected an Exporter or SelectedExporter, got {type(e).__name__}")
    return tuple(out)

