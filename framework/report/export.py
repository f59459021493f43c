"""The core's exports of a :class:`~spherecal.core.models.CalibrationResult`, brand-free, and
the built-in plugin that registers them as exporters.

Every export is a pure function returning text, and every one has a reader here that
parses it back (the tests check each export against the result it came from):

==============================  =====================================  ===========================
export                          writer                                 reader
==============================  =====================================  ===========================
4x4 matrices, both ways         :func:`matrix_text`                    :func:`read_matrix_text`
xyz + quaternion (w, x, y, z)   :func:`xyz_quaternion_text`            :func:`read_xyz_quaternion`
ROS 2 static transform          :func:`ros_static_transform_command`,  :func:`read_ros_command`,
                                :func:`ros_static_transform_yaml`,     :func:`read_ros_yaml`,
                                :func:`ros_launch_py`                  :func:`read_ros_launch`
URDF/xacro joint (ROS 2)        :func:`ros_urdf_joint`                 :func:`read_ros_urdf_joint`
JSON result                     :func:`json_text`                      :func:`read_json`
==============================  =====================================  ===========================

As exporters (:class:`spherecal.io.exporters.Exporter`) they are :data:`MATRIX_EXPORTER`
(``matrix``), :data:`XYZ_QUATERNION_EXPORTER` (``xyz_quaternion``) and
:data:`ROS2_EXPORTER` (``ros2``, settings :class:`Ros2ExportSettings`), together
:data:`CORE_EXPORTERS`, which the built-in plugin ``core_exports``
(:mod:`spherecal.plugins.core_exports`, entry point in pyproject.toml) registers. A robot's own controller format comes
from its plugin (docs/results.md).

Conventions (docs/conventions.md, docs/results.md): ``A_from_B`` maps points from B to
A, ``p_A = T_A_from_B p_B``; lengths in mm, except the ROS exports, which are in metres
as ROS requires. Quaternions are (w, x, y, z), scalar first, except in the ROS exports,
which use ROS's (x, y, z, w); the URDF joint gives roll-pitch-yaw in radians as URDF
defines them. Each file says its units and order in a comment.
"""

from __future__ import annotations

import math
import re

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from spherecal.core.errors import InputError
from spherecal.io.exporters import (
    ExportNote, Exporter, calibrated_model_warning, red_warning, sensor_frame_warning, write_exports,
)
from spherecal.core.models import CalibrationResult, Pose

