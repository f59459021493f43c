"""Exports of a :class:`~spherecal.models.CalibrationResult` in the forms people load.

Every export is a pure function returning text, and every one has a reader here that
parses it back (the tests check each export against the result it came from):

========================  =====================================  ===========================
export                    writer                                 reader
========================  =====================================  ===========================
4x4 matrices, both ways   :func:`matrix_text`                    :func:`read_matrix_text`
xyz + ABB quaternion      :func:`xyz_quaternion_text`            :func:`read_xyz_quaternion`
RAPID declaration         :func:`rapid_declaration`,             :func:`read_rapid`
                          :func:`rapid_module`
ROS 2 static transform    :func:`ros_static_transform_command`,  :func:`read_ros_command`,
                          :func:`ros_static_transform_yaml`      :func:`read_ros_yaml`
JSON result               :func:`json_text`                      :func:`read_json`
========================  =====================================  ===========================

:func:`write_exports` writes them all into a folder.

Conventions (docs/conventions.md, docs/results.md): ``A_from_B`` maps points from B to
A, ``p_A = T_A_from_B p_B``; lengths in mm, except the ROS exports, which are in metres
as ROS requires. Quaternions are (w, x, y, z) -- ABB ``[q1, q2, q3, q4]`` -- except in the
ROS exports, which use ROS's (x, y, z, w). Each file says its order in a comment.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from .. import safeio
from ..dataio import write_result
from ..errors import InputError
from ..models import CalibrationResult, Pose

__all__ = [
    "MM_DECIMALS",
    "QUAT_DECIMALS",
    "METRE_DECIMALS",
    "MATRIX_DECIMALS",
    "RAPID_MAX_LINE",
    "inverse_name",
    "frames_of",
    "matrix_text",
    "read_matrix_text",
    "xyz_quaternion_text",
    "read_xyz_quaternion",
    "check_rapid_identifier",
    "rapid_declaration",
    "rapid_module",
    "read_rapid",
    "default_ros_frames",
    "ros_static_transform_command",
    "ros_static_transform_yaml",
    "read_ros_command",
    "read_ros_yaml",
    "json_text",
    "read_json",
    "write_exports",
]

#: Decimals of millimetre values in the human-facing exports (0.1 um).
MM_DECIMALS = 4
#: Decimals of quaternion components (about 1e-6 degree).
QUAT_DECIMALS = 8
#: Decimals of metre values in the ROS exports (0.1 um, as MM_DECIMALS).
METRE_DECIMALS = 7
#: Decimals of every element of the 4x4 matrices.
MATRIX_DECIMALS = 10
#: Longest line written into a RAPID file (the FlexPendant shows about this many;
#: a RAPID string holds at most 80 characters).
RAPID_MAX_LINE = 80

_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


# --- small helpers ----------------------------------------------------------------------------
def _fmt(value: float, decimals: int) -> str:
    """Fixed-point text without a negative zero."""
    text = f"{float(value):.{decimals}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return text


def frames_of(name: str) -> tuple[str, str]:
    """``("flange", "sensor")`` from ``"flange_from_sensor"``."""
    parts = name.split("_from_")
    if len(parts) != 2 or not all(parts):
        raise InputError(f"transform name {name!r} is not of the form 'A_from_B'")
    return parts[0], parts[1]


def inverse_name(name: str) -> str:
    """``"sensor_from_flange"`` from ``"flange_from_sensor"``."""
    a, b = frames_of(name)
    return f"{b}_from_{a}"


def _check_result(result) -> CalibrationResult:
    if not isinstance(result, CalibrationResult):
        raise InputError(f"expected a CalibrationResult, got {type(result).__name__}")
    return result


def _uncertainty_sentence(result: CalibrationResult) -> str:
    target, _ = frames_of(result.transform_name)
    rot = " ".join(_fmt(v, 4) for v in result.std_rotation_deg)
    tr = " ".join(_fmt(v, 4) for v in result.std_translation_mm)
    return (f"1-sigma: rotation {rot} deg about the {target} x y z axes; "
            f"translation {tr} mm along {target} x y z")


def _rounded_quaternion(pose: Pose) -> list[str]:
    """Quaternion (w, x, y, z), w >= 0 as the Pose stores it, as text with
    :data:`QUAT_DECIMALS` decimals (rounding leaves the norm within 2e-8 of 1)."""
    return [_fmt(c, QUAT_DECIMALS) for c in pose.quaternion_wxyz]


# --- 4x4 matrices -------------------------------------------------------------------------------
def matrix_text(result: CalibrationResult) -> str:
    """The transform in both directions as 4x4 homogeneous matrices (mm), each under its
    name in brackets, row-major, :data:`MATRIX_DECIMALS` decimals. Read back with
    :func:`read_matrix_text`."""
    result = _check_result(result)
    name = result.transform_name
    inv = inverse_name(name)
    a, b = frames_of(name)
    lines = [
        "# spherecal calibration result: 4x4 homogeneous transforms",
        f"# mounting: {result.mounting}",
        "# convention: p_A = T_A_from_B @ p_B, p as the column [x, y, z, 1]; "
        "T_A_from_B maps points from frame B into frame A",
        "# units: translation (last column) in millimetres; rotation part dimensionless",
        f"# [{name}]: points of the {b} frame into the {a} frame; [{inv}] is its inverse",
        f"# {_uncertainty_sentence(result)}",
        "# each block: a [name] line, then 4 rows of 4 numbers",
    ]
    for label, T in ((name, result.transform.as_matrix()), (inv, result.transform.inverse().as_matrix())):
        lines.append(f"[{label}]")
        for row in T:
            lines.append(" ".join(f"{_fmt(v, MATRIX_DECIMALS):>20}" for v in row))
    return "\n".join(lines) + "\n"


def read_matrix_text(text: str) -> dict[str, np.ndarray]:
    """Parse :func:`matrix_text` output: ``{name: 4x4 array}``. Raises InputError naming
    the line at fault."""
    out: dict[str, np.ndarray] = {}
    current: str | None = None
    rows: list[list[float]] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        m = re.fullmatch(r"\[(\w+)\]", line)
        if m:
            if current is not None:
                raise InputError(f"line {lineno}: block [{current}] has {len(rows)} rows, expected 4")
            current, rows = m.group(1), []
            continue
        if current is None:
            raise InputError(f"line {lineno}: numbers before any [name] line: {line!r}")
        try:
            row = [float(v) for v in line.split()]
        except ValueError:
            raise InputError(f"line {lineno}: not a row of numbers: {line!r}") from None
        if len(row) != 4:
            raise InputError(f"line {lineno}: expected 4 numbers in a matrix row, got {len(row)}")
        rows.append(row)
        if len(rows) == 4:
            T = np.array(rows)
            if not np.allclose(T[3], [0, 0, 0, 1]):
                raise InputError(f"line {lineno}: last row of [{current}] must be 0 0 0 1, got {T[3].tolist()}")
            out[current] = T
            current, rows = None, []
    if current is not None:
        raise InputError(f"block [{current}] ends after {len(rows)} rows, expected 4")
    if not out:
        raise InputError("no [name] matrix block found")
    return out


# --- xyz + quaternion line ----------------------------------------------------------------------
def xyz_quaternion_text(result: CalibrationResult) -> str:
    """One line ``<name> x y z q1 q2 q3 q4``: translation in mm (:data:`MM_DECIMALS`
    decimals) and the ABB quaternion (w, x, y, z), scalar first (:data:`QUAT_DECIMALS`
    decimals), after comment lines that say so."""
    result = _check_result(result)
    name = result.transform_name
    a, b = frames_of(name)
    xyz = " ".join(_fmt(v, MM_DECIMALS) for v in result.transform.translation_mm)
    q = " ".join(_rounded_quaternion(result.transform))
    return (
        f"# {name} ({result.mounting}): p_{a} = R p_{b} + t\n"
        "# columns: name, x y z (mm, origin of the "
        f"{b} frame in the {a} frame), q1 q2 q3 q4 = quaternion (w, x, y, z), scalar FIRST (ABB order)\n"
        f"# {_uncertainty_sentence(result)}\n"
        f"{name} {xyz} {q}\n"
    )


def read_xyz_quaternion(text: str) -> tuple[str, np.ndarray, np.ndarray]:
    """Parse :func:`xyz_quaternion_text`: ``(name, xyz_mm, quaternion_wxyz)``."""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise InputError(f"expected 'name x y z q1 q2 q3 q4' (8 fields), got {len(parts)}: {line!r}")
        try:
            values = np.array([float(v) for v in parts[1:]])
        except ValueError:
            raise InputError(f"not numbers after the name: {line!r}") from None
        frames_of(parts[0])
        return parts[0], values[:3], values[3:]
    raise InputError("no data line found (only comments or blank lines)")


# --- RAPID ----------------------------------------------------------------------------------------
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
        + " ".join(_fmt(v, 4) for v in result.std_rotation_deg),
        f"! 1-sigma translation mm along {a} x y z: "
        + " ".join(_fmt(v, 4) for v in result.std_translation_mm),
    ]
    return lines + extra


def rapid_declaration(
    result: CalibrationResult,
    name: str | None = None,
    *,
    mass_kg: float = 1.0,
    cog_mm: tuple[float, float, float] | None = None,
) -> str:
    """A RAPID ``PERS`` declaration with comments, every line at most
    :data:`RAPID_MAX_LINE` characters.

    Eye-in-hand: ``PERS tooldata <name> := [TRUE, [[x,y,z],[q1,q2,q3,q4]],
    [mass,[cog],[1,0,0,0],0,0,0]];`` -- the sensor frame as the tool frame (``tframe`` is
    ``flange_from_sensor``), robot-held. ``name`` defaults to ``tSensor``. The load is
    the sensor and its bracket: ``mass_kg`` (default 1.0 kg, must be > 0) and ``cog_mm``
    (in tool0, default half way from the flange to the sensor origin); both are rough
    defaults to replace with the real values (LoadIdentify or the data sheet).

    Eye-to-hand: ``PERS wobjdata <name> := [FALSE, TRUE, "", [[x,y,z],[q1..q4]],
    [[0,0,0],[1,0,0,0]]];`` -- the sensor frame as a fixed user frame (``uframe`` is
    ``base_from_sensor``; the controller reads it in world coordinates, equal to base
    unless the robot's base frame was moved). ``name`` defaults to ``wobjSensor``.

    Positions to :data:`MM_DECIMALS` decimals, quaternions to :data:`QUAT_DECIMALS`.
    """
    result = _check_result(result)
    xyz = "[" + ", ".join(_fmt(v, MM_DECIMALS) for v in result.transform.translation_mm) + "]"
    quat = "[" + ", ".join(_rounded_quaternion(result.transform)) + "]"
    if result.mounting == "eye_in_hand":
        name = check_rapid_identifier(name or "tSensor", "tooldata name")
        if not (math.isfinite(mass_kg) and mass_kg > 0):
            raise InputError(f"mass_kg = {mass_kg}: the tool load must have a mass > 0 kg (the controller rejects 0)")
        cog = np.asarray(result.transform.translation_mm, dtype=float) / 2 if cog_mm is None else np.asarray(cog_mm, float)
        if cog.shape != (3,) or not np.all(np.isfinite(cog)):
            raise InputError(f"cog_mm must be 3 finite numbers (mm, in tool0), got {cog_mm!r}")
        cog_txt = "[" + ", ".join(_fmt(v, 1) for v in cog) + "]"
        comments = _rapid_comment_lines(result, [
            f"! load: {_fmt(mass_kg, 3)} kg at {cog_txt} mm (tool0): estimates, replace",
            "! them with the real values (LoadIdentify or the data sheet)",
        ])
        body = [
            f"PERS tooldata {name} := [TRUE,",
            f"    [{xyz},",
            f"     {quat}],",
            f"    [{_fmt(mass_kg, 3)}, {cog_txt}, [1, 0, 0, 0], 0, 0, 0]];",
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
    mass_kg: float = 1.0,
    cog_mm: tuple[float, float, float] | None = None,
) -> str:
    """:func:`rapid_declaration` wrapped in ``MODULE <module_name> ... ENDMODULE``, a file
    the controller loads as a program module."""
    check_rapid_identifier(module_name, "module name")
    decl = rapid_declaration(result, name, mass_kg=mass_kg, cog_mm=cog_mm)
    return _check_rapid_lines([f"MODULE {module_name}"] + ["  " + line for line in decl.splitlines()] + ["ENDMODULE"])


_RAPID_TOOL = re.compile(
    rf"PERS\s+tooldata\s+(?P<name>[A-Za-z]\w*)\s*:=\s*\[\s*(?P<robhold>TRUE|FALSE)\s*,"
    rf"\s*\[\s*\[(?P<xyz>[^\]]*)\]\s*,\s*\[(?P<q>[^\]]*)\]\s*\]\s*,"
    rf"\s*\[\s*(?P<mass>{_FLOAT})\s*,\s*\[(?P<cog>[^\]]*)\]\s*,\s*\[(?P<aom>[^\]]*)\]"
    rf"\s*,\s*(?P<ix>{_FLOAT})\s*,\s*(?P<iy>{_FLOAT})\s*,\s*(?P<iz>{_FLOAT})\s*\]\s*\]\s*;",
    re.IGNORECASE,
)
_RAPID_WOBJ = re.compile(
    r"PERS\s+wobjdata\s+(?P<name>[A-Za-z]\w*)\s*:=\s*\[\s*(?P<robhold>TRUE|FALSE)\s*,"
    r"\s*(?P<ufprog>TRUE|FALSE)\s*,\s*\"(?P<ufmec>[^\"]*)\"\s*,"
    r"\s*\[\s*\[(?P<xyz>[^\]]*)\]\s*,\s*\[(?P<q>[^\]]*)\]\s*\]\s*,"
    r"\s*\[\s*\[(?P<oxyz>[^\]]*)\]\s*,\s*\[(?P<oq>[^\]]*)\]\s*\]\s*\]\s*;",
    re.IGNORECASE,
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
    m = _RAPID_TOOL.search(code)
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
    m = _RAPID_WOBJ.search(code)
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


# --- ROS ----------------------------------------------------------------------------------------
def default_ros_frames(result: CalibrationResult) -> tuple[str, str]:
    """(parent frame id, child frame id): ``("tool0", "sensor")`` eye-in-hand,
    ``("base", "sensor")`` eye-to-hand (ROS-Industrial names of ABB's tool0 and base)."""
    return ("tool0", "sensor") if result.mounting == "eye_in_hand" else ("base", "sensor")


def _check_frame_id(frame: str, what: str) -> str:
    if not isinstance(frame, str) or not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_/]*", frame) or frame.endswith("/"):
        raise InputError(
            f"{what} {frame!r} is not a valid tf2 frame id: use letters, digits, underscores "
            "(and '/' inside), no spaces and no leading '/'"
        )
    return frame


def _ros_values(result: CalibrationResult, frame_id, child_frame_id):
    parent, child = default_ros_frames(result)
    parent = _check_frame_id(frame_id or parent, "frame_id")
    child = _check_frame_id(child_frame_id or child, "child_frame_id")
    if parent == child:
        raise InputError(f"frame_id and child_frame_id are both {parent!r}; they must differ")
    xyz_m = [_fmt(v / 1000.0, METRE_DECIMALS) for v in result.transform.translation_mm]
    w, x, y, z = _rounded_quaternion(result.transform)
    return parent, child, xyz_m, (x, y, z, w)


def ros_static_transform_command(
    result: CalibrationResult, frame_id: str | None = None, child_frame_id: str | None = None
) -> str:
    """A comment and the ``ros2 run tf2_ros static_transform_publisher`` command that
    publishes the result: ``frame_id`` is the parent (the A of ``A_from_B``),
    ``child_frame_id`` the sensor; translation in METRES, quaternion (x, y, z, w)."""
    result = _check_result(result)
    parent, child, xyz, q = _ros_values(result, frame_id, child_frame_id)
    return (
        f"# {result.transform_name} from spherecal: pose of '{child}' in '{parent}'; "
        "translation in METRES, quaternion in ROS order (x, y, z, w)\n"
        "ros2 run tf2_ros static_transform_publisher"
        f" --x {xyz[0]} --y {xyz[1]} --z {xyz[2]}"
        f" --qx {q[0]} --qy {q[1]} --qz {q[2]} --qw {q[3]}"
        f" --frame-id {parent} --child-frame-id {child}\n"
    )


def ros_static_transform_yaml(
    result: CalibrationResult, frame_id: str | None = None, child_frame_id: str | None = None
) -> str:
    """A ``geometry_msgs/TransformStamped`` in YAML (no launch file needed): translation
    in METRES, rotation quaternion in ROS order (x, y, z, w)."""
    result = _check_result(result)
    parent, child, xyz, q = _ros_values(result, frame_id, child_frame_id)
    a, b = frames_of(result.transform_name)
    return (
        f"# {result.transform_name} ({result.mounting}) from spherecal, as geometry_msgs/TransformStamped\n"
        f"# parent '{parent}' = spherecal '{a}', child '{child}' = spherecal '{b}'\n"
        "# translation in METRES; rotation quaternion in ROS order (x, y, z, w), scalar LAST\n"
        f"# {_uncertainty_sentence(result)}\n"
        "header:\n"
        f"  frame_id: {parent}\n"
        f"child_frame_id: {child}\n"
        "transform:\n"
        "  translation:\n"
        f"    x: {xyz[0]}\n"
        f"    y: {xyz[1]}\n"
        f"    z: {xyz[2]}\n"
        "  rotation:\n"
        f"    x: {q[0]}\n"
        f"    y: {q[1]}\n"
        f"    z: {q[2]}\n"
        f"    w: {q[3]}\n"
    )


def read_ros_command(text: str) -> dict:
    """Parse :func:`ros_static_transform_command`: ``{"xyz_m", "quaternion_xyzw",
    "frame_id", "child_frame_id"}``."""
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if len(lines) != 1 or "static_transform_publisher" not in lines[0]:
        raise InputError("expected one 'ros2 run tf2_ros static_transform_publisher' command line")
    args = dict(re.findall(r"--([a-z-]+)\s+(\S+)", lines[0]))
    missing = [k for k in ("x", "y", "z", "qx", "qy", "qz", "qw", "frame-id", "child-frame-id") if k not in args]
    if missing:
        raise InputError(f"static_transform_publisher command lacks --{', --'.join(missing)}")
    return {
        "xyz_m": np.array([float(args[k]) for k in ("x", "y", "z")]),
        "quaternion_xyzw": np.array([float(args[k]) for k in ("qx", "qy", "qz", "qw")]),
        "frame_id": args["frame-id"],
        "child_frame_id": args["child-frame-id"],
    }


def read_ros_yaml(text: str) -> dict:
    """Parse :func:`ros_static_transform_yaml` (the subset of YAML it writes): same keys
    as :func:`read_ros_command`."""
    values: dict[str, str] = {}
    path: list[tuple[int, str]] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        body = raw.split("#", 1)[0].rstrip()
        if not body.strip():
            continue
        indent = len(body) - len(body.lstrip())
        m = re.fullmatch(r"\s*(\w+):\s*(.*)", body)
        if not m:
            raise InputError(f"line {lineno}: expected 'key: value', got {raw!r}")
        while path and path[-1][0] >= indent:
            path.pop()
        key = ".".join([p for _, p in path] + [m.group(1)])
        if m.group(2):
            values[key] = m.group(2).strip()
        else:
            path.append((indent, m.group(1)))
    try:
        return {
            "xyz_m": np.array([float(values[f"transform.translation.{k}"]) for k in "xyz"]),
            "quaternion_xyzw": np.array([float(values[f"transform.rotation.{k}"]) for k in "xyzw"]),
            "frame_id": values["header.frame_id"],
            "child_frame_id": values["child_frame_id"],
        }
    except KeyError as exc:
        raise InputError(f"TransformStamped YAML lacks {exc.args[0]}") from None


# --- JSON ---------------------------------------------------------------------------------------
def json_text(result: CalibrationResult) -> str:
    """The full result as JSON (the ``spherecal-result`` document of docs/file-formats.md)."""
    return _check_result(result).model_dump_json(indent=2) + "\n"


def read_json(text: str) -> CalibrationResult:
    """Parse :func:`json_text` (or a file written by ``dataio.write_result``)."""
    return CalibrationResult.model_validate_json(text)


# --- all at once --------------------------------------------------------------------------------
def write_exports(
    result: CalibrationResult,
    out_dir: str | Path,
    *,
    rapid_name: str | None = None,
    rapid_module_name: str = "SpherecalSensor",
    mass_kg: float = 1.0,
    cog_mm: tuple[float, float, float] | None = None,
    ros_frame_id: str | None = None,
    ros_child_frame_id: str | None = None,
    overwrite: bool = False,
) -> dict[str, Path]:
    """Write every export into ``out_dir`` (created if needed) and return
    ``{export name: path}``. Names: ``matrix``, ``xyz_quaternion``, ``rapid``,
    ``ros_command``, ``ros_yaml``, ``json``. Existing files are replaced only with
    ``overwrite=True``; nothing is written if any would be refused."""
    result = _check_result(result)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = result.transform_name
    texts = {
        "matrix": (f"{name}_4x4.txt", matrix_text(result)),
        "xyz_quaternion": (f"{name}_xyz_quat_wxyz.txt", xyz_quaternion_text(result)),
        "rapid": (f"{rapid_module_name}.mod", rapid_module(
            result, rapid_name, module_name=rapid_module_name, mass_kg=mass_kg, cog_mm=cog_mm)),
        "ros_command": ("ros_static_transform.sh", ros_static_transform_command(
            result, ros_frame_id, ros_child_frame_id)),
        "ros_yaml": ("ros_static_transform.yaml", ros_static_transform_yaml(
            result, ros_frame_id, ros_child_frame_id)),
    }
    paths = {key: out / fname for key, (fname, _) in texts.items()}
    paths["json"] = out / "result.json"
    if not overwrite:
        existing = [str(p) for p in paths.values() if p.exists()]
        if existing:
            raise InputError(f"{existing[0]} exists; pass overwrite=True to replace the exports")
    for p in paths.values():  # no link nor device among them: nothing is written if one is refused
        safeio.check_writable_target(p)
    for key, (_, text) in texts.items():
        safeio.write_text(paths[key], text)
    write_result(paths["json"], result, overwrite=True)
    return paths
