"""The ABB RAPID export of a calibration: the sensor frame as a ``tooldata`` (eye-in-hand)
or ``wobjdata`` (eye-to-hand) declaration in a program module, registered as the exporter
``abb_rapid`` (:data:`RAPID_EXPORTER`) for the ``abb_irb2400`` robot type.

Conventions: mm, quaternion ``[q1, q2, q3, q4]`` = (w, x, y, z), scalar first, as RAPID
``orient`` holds it; ``tframe`` is ``flange_from_sensor`` (tool0 is the flange),
``uframe`` is ``base_from_sensor`` (read by the controller in world coordinates). See
docs/results.md, "RAPID".
"""

from __future__ import annotations

import math
import re

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from spherecal.plugins import (
    MM_DECIMALS,
    QUAT_DECIMALS,
    CalibrationResult,
    ExportNote,
    Exporter,
    InputError,
    calibrated_model_warning,
    check_result,
    fixed,
    frames_of,
    red_warning,
    rounded_quaternion_wxyz,
    sensor_frame_warning,
)

__all__ = [
    "RAPID_MAX_LINE",
    "AbbRapidExportSettings",
    "RAPID_EXPORTER",
    "check_rapid_identifier",
    "rapid_declaration",
    "rapid_module",
    "read_rapid",
]

#: Longest line written into a RAPID file (the FlexPendant shows about this many;
#: a RAPID string holds at most 80 characters).
RAPID_MAX_LINE = 80
#: Largest tool mass the export accepts, kg (the largest ABB arms carry well under this).
MAX_TOOL_MASS_KG = 2000.0
#: Largest centre-of-gravity coordinate the export accepts, mm (a typo guard).
MAX_COG_MM = 5000.0

_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_RAPID_RESERVED = frozenset(
    """ALIAS AND BACKWARD CASE CONNECT CONST DEFAULT DIV DO ELSE ELSEIF ENDFOR ENDFUNC ENDIF
    ENDMODULE ENDPROC ENDRECORD ENDTEST ENDTRAP ENDWHILE ERROR EXIT FALSE FOR FROM FUNC GOTO IF
    INOUT LOCAL MOD MODULE NOSTEPIN NOT NOVIEW OR PERS PROC RAISE READONLY RECORD RETRY RETURN
    STEP SYSMODULE TASK TEST THEN TO TRAP TRUE TRYNEXT UNDO VAR VIEWONLY WHILE WITH XOR""".split()
)
#: Predefined data a declaration must not redefine.
_RAPID_PREDEFINED = frozenset({"TOOL0", "WOBJ0", "LOAD0"})