__all__ = [
    "MM_DECIMALS",
    "QUAT_DECIMALS",
    "METRE_DECIMALS",
    "MATRIX_DECIMALS",
    "fixed",
    "check_result",
    "rounded_quaternion_wxyz",
    "uncertainty_sentence",
    "inverse_name",
    "frames_of",
    "matrix_text",
    "read_matrix_text",
    "xyz_quaternion_text",
    "read_xyz_quaternion",
    "default_ros_frames",
    "ros_transform",
    "ros_frame_text",
    "ros_static_transform_command",
    "ros_static_transform_yaml",
    "ros_launch_py",
    "ros_urdf_joint",
    "rpy_from_matrix",
    "read_ros_command",
    "read_ros_yaml",
    "read_ros_launch",
    "read_ros_urdf_joint",
    "json_text",
    "read_json",
    "Ros2ExportSettings",
    "MATRIX_EXPORTER",
    "XYZ_QUATERNION_EXPORTER",
    "ROS2_EXPORTER",
    "CORE_EXPORTERS",
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

# --- small helpers ----------------------------------------------------------------------------
def fixed(value: float, decimals: int) -> str:
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


def check_result(result) -> CalibrationResult:
    if not isinstance(result, CalibrationResult):
        raise InputError(f"expected a CalibrationResult, got {type(result).__name__}")
    return result


def uncertainty_sentence(result: CalibrationResult) -> str:
    target, _ = frames_of(result.transform_name)
    rot = " ".join(fixed(v, 4) for v in result.std_rotation_deg)
    tr = " ".join(fixed(v, 4) for v in result.std_translation_mm)
    return (f"1-sigma: rotation {rot} deg about the {target} x y z axes; "
            f"translation {tr} mm along {target} x y z")


def warning_lines(result: CalibrationResult, prefix: str, sensor_frame: bool = True) -> str:
    """The RED warning (:func:`~spherecal.io.exporters.red_warning`), the calibrated
    arm model's (:func:`~spherecal.io.exporters.calibrated_model_warning`) and, with
    ``sensor_frame``, that the sensor frame is not the clouds'
    (:func:`~spherecal.io.exporters.sensor_frame_warning`), each as one comment line
    starting with ``prefix`` and ending in a line break; "" when none applies."""
    said = (red_warning(result), calibrated_model_warning(result), sensor_frame_warning(result) if sensor_frame else "")
    return "".join(f"{prefix}{w}\n" for w in said if w)


def rounded_quaternion_wxyz(pose: Pose) -> list[str]:
    """Quaternion (w, x, y, z), w >= 0 as the Pose stores it, as text with
    :data:`QUAT_DECIMALS` decimals (rounding leaves the norm within 2e-8 of 1)."""
    return [fixed(c, QUAT_DECIMALS) for c in pose.quaternion_wxyz]


# --- 4x4 matrices -------------------------------------------------------------------------------
def matrix_text(result: CalibrationResult) -> str:
    """The transform in both directions as 4x4 homogeneous matrices (mm), each under its
    name in brackets, row-major, :data:`MATRIX_DECIMALS` decimals. Read back with
    :func:`read_matrix_text`."""
    result = check_result(result)
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
        f"# {uncertainty_sentence(result)}",
        "# each block: a [name] line, then 4 rows of 4 numbers",
    ]
    for label, T in ((name, result.transform.as_matrix()), (inv, result.transform.inverse().as_matrix())):
        lines.append(f"[{label}]")
        for row in T:
            lines.append(" ".join(f"{fixed(v, MATRIX_DECIMALS):>20}" for v in row))
    return warning_lines(result, "# ") + "\n".join(lines) + "\n"


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
    decimals) and the quaternion (w, x, y, z), scalar first (:data:`QUAT_DECIMALS`
    decimals), after comment lines that say so."""
    result = check_result(result)
    name = result.transform_name
    a, b = frames_of(name)
    xyz = " ".join(fixed(v, MM_DECIMALS) for v in result.transform.translation_mm)
    q = " ".join(rounded_quaternion_wxyz(result.transform))
    return warning_lines(result, "# ") + (
        f"# {name} ({result.mounting}): p_{a} = R p_{b} + t\n"
        "# columns: name, x y z (mm, origin of the "
        f"{b} frame in the {a} frame), q1 q2 q3 q4 = quaternion (w, x, y, z), scalar FIRST\n"
        f"# {uncertainty_sentence(result)}\n"
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


# --- ROS ----------------------------------------------------------------------------------------
def default_ros_frames(result: CalibrationResult) -> tuple[str, str]:
    """(parent frame id, child frame id) of the ROS exports when their settings name none:
    the frames the data named (``result.data_frames``, a ROS 2 bag's: the flange frame
    eye-in-hand or the base frame eye-to-hand, and the clouds' frame), else
    ``("tool0", "sensor")`` eye-in-hand, ``("base", "sensor")`` eye-to-hand: the
    ROS-Industrial names of the flange frame and of the robot's base frame as its
    controller reports poses in (REP-199)."""
    parent, child = ("tool0", "sensor") if result.mounting == "eye_in_hand" else ("base", "sensor")
    frames = result.data_frames
    if frames is not None:
        parent = (frames.flange_frame_id if result.mounting == "eye_in_hand" else frames.base_frame_id) or parent
        child = frames.cloud_frame_id or child
    return parent, child


def ros_transform(result: CalibrationResult, child_frame_id: str) -> Pose:
    """What the ROS exports publish for the child frame ``child_frame_id``: the clouds'
    frame of the data (``result.data_frames.cloud_frame_id``) gets
    ``<mount>_from_cloud = <mount>_from_sensor @ sensor_from_cloud``, so that the clouds
    published in it land where the calibration put them; any other child is the
    calibrated sensor frame, ``result.transform``."""
    frames = result.data_frames
    if frames is not None and frames.cloud_frame_id == child_frame_id and not frames.cloud_is_sensor:
        return result.transform @ frames.sensor_from_cloud
    return result.transform


def ros_frame_text(result: CalibrationResult, child_frame_id: str) -> tuple[str, bool]:
    """What the ROS child frame ``child_frame_id`` is when the calibrated sensor frame is
    not the clouds' frame, and whether that is a warning: the clouds' frame gets the
    transform composed with ``sensor_from_cloud`` (said); any other child gets the
    calibrated sensor frame, which needs the fixed turn published between the two (a
    warning). ("", False) when the two frames are one."""
    frames = result.data_frames
    if frames is None or frames.cloud_is_sensor:
        return "", False
    cloud, turn = frames.cloud_frame_id, frames.sensor_from_cloud_text or "not the identity"
    a, _ = frames_of(result.transform_name)
    if cloud is not None and cloud == child_frame_id:
        return (f"'{child_frame_id}' is the clouds' own frame: this is {a}_from_cloud = {a}_from_sensor @ "
                f"sensor_from_cloud, sensor_from_cloud = {turn} (result.json data_frames): spherecal's calibrated "
                "sensor frame is not the clouds' frame"), False
    return (f"'{child_frame_id}' is spherecal's calibrated sensor frame, NOT the clouds' frame "
            f"'{cloud or '(not named)'}': sensor_from_cloud = {turn}; publish the clouds' frame in "
            f"'{child_frame_id}' with that fixed rotation, or set [export.ros2] child_frame_id to the clouds' "
            "frame to have it published directly"), True


def ros_frame_lines(result: CalibrationResult, child_frame_id: str, prefix: str) -> str:
    """:func:`ros_frame_text` as a comment line starting with ``prefix`` (a warning
    starting with WARNING), or ""."""
    text, warn = ros_frame_text(result, child_frame_id)
    return f"{prefix}{'WARNING: ' if warn else ''}{text}\n" if text else ""


def _check_frame_id(frame: str, what: str) -> str:
    if not isinstance(frame, str) or not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_/]*", frame) or frame.endswith("/"):
        raise InputError(
            f"{what} {frame!r} is not a valid tf2 frame id: use letters, digits, underscores "
            "(and '/' inside), no spaces and no leading '/'"
        )
    return frame


def _ros_name(result: CalibrationResult, child_frame_id: str) -> str:
    """The name of what the ROS exports publish for ``child_frame_id``: the result's
    transform name, or ``<mount>_from_cloud`` for the clouds' frame (:func:`ros_transform`)."""
    if ros_transform(result, child_frame_id) is result.transform:
        return result.transform_name
    return f"{frames_of(result.transform_name)[0]}_from_cloud"


def _ros_values(result: CalibrationResult, frame_id, child_frame_id):
    parent, child = default_ros_frames(result)
    parent = _check_frame_id(frame_id or parent, "frame_id")
    child = _check_frame_id(child_frame_id or child, "child_frame_id")
    if parent == child:
        raise InputError(f"frame_id and child_frame_id are both {parent!r}; they must differ")
    X = ros_transform(result, child)
    xyz_m = [fixed(v / 1000.0, METRE_DECIMALS) for v in X.translation_mm]
    w, x, y, z = rounded_quaternion_wxyz(X)
    return parent, child, xyz_m, (x, y, z, w)


def ros_static_transform_command(
    result: CalibrationResult, frame_id: str | None = None, child_frame_id: str | None = None
) -> str:
    """A comment and the ``ros2 run tf2_ros static_transform_publisher`` command that
    publishes the result: ``frame_id`` is the parent (the A of ``A_from_B``),
    ``child_frame_id`` the sensor; translation in METRES, quaternion (x, y, z, w)."""
    result = check_result(result)
    parent, child, xyz, q = _ros_values(result, frame_id, child_frame_id)
    return warning_lines(result, "# ", sensor_frame=False) + ros_frame_lines(result, child, "# ") + (
        f"# {_ros_name(result, child)} from spherecal: pose of '{child}' in '{parent}'; "
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
    result = check_result(result)
    parent, child, xyz, q = _ros_values(result, frame_id, child_frame_id)
    a, b = frames_of(_ros_name(result, child))
    return warning_lines(result, "# ", sensor_frame=False) + ros_frame_lines(result, child, "# ") + (
        f"# {_ros_name(result, child)} ({result.mounting}) from spherecal, as geometry_msgs/TransformStamped\n"
        f"# parent '{parent}' = spherecal '{a}', child '{child}' = spherecal '{b}'\n"
        "# translation in METRES; rotation quaternion in ROS order (x, y, z, w), scalar LAST\n"
        f"# {uncertainty_sentence(result)}\n"
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


#: The static_transform_publisher arguments every ROS export carries (ROS 2 Humble and later).
_ROS_ARGS = ("x", "y", "z", "qx", "qy", "qz", "qw", "frame-id", "child-frame-id")


def _ros_args(args: dict, what: str) -> dict:
    missing = [k for k in _ROS_ARGS if k not in args]
    if missing:
        raise InputError(f"{what} lacks --{', --'.join(missing)}")
    try:
        xyz = np.array([float(args[k]) for k in ("x", "y", "z")])
        q = np.array([float(args[k]) for k in ("qx", "qy", "qz", "qw")])
    except ValueError as exc:
        raise InputError(f"{what}: not a number: {exc}") from None
    return {"xyz_m": xyz, "quaternion_xyzw": q, "frame_id": args["frame-id"], "child_frame_id": args["child-frame-id"]}


def read_ros_command(text: str) -> dict:
    """Parse :func:`ros_static_transform_command`: ``{"xyz_m", "quaternion_xyzw",
    "frame_id", "child_frame_id"}``."""
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if len(lines) != 1 or "static_transform_publisher" not in lines[0]:
        raise InputError("expected one 'ros2 run tf2_ros static_transform_publisher' command line")
    return _ros_args(dict(re.findall(r"--([a-z-]+)\s+(\S+)", lines[0])), "static_transform_publisher command")


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


def _ros_node_name(parent: str, child: str) -> str:
    """A valid ROS node name for the publisher (letters, digits and underscores)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", f"spherecal_{parent}_to_{child}")


def ros_launch_py(result: CalibrationResult, frame_id: str | None = None, child_frame_id: str | None = None) -> str:
    """A ROS 2 Python launch file (``ros2 launch ./ros_static_transform.launch.py``) that
    runs ``tf2_ros static_transform_publisher`` with the result, in the argument form of
    ROS 2 Humble and later: translation in METRES, quaternion (x, y, z, w). Frames as in
    :func:`ros_static_transform_command`. Read back with :func:`read_ros_launch`."""
    result = check_result(result)
    parent, child, xyz, q = _ros_values(result, frame_id, child_frame_id)
    args = [("--x", xyz[0]), ("--y", xyz[1]), ("--z", xyz[2]),
            ("--qx", q[0]), ("--qy", q[1]), ("--qz", q[2]), ("--qw", q[3]),
            ("--frame-id", parent), ("--child-frame-id", child)]
    arg_lines = "".join(f'                "{k}", "{v}",\n' for k, v in args)
    return warning_lines(result, "# ", sensor_frame=False) + ros_frame_lines(result, child, "# ") + (
        f"# {_ros_name(result, child)} ({result.mounting}) from spherecal: pose of '{child}' in '{parent}'.\n"
        "# Translation in METRES; quaternion in ROS order (x, y, z, w), scalar LAST.\n"
        f"# {uncertainty_sentence(result)}\n"
        "# Run: ros2 launch ./ros_static_transform.launch.py (ROS 2 Humble or later)\n"
        '"""Publish the spherecal calibration as a static transform on /tf_static."""\n'
        "\n"
        "from launch import LaunchDescription\n"
        "from launch_ros.actions import Node\n"
        "\n"
        "\n"
        "def generate_launch_description():\n"
        "    return LaunchDescription([\n"
        "        Node(\n"
        '            package="tf2_ros",\n'
        '            executable="static_transform_publisher",\n'
        f'            name="{_ros_node_name(parent, child)}",\n'
        "            arguments=[\n"
        f"{arg_lines}"
        "            ],\n"
        "        ),\n"
        "    ])\n"
    )


def read_ros_launch(text: str) -> dict:
    """Parse :func:`ros_launch_py`: the file must compile as Python, and the arguments
    of its ``static_transform_publisher`` node are read without running it. Same keys as
    :func:`read_ros_command`."""
    import ast  # (the readers check exports: tests and tools, not a run)

    try:
        tree = ast.parse(compile(text, "launch.py", "exec", ast.PyCF_ONLY_AST))
    except SyntaxError as exc:
        raise InputError(f"the launch file is not valid Python: line {exc.lineno}: {exc.msg}") from None
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        kw = {k.arg: k.value for k in node.keywords if k.arg}
        try:
            if ast.literal_eval(kw.get("executable", ast.Constant(None))) != "static_transform_publisher":
                continue
            values = ast.literal_eval(kw["arguments"])
        except (KeyError, ValueError) as exc:
            raise InputError(f"the static_transform_publisher node's arguments are not a literal list: {exc}") from None
        if not (isinstance(values, list) and len(values) % 2 == 0 and all(isinstance(v, str) for v in values)):
            raise InputError("the static_transform_publisher node's arguments are not pairs of strings")
        if any(not k.startswith("--") for k in values[::2]):
            raise InputError(f"expected '--name value' pairs in the node's arguments, got {values!r:.80}")
        return _ros_args({k[2:]: v for k, v in zip(values[::2], values[1::2])}, "the launch file's node")
    raise InputError("no static_transform_publisher node in the launch file")


def rpy_from_matrix(R) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians of a rotation matrix as URDF defines them: about the
    fixed x, y, z axes in that order, ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Accurate to rounding error everywhere, gimbal lock (pitch = +-90 deg) included: yaw
    is taken first, then pitch and roll from what remains after undoing it, so an
    ill-determined yaw is absorbed by the roll instead of spoiling the rotation."""
    R = np.asarray(R, dtype=float)
    yaw = math.atan2(R[1, 0], R[0, 0])
    cy, sy = math.cos(yaw), math.sin(yaw)
    N = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ R  # = Ry(pitch) Rx(roll)
    pitch = math.atan2(-N[2, 0], N[0, 0])
    cp, sp = math.cos(pitch), math.sin(pitch)
    M = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]]) @ N  # = Rx(roll)
    roll = math.atan2(M[2, 1], M[1, 1])
    return roll, pitch, yaw


def ros_urdf_joint(result: CalibrationResult, frame_id: str | None = None, child_frame_id: str | None = None) -> str:
    """A URDF snippet, also a xacro file to include: the sensor's ``<link>`` and the
    fixed ``<joint>`` that places it on its parent, the flange (``tool0``) eye-in-hand or
    the robot's base (``base``) eye-to-hand, or the frames given. ``<origin>`` carries xyz
    in METRES and rpy in RADIANS (:func:`rpy_from_matrix`), both at full precision (they
    give back the transform to about 1e-15). Read back with :func:`read_ros_urdf_joint`."""
    result = check_result(result)
    parent, child, _, _ = _ros_values(result, frame_id, child_frame_id)
    X = ros_transform(result, child)
    xyz = " ".join(repr(float(v) / 1000.0) for v in X.translation_mm)
    rpy = " ".join(repr(float(v)) for v in rpy_from_matrix(X.rotation_matrix))
    a, b = frames_of(_ros_name(result, child))
    where = "on the flange" if result.mounting == "eye_in_hand" else "fixed in the cell, relative to the robot's base"
    return (
        '<?xml version="1.0"?>\n'
        "<!--\n"
        + warning_lines(result, "  ", sensor_frame=False) + ros_frame_lines(result, child, "  ")
        + f"  spherecal {_ros_name(result, child)} ({result.mounting}): the sensor frame '{child}' {where} '{parent}'\n"
        f"  (spherecal '{a}' = '{parent}', '{b}' = '{child}').\n"
        "  origin: xyz in METRES, rpy in RADIANS about the fixed parent axes x, y, z in that order\n"
        "  (R = Rz(yaw) Ry(pitch) Rx(roll), as URDF defines it); full precision, do not round.\n"
        f"  {uncertainty_sentence(result)}\n"
        "  Use: paste the link and the joint into the robot's URDF, or include this file from a\n"
        "  xacro description: <xacro:include filename=\"ros_sensor_joint.urdf.xacro\"/>\n"
        "-->\n"
        '<robot name="spherecal_sensor" xmlns:xacro="http://www.ros.org/wiki/xacro">\n'
        f'  <link name="{child}"/>\n'
        f'  <joint name="{parent}_to_{child}" type="fixed">\n'
        f'    <parent link="{parent}"/>\n'
        f'    <child link="{child}"/>\n'
        f'    <origin xyz="{xyz}" rpy="{rpy}"/>\n'
        "  </joint>\n"
        "</robot>\n"
    )