def check_rapid_identifier(name: str, what: str = "RAPID name") -> str:
    """Return ``name`` if it is a valid RAPID identifier (a letter, then letters, digits
    or underscores, at most 32 characters, not a reserved word nor tool0/wobj0/load0);
    else raise InputError saying why."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", name):
        raise InputError(
            f"{what} {name!r} is not a valid RAPID identifier: start with a letter, then use only "
            "letters, digits and underscores"
        )
    if len(name) > 32:
        raise InputError(f"{what} {name!r} has {len(name)} characters; RAPID identifiers have at most 32")
    if name.upper() in _RAPID_RESERVED:
        raise InputError(f"{what} {name!r} is a RAPID reserved word; choose another name")
    if name.upper() in _RAPID_PREDEFINED:
        raise InputError(f"{what} {name!r} is predefined on the controller and must not be redefined")
    return name


def _rapid_comment_lines(result: CalibrationResult, extra: list[str]) -> list[str]:
    a, b = frames_of(result.transform_name)
    lines = [
        f"! spherecal: {result.transform_name} ({result.mounting}), mm,",
        "! orient [q1,q2,q3,q4] = quaternion (w, x, y, z)",
        f"! 1-sigma rotation deg about {a} x y z: "
        + " ".join(fixed(v, 4) for v in result.std_rotation_deg),
        f"! 1-sigma translation mm along {a} x y z: "
        + " ".join(fixed(v, 4) for v in result.std_translation_mm),
    ]
    said = (red_warning(result), calibrated_model_warning(result), sensor_frame_warning(result))
    warnings = [f"! {line}" for w in said if w for line in _wrap(w)]
    return warnings + lines + extra


def _wrap(text: str, width: int = 76) -> list[str]:
    """``text`` in lines of at most ``width`` characters, broken at spaces (a RAPID
    module's comment lines are kept within 80 characters)."""
    import textwrap

    return textwrap.wrap(text, width)


def rapid_declaration(
    result: CalibrationResult,
    name: str | None = None,
    *,
    mass_kg: float | None = None,
    cog_mm: tuple[float, float, float] | None = None,
) -> str:
    """A RAPID ``PERS`` declaration with comments, every line at most
    :data:`RAPID_MAX_LINE` characters.

    Eye-in-hand: ``PERS tooldata <name> := [TRUE, [[x,y,z],[q1,q2,q3,q4]],
    [mass,[cog],[1,0,0,0],0,0,0]];`` -- the sensor frame as the tool frame (``tframe`` is
    ``flange_from_sensor``), robot-held. ``name`` defaults to ``tSensor``. The load is
    the sensor and its bracket: ``mass_kg`` (> 0) and ``cog_mm`` (in tool0), both from the
    data sheet or LoadIdentify. spherecal does not invent them (a wrong load degrades the
    controller's motion supervision): without them the load is written as mass 0 at the
    flange, which the controller refuses for a robot-held tool, so the tooldata cannot be
    used until the real values are filled in; the comment above it says so.

    Eye-to-hand: ``PERS wobjdata <name> := [FALSE, TRUE, "", [[x,y,z],[q1..q4]],
    [[0,0,0],[1,0,0,0]]];`` -- the sensor frame as a fixed user frame (``uframe`` is
    ``base_from_sensor``; the controller reads it in world coordinates, equal to base
    unless the robot's base frame was moved). ``name`` defaults to ``wobjSensor``.

    Positions to :data:`MM_DECIMALS` decimals, quaternions to :data:`QUAT_DECIMALS`.
    """
    result = check_result(result)
    xyz = "[" + ", ".join(fixed(v, MM_DECIMALS) for v in result.transform.translation_mm) + "]"
    quat = "[" + ", ".join(rounded_quaternion_wxyz(result.transform)) + "]"
    if result.mounting == "eye_in_hand":
        name = check_rapid_identifier(name or "tSensor", "tooldata name")
        if (mass_kg is None) != (cog_mm is None):
            raise InputError("the tool load needs both mass_kg and cog_mm (or neither, to be filled in later)")
        if mass_kg is None:
            mass_kg, cog = 0.0, np.zeros(3)
            load_lines = ["! load NOT GIVEN: mass 0, which the controller refuses: fill in",
                          "! the real mass (kg) and cog (mm, tool0) before use",
                          "! (data sheet or LoadIdentify)"]
        else:
            if not (math.isfinite(mass_kg) and mass_kg > 0):
                raise InputError(f"mass_kg = {mass_kg}: the tool load must have a mass > 0 kg (the controller "
                                 "rejects 0)")
            cog = np.asarray(cog_mm, float)
            if cog.shape != (3,) or not np.all(np.isfinite(cog)):
                raise InputError(f"cog_mm must be 3 finite numbers (mm, in tool0), got {cog_mm!r}")
            load_lines = [f"! load: {fixed(mass_kg, 3)} kg at [{', '.join(fixed(v, 1) for v in cog)}] mm (tool0)"]
        cog_txt = "[" + ", ".join(fixed(v, 1) for v in cog) + "]"
        comments = _rapid_comment_lines(result, load_lines)
        body = [
            f"PERS tooldata {name} := [TRUE,",
            f"    [{xyz},",
            f"     {quat}],",
            f"    [{fixed(mass_kg, 3)}, {cog_txt}, [1, 0, 0, 0], 0, 0, 0]];",
        ]
    else:
        name = check_rapid_identifier(name or "wobjSensor", "wobjdata name")
        comments = _rapid_comment_lines(result, [
            "! user frame = sensor frame, fixed in the cell (not robot-held);",
            "! uframe is read in world coordinates (= base unless the base moved)",
        ])
        body = [
            f"PERS wobjdata {name} := [FALSE, TRUE, \"\",",
            f"    [{xyz},",
            f"     {quat}],",
            "    [[0, 0, 0], [1, 0, 0, 0]]];",
        ]
    return _check_rapid_lines(comments + body)


def _check_rapid_lines(lines: list[str]) -> str:
    for line in lines:
        if len(line) > RAPID_MAX_LINE:  # only implausibly large coordinates get here
            raise InputError(
                f"RAPID line of {len(line)} characters exceeds {RAPID_MAX_LINE}: {line!r}; "
                "check that the translation is in mm and plausible"
            )
    return "\n".join(lines) + "\n"


def rapid_module(
    result: CalibrationResult,
    name: str | None = None,
    *,
    module_name: str = "SpherecalSensor",
    mass_kg: float | None = None,
    cog_mm: tuple[float, float, float] | None = None,
) -> str:
    """:func:`rapid_declaration` wrapped in ``MODULE <module_name> ... ENDMODULE``, a file
    the controller loads as a program module."""
    check_rapid_identifier(module_name, "module name")
    decl = rapid_declaration(result, name, mass_kg=mass_kg, cog_mm=cog_mm)
    return _check_rapid_lines([f"MODULE {module_name}"] + ["  " + line for line in decl.splitlines()] + ["ENDMODULE"])


# (patterns that ``re`` compiles when read_rapid first uses them: writing the export
# does not need them)
_RAPID_TOOL = (
    rf"PERS\s+tooldata\s+(?P<name>[A-Za-z]\w*)\s*:=\s*\[\s*(?P<robhold>TRUE|FALSE)\s*,"
    rf"\s*\[\s*\[(?P<xyz>[^\]]*)\]\s*,\s*\[(?P<q>[^\]]*)\]\s*\]\s*,"
    rf"\s*\[\s*(?P<mass>{_FLOAT})\s*,\s*\[(?P<cog>[^\]]*)\]\s*,\s*\[(?P<aom>[^\]]*)\]"
    rf"\s*,\s*(?P<ix>{_FLOAT})\s*,\s*(?P<iy>{_FLOAT})\s*,\s*(?P<iz>{_FLOAT})\s*\]\s*\]\s*;"
)
_RAPID_WOBJ = (
    r"PERS\s+wobjdata\s+(?P<name>[A-Za-z]\w*)\s*:=\s*\[\s*(?P<robhold>TRUE|FALSE)\s*,"
    r"\s*(?P<ufprog>TRUE|FALSE)\s*,\s*\"(?P<ufmec>[^\"]*)\"\s*,"
    r"\s*\[\s*\[(?P<xyz>[^\]]*)\]\s*,\s*\[(?P<q>[^\]]*)\]\s*\]\s*,"
    r"\s*\[\s*\[(?P<oxyz>[^\]]*)\]\s*,\s*\[(?P<oq>[^\]]*)\]\s*\]\s*\]\s*;"
)


def _numbers(text: str, n: int, what: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise InputError(f"{what}: not a list of numbers: [{text}]") from None
    if values.size != n:
        raise InputError(f"{what}: expected {n} numbers, got {values.size}: [{text}]")
    return values


def read_rapid(text: str) -> dict:
    """Parse the tooldata or wobjdata declaration in ``text`` (comments ignored).

    Returns ``{"kind": "tooldata"|"wobjdata", "name", "robhold", "xyz_mm",
    "quaternion_wxyz"}`` plus ``"mass_kg"`` and ``"cog_mm"`` for a tooldata, ``"ufprog"``
    for a wobjdata."""
    code = "\n".join(line.split("!", 1)[0] for line in text.splitlines())
    m = re.search(_RAPID_TOOL, code, re.IGNORECASE)
    if m:
        return {
            "kind": "tooldata",
            "name": m["name"],
            "robhold": m["robhold"].upper() == "TRUE",
            "xyz_mm": _numbers(m["xyz"], 3, "tframe.trans"),
            "quaternion_wxyz": _numbers(m["q"], 4, "tframe.rot"),
            "mass_kg": float(m["mass"]),
            "cog_mm": _numbers(m["cog"], 3, "tload.cog"),
        }
    m = re.search(_RAPID_WOBJ, code, re.IGNORECASE)
    if m:
        return {
            "kind": "wobjdata",
            "name": m["name"],
            "robhold": m["robhold"].upper() == "TRUE",
            "ufprog": m["ufprog"].upper() == "TRUE",
            "xyz_mm": _numbers(m["xyz"], 3, "uframe.trans"),
            "quaternion_wxyz": _numbers(m["q"], 4, "uframe.rot"),
        }
    raise InputError("no 'PERS tooldata' or 'PERS wobjdata' declaration found")




# --- the exporter ------------------------------------------------------------------------------------------
def _identifier(value: str, what: str) -> str:
    try:
        return check_rapid_identifier(value, what)
    except InputError as exc:
        raise ValueError(str(exc)) from None


class AbbRapidExportSettings(BaseModel):
    """``[export.abb_rapid]``: names and tool load of the RAPID export. Lengths in mm,
    mass in kg."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    tool_name: str = Field("tSensor", description="name of the tooldata (eye_in_hand), a RAPID identifier")
    wobj_name: str = Field("wobjSensor", description="name of the wobjdata (eye_to_hand), a RAPID identifier")
    module_name: str = Field("SpherecalSensor", description="name of the program module; the file is <module_name>.mod")
    mass_kg: float | None = Field(
        None, gt=0, le=MAX_TOOL_MASS_KG,
        description="mass of the sensor and its bracket (tooldata tload.mass), kg, from the data sheet or "
        "LoadIdentify; not given: the tooldata is written with mass 0, which the controller refuses until it is "
        "filled in")
    cog_mm: tuple[float, float, float] | None = Field(
        None, description="their centre of gravity in tool0 (tload.cog), mm; given with mass_kg")

    @field_validator("tool_name", "wobj_name", "module_name")
    @classmethod
    def _rapid_name(cls, v, info):
        return _identifier(v, info.field_name)

    @model_validator(mode="after")
    def _load_whole(self):
        if (self.mass_kg is None) != (self.cog_mm is None):
            given, missing = ("mass_kg", "cog_mm") if self.cog_mm is None else ("cog_mm", "mass_kg")
            raise ValueError(f"{given} without {missing}: the tool load needs both (the centre of gravity in tool0, mm, "
                             "and the mass, kg), or neither")
        return self

    @field_validator("cog_mm")
    @classmethod
    def _cog(cls, v):
        if v is not None and any(not math.isfinite(c) or abs(c) > MAX_COG_MM for c in v):
            raise ValueError(f"cog_mm = {list(v)}: each coordinate must be finite and within +-{MAX_COG_MM:g} mm "
                             "(tool0, mm; not metres)")
        return v


def _name(result: CalibrationResult, s: AbbRapidExportSettings) -> str:
    return s.tool_name if result.mounting == "eye_in_hand" else s.wobj_name


def _write(result: CalibrationResult, s: AbbRapidExportSettings) -> dict[str, str]:
    text = rapid_module(result, _name(result, s), module_name=s.module_name, mass_kg=s.mass_kg, cog_mm=s.cog_mm)
    return {f"{s.module_name}.mod": text}


def _note(result: CalibrationResult, s: AbbRapidExportSettings) -> ExportNote:
    name = _name(result, s)
    warning = ""
    if result.mounting == "eye_in_hand":
        text = (f"On an ABB controller this is tooldata.tframe: load {s.module_name}.mod (FlexPendant: Program "
                f"Editor, Modules, Load Module) and move with \\Tool:={name}.")
        if s.mass_kg is None:
            text += (" Its load is not given: it is written as mass 0, which the controller refuses for a robot-held "
                     "tool; give the mass and centre of gravity ([export.abb_rapid] mass_kg, cog_mm) or run "
                     "LoadIdentify before using it.")
            warning = (f"{s.module_name}.mod: {name}'s load (mass, centre of gravity) is not given; the controller "
                       "refuses the tooldata until it is filled in ([export.abb_rapid] mass_kg and cog_mm, or "
                       "LoadIdentify); spherecal does not invent a load")
    else:
        text = (f"On an ABB controller this is wobjdata.uframe, read in world coordinates (equal to base unless "
                f"the robot's base frame was moved): load {s.module_name}.mod and move with \\WObj:={name}.")
    if calibrated_model_warning(result):
        text += (" The arm's geometry was calibrated with it: the controller keeps its nominal model, so give the "
                 "robot the calibrated model ([robot] calibrated_model, applied on the PC side) wherever the accuracy "
                 "of the calibrated model is needed (the module's first comment says what to expect without it).")
    return ExportNote(title="ABB controller (RAPID)", text=text,
                      code=rapid_declaration(result, name, mass_kg=s.mass_kg, cog_mm=s.cog_mm), warning=warning)


RAPID_EXPORTER = Exporter(
    name="abb_rapid",
    description="ABB RAPID program module: the sensor as tooldata (eye_in_hand) or wobjdata (eye_to_hand)",
    files=("{module_name}.mod",),
    write=_write,
    settings_model=AbbRapidExportSettings,
    robot_types=("abb_irb2400",),
    note=_note,
)