def read_ros_urdf_joint(text: str) -> dict:
    """Parse :func:`ros_urdf_joint` as XML: ``{"xyz_m", "rpy_rad", "frame_id",
    "child_frame_id", "joint"}`` of its one fixed joint."""
    import xml.etree.ElementTree as ET  # (the readers check exports: tests and tools, not a run)

    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(f"the URDF snippet is not well-formed XML: {exc}") from None
    joints = root.findall("joint")
    if len(joints) != 1 or joints[0].get("type") != "fixed":
        raise InputError(f"expected one fixed <joint> in the URDF snippet, found {len(joints)} joint(s)")
    j = joints[0]
    parent, child, origin = j.find("parent"), j.find("child"), j.find("origin")
    if parent is None or child is None or origin is None:
        raise InputError(f"joint {j.get('name')!r} lacks <parent>, <child> or <origin>")
    try:
        xyz = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()])
        rpy = np.array([float(v) for v in origin.get("rpy", "0 0 0").split()])
    except ValueError as exc:
        raise InputError(f"joint {j.get('name')!r}: <origin> is not numbers: {exc}") from None
    if xyz.shape != (3,) or rpy.shape != (3,):
        raise InputError(f"joint {j.get('name')!r}: <origin> xyz and rpy need 3 numbers each")
    if root.find(f"link[@name='{child.get('link')}']") is None:
        raise InputError(f"the URDF snippet does not define the child link {child.get('link')!r}")
    return {"xyz_m": xyz, "rpy_rad": rpy, "frame_id": parent.get("link"), "child_frame_id": child.get("link"),
            "joint": j.get("name")}


# --- JSON ---------------------------------------------------------------------------------------
def json_text(result: CalibrationResult) -> str:
    """The full result as JSON (the ``spherecal-result`` document of docs/file-formats.md)."""
    return check_result(result).model_dump_json(indent=2) + "\n"


def read_json(text: str) -> CalibrationResult:
    """Parse :func:`json_text` (or a file written by ``io.result.write_result``)."""
    return CalibrationResult.model_validate_json(text)




# --- the core's exporters ---------------------------------------------------------------------------------
#: Longest frame id accepted (tf2 sets no limit; this is a typo guard).
MAX_FRAME_ID_LENGTH = 256


class Ros2ExportSettings(BaseModel):
    """``[export.ros2]``: the frame names of the ROS 2 exports (tf2 frame ids)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    frame_id: str | None = Field(
        None, max_length=MAX_FRAME_ID_LENGTH,
        description="parent frame: the flange (eye_in_hand) or the robot's base (eye_to_hand); default: the frame "
        "the data name (a ROS 2 bag's), else 'tool0' or 'base' (the ROS-Industrial names)")
    child_frame_id: str | None = Field(
        None, max_length=MAX_FRAME_ID_LENGTH, description="the sensor's frame; default: the frame the data's clouds "
        "came in (a ROS 2 bag's frame_id; its transform composed with sensor_from_cloud), else 'sensor'")

    @field_validator("frame_id", "child_frame_id")
    @classmethod
    def _frame(cls, v, info):
        if v is not None:
            try:
                _check_frame_id(v, info.field_name)
            except InputError as exc:
                raise ValueError(str(exc)) from None
        return v

    @model_validator(mode="after")
    def _differ(self):
        # (the child's default 'sensor' counts: a configuration's run has no data to name another)
        if self.frame_id is not None and self.frame_id == (self.child_frame_id or "sensor"):
            raise ValueError(f"frame_id and child_frame_id are both {self.frame_id!r}; they must differ")
        return self


MATRIX_EXPORTER = Exporter(
    name="matrix",
    description="the transform in both directions as 4x4 homogeneous matrices, mm",
    files=("{transform_name}_4x4.txt",),
    write=lambda r, s: {f"{r.transform_name}_4x4.txt": matrix_text(r)},
)

XYZ_QUATERNION_EXPORTER = Exporter(
    name="xyz_quaternion",
    description="one line: name, x y z in mm, quaternion (w, x, y, z) scalar first",
    files=("{transform_name}_xyz_quat_wxyz.txt",),
    write=lambda r, s: {f"{r.transform_name}_xyz_quat_wxyz.txt": xyz_quaternion_text(r)},
)

#: The ROS 2 files, in the order they are written.
ROS2_FILES = ("ros_static_transform.sh", "ros_static_transform.yaml", "ros_static_transform.launch.py",
              "ros_sensor_joint.urdf.xacro")


def _ros2_files(result: CalibrationResult, s: Ros2ExportSettings) -> dict[str, str]:
    makers = (ros_static_transform_command, ros_static_transform_yaml, ros_launch_py, ros_urdf_joint)
    return {name: make(result, s.frame_id, s.child_frame_id) for name, make in zip(ROS2_FILES, makers)}


def _ros2_note(result: CalibrationResult, s: Ros2ExportSettings) -> ExportNote:
    parent, child, _, _ = _ros_values(result, s.frame_id, s.child_frame_id)
    frames, warn = ros_frame_text(result, child)
    named = ""
    if result.data_frames is not None and s.frame_id is None:
        what, given = (("flange", result.data_frames.flange_frame_id) if result.mounting == "eye_in_hand" else
                       ("base", result.data_frames.base_frame_id))
        named = (f" '{parent}' is the {what} frame the {result.data_frames.source} data named." if given else
                 f" The {result.data_frames.source} data name no {what} frame: '{parent}' is the ROS-Industrial "
                 "name; set [export.ros2] frame_id (or name it when converting the data) if yours differs.")
    return ExportNote(
        title="ROS 2",
        text=(f"The sensor frame '{child}' in '{parent}': run the command below or "
              "'ros2 launch ./ros_static_transform.launch.py' (ROS 2 Humble or later) to publish it on /tf_static, "
              "or add ros_sensor_joint.urdf.xacro to the robot description. Metres; quaternion (x, y, z, w)."
              + named + (f" {frames[0].upper()}{frames[1:]}." if frames else "")),
        code=ros_static_transform_command(result, s.frame_id, s.child_frame_id),
        warning=frames if warn else "",
    )


ROS2_EXPORTER = Exporter(
    name="ros2",
    description="ROS 2: static_transform_publisher command, TransformStamped YAML, launch.py, URDF/xacro joint "
    "(metres, quaternion x y z w)",
    files=ROS2_FILES,
    write=_ros2_files,
    settings_model=Ros2ExportSettings,
    note=_ros2_note,
)

#: The core's brand-free exporters, registered by the built-in plugin ``core_exports``
#: (:mod:`spherecal.plugins.core_exports`).
CORE_EXPORTERS = (MATRIX_EXPORTER, XYZ_QUATERNION_EXPORTER, ROS2_EXPORTER)
