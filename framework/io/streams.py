"""Stream recordings: the dataset format's stream form (version 3, docs/file-formats.md).

A stream recording holds what an on-the-fly acquisition (or a converted ROS 2 bag)
measured, as a :class:`~spherecal.core.streams.Recording`: flange poses stamped by the
robot's clock and profiles stamped by the sensor's. It is JSON Lines, like the other
dataset files: line 1 is the header (``"format": "spherecal-dataset"``,
``"version": 3``, ``"form": "stream"``), then, in any order, lines of pose samples::

    {"poses": {"t_robot_s": [...], "translation_mm": [[x, y, z], ...],
               "quaternion_wxyz": [[w, x, y, z], ...], "joints_deg": [[...], ...], "seq": [...]}}

and one line per profile::

    {"profile": {"t_sensor_s": 12.345, "frame": 17, "sweep": 0, "points_yz_mm_f32le": "<base64>"}}

The points are the profile's (y, z) in mm, interleaved, as little-endian float32 in
base64 (resolution 4e-6 mm at 30 mm, 6e-5 mm at 500 mm), so a profile of 1,280 points
is a 14 kB line and ten thousand profiles read in a fraction of a second. Stamps and
poses are float64 JSON numbers at full precision (the shortest text that reads back to
the same double). Quaternions are (w, x, y, z), scalar first, as everywhere in our files.

:class:`RecordingWriter` appends whole lines and flushes each (``fsync=True`` waits for
the disk), so a killed acquisition leaves a file that :func:`read_recording` reads up to
its last whole line, with a :class:`~spherecal.io.dataset.TruncatedFileWarning` for the
cut line. Every problem raises :class:`~spherecal.core.errors.DatasetFileError` naming
the file, the line and the field.

Public API::

    write_recording(path, recording)        read_recording(path) -> Recording
    RecordingWriter(path, mounting=..., sphere_radius_mm=..., clocks=..., sweeps=...)
    recording_kind(path) -> "dataset" | "stream" | "rosbag"
"""

from __future__ import annotations

import binascii
import json
import math
import mmap
import os
import warnings
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal, Sequence

import numpy as np
from pydantic import ValidationError

from spherecal import __version__
from spherecal.core.errors import DatasetFileError, FileWriteError, InputError
from spherecal.core.models import Dataset
from spherecal.core.streams import PoseStream, ProfileStream, Recording, SweepInfo
from spherecal.core.validation_errors import validation_error_lines
from spherecal.io.dataset import MAX_LINE_BYTES, STREAM_DATASET_VERSION, TruncatedFileWarning
from spherecal.io.files import check_input
from spherecal.io.json_files import DATASET_FORMAT, MAX_ABS_VALUE, atomic_temporary, fsync_dir, json_safe
from spherecal.io.observation_line import FieldError, loads_json, parse_timestamp

try:  # the fast serialiser (a dependency; the standard library is the fallback)
    import orjson as _orjson
except ImportError:  # pragma: no cover
    _orjson = None
try:  # SIMD base64, about 15 times binascii's speed (a dependency; binascii is the fallback)
    import pybase64 as _pybase64
except ImportError:  # pragma: no cover
    _pybase64 = None

__all__ = [
    "MAX_STAMP_STEP_S",
    "POSES_PER_LINE",
    "STREAM_FORM",
    "STREAM_VERSION",
    "RecordingWriter",
    "TruncatedFileWarning",
    "read_recording",
    "recording_kind",
    "write_recording",
]

#: Dataset format version of the stream form.
STREAM_VERSION = STREAM_DATASET_VERSION
#: ``form`` value on line 1 of a stream recording.
STREAM_FORM = "stream"
#: A step between two consecutive stamps of one stream longer than this (s) is a clock
#: jump (a reset, a wrap, stamps in another unit), not a pause of a calibration.
MAX_STAMP_STEP_S = 3600.0
#: Pose samples per line that :func:`write_recording` writes (a second at 250 Hz).
POSES_PER_LINE = 250
#: A quaternion's norm may differ from 1 by this much (rounding); more is a typo.
_QUAT_NORM_TOL = 1e-3

_HEADER_REQUIRED = ("format", "version", "form", "mounting", "sphere_radius_mm", "clocks", "sweeps", "created")
_HEADER_OPTIONAL = ("provenance", "written_by")
_POSE_FIELDS = ("t_robot_s", "translation_mm", "quaternion_wxyz", "joints_deg", "seq")
_PROFILE_FIELDS = ("t_sensor_s", "frame", "sweep", "points_yz_mm_f32le")
_CLOCK_KEYS = ("robot", "sensor")
_POINTS_KEY = b'"points_yz_mm_f32le"'


def _b64decode(text) -> bytes:
    """Strict base64 (no whitespace, no stray characters, correct padding); binascii.Error."""
    if _pybase64 is not None:
        return _pybase64.b64decode(text, validate=True)
    return binascii.a2b_base64(text, strict_mode=True)  # pragma: no cover


def _b64encode(data) -> bytes:
    if _pybase64 is not None:
        return _pybase64.b64encode(data)
    return binascii.b2a_base64(data, newline=False)  # pragma: no cover


# ---------------------------------------------------------------------------------------
# checks shared by the reader and the writer
# ---------------------------------------------------------------------------------------


def _check_mounting_radius(mounting: Any, radius: Any) -> str | None:
    """The dataset's own rules on mounting and radius (a radius in metres is refused)."""
    try:
        Dataset.model_validate({"mounting": mounting, "sphere_radius_mm": radius}, strict=True)
    except ValidationError as exc:
        return "; ".join(validation_error_lines(exc))
    return None


def _check_clocks(clocks: Any) -> dict[str, str]:
    if not isinstance(clocks, dict):
        raise FieldError("clocks", f"expected an object {{\"robot\": name, \"sensor\": name}}, got {clocks!r:.60}")
    keys = set(clocks)
    if keys != set(_CLOCK_KEYS):
        missing = [k for k in _CLOCK_KEYS if k not in keys]
        extra = sorted(keys - set(_CLOCK_KEYS))
        what = (f"missing {', '.join(missing)}" if missing else "") + ("; " if missing and extra else "") + \
            (f"unknown {', '.join(map(str, extra))}" if extra else "")
        raise FieldError("clocks", f"needs exactly the keys robot and sensor (the pose stream's and the profile "
                                   f"stream's clock names): {what}")
    for k in _CLOCK_KEYS:
        v = clocks[k]
        if not isinstance(v, str) or not v.strip() or len(v) > 200:
            raise FieldError(f"clocks.{k}", f"must be a clock's name (1-200 characters), got {v!r:.60}")
    return {k: clocks[k] for k in _CLOCK_KEYS}


def _check_sweep(s: Any, field: str) -> SweepInfo:
    if isinstance(s, SweepInfo):
        s = {"station": s.station, "speed_mm_s": s.speed_mm_s, "direction": list(s.direction)}
    if not isinstance(s, dict):
        raise FieldError(field, f"expected an object with station, speed_mm_s and direction, got {s!r:.60}")
    unknown = sorted(set(s) - {"station", "speed_mm_s", "direction"})
    if unknown:
        raise FieldError(f"{field}.{unknown[0]}", "unknown field (allowed: station, speed_mm_s, direction)")
    for k in ("station", "speed_mm_s", "direction"):
        if k not in s:
            raise FieldError(f"{field}.{k}", "missing (required)")
    station, speed, direction = s["station"], s["speed_mm_s"], s["direction"]
    if not isinstance(station, str) or not station or len(station) > 200:
        raise FieldError(f"{field}.station", f"must be a station label (1-200 characters), got {station!r:.60}")
    if type(speed) is bool or not isinstance(speed, (int, float)) or not (0 < speed <= MAX_ABS_VALUE):
        raise FieldError(f"{field}.speed_mm_s", f"must be a speed > 0 in mm/s, got {speed!r:.40}")
    d = list(direction) if isinstance(direction, (list, tuple, np.ndarray)) else direction
    if (not isinstance(d, list) or len(d) != 3
            or any(type(v) is bool or not isinstance(v, (int, float, np.floating)) or not math.isfinite(v) for v in d)):
        raise FieldError(f"{field}.direction", f"needs 3 finite numbers (x, y, z), a unit vector in base, got {d!r:.60}")
    norm = math.sqrt(sum(float(v) ** 2 for v in d))
    if abs(norm - 1.0) > _QUAT_NORM_TOL:
        raise FieldError(f"{field}.direction", f"must be a unit vector (base frame), its norm is {norm:.6g}")
    return SweepInfo(station=station, speed_mm_s=float(speed), direction=tuple(float(v) for v in d))


def _as_numbers(value: Any, field: str, shape: tuple[int | None, ...], limit: float | None) -> np.ndarray:
    """A JSON (nested) list of numbers as a float array of ``shape`` (None: any length),
    refusing strings, booleans, nulls, non-finite values and values beyond ``limit``."""
    if not isinstance(value, list):
        raise FieldError(field, f"expected a list of numbers, got {type(value).__name__} {value!r:.60}")
    try:
        arr = np.asarray(value)
    except ValueError:
        raise FieldError(field, "rows of unequal length") from None
    kind = arr.dtype.kind
    if kind not in "fiu":
        flat = _flatten(value)
        for i, v in enumerate(flat):
            if type(v) is bool or not isinstance(v, (int, float)):
                shown = "null" if v is None else json.dumps(v) if isinstance(v, (bool, str)) else repr(v)
                raise FieldError(field, f"must hold only numbers; item {_item(i, arr.shape)} is {shown:.40}")
        raise FieldError(field, "must hold only numbers")
    if kind == "f":  # NumPy reads true/false among floats as 1.0/0.0
        suspects = np.flatnonzero((arr == 1.0) | (arr == 0.0))
        if suspects.size:
            flat = _flatten(value)
            for i in suspects:
                if type(flat[i]) is bool:
                    raise FieldError(field, f"must hold only numbers; item {_item(int(i), arr.shape)} is "
                                            f"{json.dumps(flat[i])}")
    try:
        arr = arr.astype(float)
    except OverflowError:  # pragma: no cover - integers beyond float range
        raise FieldError(field, "a number is too large") from None
    expected = tuple(len(arr) if d is None else d for d in shape)
    if arr.shape != expected:
        raise FieldError(field, f"expected {_shape_text(expected)}, got {_shape_text(arr.shape)}")
    bad = ~np.isfinite(arr) if limit is None else ~(np.abs(arr) <= limit)
    if bad.any():
        i = int(np.flatnonzero(bad.ravel())[0])
        v = float(arr.ravel()[i])
        more = "" if limit is None else f" of at most {limit:g} (check the units)"
        raise FieldError(field, f"item {_item(i, arr.shape)} is {v!r}: not a finite number{more}")
    return arr


def _flatten(value: list) -> list:
    return [v for row in value for v in row] if value and isinstance(value[0], list) else list(value)


def _item(i: int, shape: tuple[int, ...]) -> str:
    return str(i) if len(shape) <= 1 else "[" + "][".join(str(int(k)) for k in np.unravel_index(i, shape)) + "]"


def _shape_text(shape: tuple[int, ...]) -> str:
    if len(shape) == 1:
        return f"{shape[0]} numbers"
    return f"{shape[0]} rows of {shape[1]} numbers" if len(shape) == 2 else f"shape {shape}"


def _within_limit(a: np.ndarray) -> bool:
    """Every value finite and at most MAX_ABS_VALUE in magnitude (max and min carry a NaN
    through, so two passes decide it)."""
    if not a.size:
        return True
    hi, lo = float(a.max()), float(a.min())
    return hi <= MAX_ABS_VALUE and -lo <= MAX_ABS_VALUE  # False for NaN


def _check_quaternions(q: np.ndarray, field: str) -> np.ndarray:
    """Unit quaternions (w, x, y, z) to rounding, normalised, w >= 0."""
    norm = np.linalg.norm(q, axis=1)
    off = np.flatnonzero(np.abs(norm - 1.0) > _QUAT_NORM_TOL)
    if off.size:
        i = int(off[0])
        raise FieldError(field, f"item {i} {q[i].tolist()} has norm {norm[i]:.6g}, not 1: a quaternion (w, x, y, z) "
                                "must be unit (to 1e-3)")
    q = q / norm[:, None]
    return np.where(q[:, :1] < 0, -q, q)


def _check_stamps(t: np.ndarray, previous: float | None, field: str, clock: str) -> None:
    """Stamps strictly increasing, after ``previous``, without a jump."""
    if previous is not None:
        t = np.concatenate([[previous], t])
        offset = -1
    else:
        offset = 0
    if len(t) < 2:
        return
    dt = np.diff(t)
    t = t.tolist()  # Python floats: their text is the shortest that reads back
    back = np.flatnonzero(dt <= 0)
    jump = np.flatnonzero(dt > MAX_STAMP_STEP_S)
    if back.size and (not jump.size or back[0] <= jump[0]):
        k = int(back[0])
        i = k + 1 + offset
        before = "the stream's sample before it" if i == 0 else f"item {i - 1}"
        raise FieldError(field, f"item {i} is {t[k + 1]!r} s, not after {t[k]!r} s ({before}): stamps must "
                                f"increase ({clock} clock; a clock reset, or lines out of order?)")
    if jump.size:
        k = int(jump[0])
        i = k + 1 + offset
        raise FieldError(field, f"item {i} jumps {dt[k]:.6g} s after the sample before it ({t[k]!r} s to "
                                f"{t[k + 1]!r} s, {clock} clock): more than {MAX_STAMP_STEP_S:g} s between two "
                                "samples is a clock jump (a reset, or stamps in another unit), not a pause")


# ---------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------


class PointBuffer:
    """Profile points (y, z) appended profile by profile into one float64 array, with the
    profiles' starts. The array grows by doubling; ``np.empty`` only reserves address
    space (a page costs when it is first written), so a generous first capacity, such as
    an upper bound from a file's size, is free, and no point is copied twice."""

    def __init__(self, capacity: int):
        self._a = np.empty((max(int(capacity), 1024), 2))
        self.n = 0
        self.starts = [0]

    def reserve(self, k: int) -> np.ndarray:
        """Room for k more points; returns the (k, 2) block to fill (then call :meth:`added`)."""
        need = self.n + k
        if need > len(self._a):
            grown = np.empty((max(need, 2 * len(self._a)), 2))
            grown[:self.n] = self._a[:self.n]
            self._a = grown
        return self._a[self.n:need]

    def added(self, k: int) -> None:
        self.n += k
        self.starts.append(self.n)

    def append_f32le(self, raw: bytes) -> None:
        k = len(raw) // 8
        self.reserve(k)[:] = np.frombuffer(raw, dtype="<f4").reshape(k, 2)
        self.added(k)

    def array(self) -> np.ndarray:
        return self._a[:self.n]


class _Reader:
    """Reads a stream recording line by line (the file is mapped, never read whole into memory)."""

    def __init__(self, name: str):
        self.name = name
        self.header: dict[str, Any] | None = None
        self.sweeps: list[SweepInfo] = []
        # poses
        self.pose_t: list[np.ndarray] = []
        self.pose_tr: list[np.ndarray] = []
        self.pose_q: list[np.ndarray] = []
        self.pose_j: list[np.ndarray] = []
        self.pose_seq: list[np.ndarray] = []
        self.pose_first_line = 0  # the first pose line: it decides whether joints and seq are given
        self.n_joints: int | None = None
        self.has_seq = False
        self.last_pose_t: float | None = None
        # profiles
        self.prof_t: list[float] = []
        self.prof_frame: list[int] = []
        self.prof_sweep: list[int] = []
        self.points = PointBuffer(0)
        self.prof_line: list[int] = []
        self.first_profile_line = 0
        self.has_frame = self.has_sweep = False

    # -- header ------------------------------------------------------------------------

    def read_header(self, obj: Any) -> None:
        name, where = self.name, f"{self.name} line 1 (header)"
        if not isinstance(obj, dict) or obj.get("format") != DATASET_FORMAT:
            fmt = obj.get("format") if isinstance(obj, dict) else None
            raise DatasetFileError(f"{name}: not a spherecal stream recording: line 1 should be a header with format "
                                   f"{DATASET_FORMAT!r}, version {STREAM_VERSION} and form {STREAM_FORM!r}"
                                   + (f" (found format {json.dumps(fmt)})" if fmt is not None else ""))
        version, form = obj.get("version"), obj.get("form")
        if version != STREAM_VERSION or form != STREAM_FORM:
            if type(version) is int and version < STREAM_VERSION:
                raise DatasetFileError(f"{name}: a dataset of observations (format version {version}), not a stream "
                                       "recording: read it with spherecal.io.dataset.read_dataset")
            if type(version) is int and version > STREAM_VERSION:
                raise DatasetFileError(f"{name}: dataset format version {version} is newer than this spherecal "
                                       f"({__version__}) reads (streams: version {STREAM_VERSION}); upgrade spherecal")
            raise DatasetFileError(f"{where}: a stream recording has version {STREAM_VERSION} and form "
                                   f"{STREAM_FORM!r}, found version {json.dumps(version)} and form {json.dumps(form)}")
        for k in _HEADER_REQUIRED:
            if k not in obj:
                raise DatasetFileError(f"{where}: {k}: missing (required)")
        unknown = sorted(set(obj) - set(_HEADER_REQUIRED) - set(_HEADER_OPTIONAL))
        if unknown:
            raise DatasetFileError(f"{where}: {unknown[0]}: unknown field (allowed: "
                                   f"{', '.join(_HEADER_REQUIRED + _HEADER_OPTIONAL)}); free-form notes go in provenance")
        problem = _check_mounting_radius(obj["mounting"], obj["sphere_radius_mm"])
        if problem:
            raise DatasetFileError(f"{where}: {problem}")
        try:
            clocks = _check_clocks(obj["clocks"])
            if not isinstance(obj["sweeps"], list):
                raise FieldError("sweeps", "expected a list of sweeps (station, speed_mm_s, direction); [] for none")
            self.sweeps = [_check_sweep(s, f"sweeps[{i}]") for i, s in enumerate(obj["sweeps"])]
            created = parse_timestamp(obj["created"])
        except FieldError as exc:
            text = str(exc)
            if text.startswith("timestamp"):
                text = "created" + text[len("timestamp"):]
            raise DatasetFileError(f"{where}: {text}") from None
        provenance = obj.get("provenance", {})
        if not isinstance(provenance, dict):
            raise DatasetFileError(f"{where}: provenance: expected an object, got {type(provenance).__name__}")
        written_by = obj.get("written_by", "")
        if not isinstance(written_by, str):
            raise DatasetFileError(f"{where}: written_by: expected a string, got {written_by!r:.40}")
        self.header = {"mounting": obj["mounting"], "sphere_radius_mm": float(obj["sphere_radius_mm"]),
                       "clocks": clocks, "provenance": provenance, "created": created, "written_by": written_by}

    # -- lines ---------------------------------------------------------------------------

    def read_line(self, obj: Any, lineno: int, points=None) -> None:
        where = f"{self.name} line {lineno}"
        if not isinstance(obj, dict) or len(obj) != 1 or next(iter(obj)) not in ("poses", "profile"):
            if isinstance(obj, dict) and "format" in obj:
                raise DatasetFileError(f"{where}: a second header (format {obj.get('format')!r}); two files were "
                                       "joined into one? Keep one recording per file")
            keys = list(obj) if isinstance(obj, dict) else type(obj).__name__
            raise DatasetFileError(f"{where}: expected an object with one key, \"poses\" or \"profile\"; got {keys!r:.80}")
        key, value = next(iter(obj.items()))
        if not isinstance(value, dict):
            raise DatasetFileError(f"{where}: {key}: expected an object, got {type(value).__name__}")
        try:
            if key == "poses":
                self._poses(value, lineno)
            else:
                self._profile(value, lineno, points)
        except FieldError as exc:
            raise DatasetFileError(f"{where}: {key}.{exc}") from None

    def _poses(self, blk: dict, lineno: int) -> None:
        unknown = sorted(set(blk) - set(_POSE_FIELDS))
        if unknown:
            raise FieldError(unknown[0], f"unknown field (allowed: {', '.join(_POSE_FIELDS)})")
        for k in _POSE_FIELDS[:3]:
            if k not in blk:
                raise FieldError(k, "missing (required)")
        t = _as_numbers(blk["t_robot_s"], "t_robot_s", (None,), None)
        n = len(t)
        if n == 0:
            raise FieldError("t_robot_s", "empty: a pose line holds at least one sample")
        lengths = {k: len(blk[k]) for k in _POSE_FIELDS[1:] if isinstance(blk.get(k), list)}
        for k, m in lengths.items():
            if m != n:
                raise FieldError(k, f"{m} samples, but t_robot_s has {n}: every list of a pose line has one entry "
                                    "per sample")
        tr = _as_numbers(blk["translation_mm"], "translation_mm", (n, 3), MAX_ABS_VALUE)
        q = _check_quaternions(_as_numbers(blk["quaternion_wxyz"], "quaternion_wxyz", (n, 4), MAX_ABS_VALUE),
                               "quaternion_wxyz")
        first = not self.pose_t
        joints = blk.get("joints_deg")
        if first:
            self.pose_first_line = lineno
            self.has_seq = blk.get("seq") is not None
            if joints is not None:
                if not isinstance(joints, list) or not joints or not isinstance(joints[0], list):
                    raise FieldError("joints_deg", "expected one list of joint angles (deg) per sample")
                self.n_joints = len(joints[0])
        if (joints is not None) != (self.n_joints is not None):
            raise FieldError("joints_deg", f"{'given' if joints is not None else 'missing'} here, but "
                                           f"{'missing' if joints is not None else 'given'} on line "
                                           f"{self.pose_first_line}: every pose line has joints or none does")
        if (blk.get("seq") is not None) != self.has_seq:
            raise FieldError("seq", f"{'given' if not self.has_seq else 'missing'} here, but "
                                    f"{'given' if self.has_seq else 'missing'} on line {self.pose_first_line}: "
                                    "every pose line has sequence numbers or none does")
        _check_stamps(t, self.last_pose_t, "t_robot_s", "robot")
        if joints is not None:
            self.pose_j.append(_as_numbers(joints, "joints_deg", (n, self.n_joints), MAX_ABS_VALUE))
        if self.has_seq:
            seq = blk["seq"]
            if not isinstance(seq, list) or any(type(v) is not int for v in seq):
                bad = next((v for v in seq if type(v) is not int), seq) if isinstance(seq, list) else seq
                raise FieldError("seq", f"must hold whole numbers (the controller's sequence numbers), found {bad!r:.40}")
            self.pose_seq.append(np.asarray(seq, dtype=np.int64))
        self.pose_t.append(t)
        self.pose_tr.append(tr)
        self.pose_q.append(q)
        self.last_pose_t = float(t[-1])

    def _profile(self, blk: dict, lineno: int, points=None) -> None:
        """One profile line; ``points`` is its base64 text when the caller cut it out of
        the line before parsing it (the JSON then holds an empty string there)."""
        for k in blk:
            if k not in _PROFILE_FIELDS:
                raise FieldError(k, f"unknown field (allowed: {', '.join(_PROFILE_FIELDS)})")
        if "t_sensor_s" not in blk:
            raise FieldError("t_sensor_s", "missing (required)")
        if "points_yz_mm_f32le" not in blk:
            raise FieldError("points_yz_mm_f32le", "missing (required)")
        t = blk["t_sensor_s"]
        if type(t) is bool or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise FieldError("t_sensor_s", f"must be a finite number of seconds, got {t!r:.40}")
        t = float(t)
        first = not self.prof_t
        if first:
            self.first_profile_line = lineno
            self.has_frame = blk.get("frame") is not None
            self.has_sweep = blk.get("sweep") is not None
        for k, has in (("frame", self.has_frame), ("sweep", self.has_sweep)):
            if (blk.get(k) is not None) != has:
                raise FieldError(k, f"{'given' if not has else 'missing'} here, but {'given' if has else 'missing'} "
                                    f"on line {self.first_profile_line}: every profile has a {k} or none does")
        if self.has_frame:
            f = blk["frame"]
            if type(f) is not int:
                raise FieldError("frame", f"must be a whole number (the sensor's frame counter), got {f!r:.40}")
            self.prof_frame.append(f)
        if self.has_sweep:
            s = blk["sweep"]
            if type(s) is not int or not -1 <= s < len(self.sweeps):
                raise FieldError("sweep", f"must be -1 (outside a sweep) or an index into the header's "
                                          f"{len(self.sweeps)} sweeps, got {s!r:.40}")
            self.prof_sweep.append(s)
        b64 = blk["points_yz_mm_f32le"] if points is None else points
        if not isinstance(b64, (str, memoryview)):
            raise FieldError("points_yz_mm_f32le", f"expected a base64 string, got {type(b64).__name__}")
        try:
            raw = _b64decode(b64)
        except (binascii.Error, ValueError) as exc:
            raise FieldError("points_yz_mm_f32le", f"not valid base64 ({exc}; {len(b64)} characters)") from None
        if len(raw) % 8:
            raise FieldError("points_yz_mm_f32le", f"decodes to {len(raw)} bytes, not a multiple of 8: expected "
                                                   "pairs of little-endian float32 (y, z)")
        if not first and t <= self.prof_t[-1]:
            raise FieldError("t_sensor_s", f"{t!r} s is not after the previous profile's {self.prof_t[-1]!r} s "
                                           f"(line {self.prof_line[-1]}): stamps must increase (sensor clock)")
        if not first and t - self.prof_t[-1] > MAX_STAMP_STEP_S:
            raise FieldError("t_sensor_s", f"{t!r} s jumps {t - self.prof_t[-1]:.6g} s after the previous profile "
                                           f"(line {self.prof_line[-1]}, sensor clock): more than {MAX_STAMP_STEP_S:g} s "
                                           "between two profiles is a clock jump (a reset, or stamps in another unit)")
        self.prof_t.append(t)
        self.points.append_f32le(raw)
        self.prof_line.append(lineno)

    # -- the recording ---------------------------------------------------------------------

    def recording(self) -> Recording:
        name, h = self.name, self.header
        assert h is not None
        n_poses = sum(len(t) for t in self.pose_t)
        if n_poses < 2:
            raise DatasetFileError(f"{name}: holds {n_poses} pose samples; a recording needs at least 2 "
                                   "(the acquisition stopped before the robot's stream began?)")
        if not self.prof_t:
            raise DatasetFileError(f"{name}: holds no profiles ({n_poses} pose samples); the acquisition stopped "
                                   "before the sensor's first profile, or the sensor saw nothing")
        start = np.asarray(self.points.starts, dtype=np.int64)
        pts = self.points.array()
        within = _within_limit(pts)
        bad = None if within else ~(np.abs(pts) <= MAX_ABS_VALUE).all(axis=1)  # NaN, infinity, or beyond 1e6 mm
        if bad is not None:
            i = int(np.flatnonzero(bad)[0])
            j = int(np.searchsorted(start, i, side="right") - 1)
            y, z = (float(v) for v in pts[i])
            raise DatasetFileError(f"{name} line {self.prof_line[j]}: profile.points_yz_mm_f32le: point {i - start[j]} "
                                   f"is (y, z) = ({y!r}, {z!r}) mm: not a finite number of at most "
                                   f"{MAX_ABS_VALUE:g} mm")
        poses = PoseStream.from_quaternions(
            np.concatenate(self.pose_t), np.concatenate(self.pose_tr), np.concatenate(self.pose_q),
            np.concatenate(self.pose_j) if self.n_joints is not None else None,
            np.concatenate(self.pose_seq) if self.has_seq else None)
        profiles = ProfileStream(np.asarray(self.prof_t), pts, start,
                                 np.asarray(self.prof_frame, dtype=np.int64) if self.has_frame else None,
                                 np.asarray(self.prof_sweep, dtype=np.int64) if self.has_sweep else None)
        return Recording(mounting=h["mounting"], sphere_radius_mm=h["sphere_radius_mm"], poses=poses,
                         profiles=profiles, sweeps=list(self.sweeps), provenance=h["provenance"], clocks=h["clocks"])


def _parse(raw: bytes) -> Any:
    return loads_json(raw)


def _split_points(buf: mmap.mmap, a: int, b: int) -> tuple[bytes, memoryview] | None:
    """A profile line ``buf[a:b]`` with its base64 points cut out without copying them:
    (the line with an empty string in their place, the base64 text). Parsing 14 kB of
    base64 as a JSON string costs more than all the rest of the line; None when the line
    is not laid out plainly (the caller parses it whole)."""
    i = buf.find(_POINTS_KEY, a, b)
    if i < 0:
        return None
    j = i + len(_POINTS_KEY)
    while j < b and buf[j] in b" \t":
        j += 1
    if j >= b or buf[j] != 0x3A:  # ':'
        return None
    j += 1
    while j < b and buf[j] in b" \t":
        j += 1
    if j >= b or buf[j] != 0x22:  # '"'
        return None
    k = buf.find(b'"', j + 1, b)
    if k < 0 or buf.find(b"\\", j + 1, k) >= 0:  # an escape: parse the line whole
        return None
    return buf[a:j + 1] + buf[k:b], memoryview(buf)[j + 1:k]


def read_recording(path: str | os.PathLike) -> Recording:
    """Load a stream recording (dataset format version 3, form ``stream``).

    Poses come back as a :class:`PoseStream` (quaternions normalised, w >= 0), profiles
    as a :class:`ProfileStream` of float64 (y, z) mm holding the file's float32 values.
    An incomplete last line (an interrupted write) is dropped with a
    :class:`TruncatedFileWarning`; any other problem raises :class:`DatasetFileError`
    naming the file, the line and the field."""
    name = os.fspath(path)
    check_input(path, DatasetFileError, "a stream recording")
    reader = _Reader(name)
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            # base64 takes at least 32/3 bytes a point: a bound, reserved (not touched) up to 1 GiB, grown beyond
            reader.points = PointBuffer(min(size * 3 // 32 + 16, 1 << 26))
            if size == 0:
                raise DatasetFileError(f"{name}: the file is empty; expected a stream recording (header line first)")
            # mapped, not read: the base64 is decoded straight from the page cache
            buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except OSError as exc:
        raise DatasetFileError(f"{name}: cannot read ({exc.strerror or exc})") from None
    try:
        _read_lines(reader, buf, size)
    finally:
        try:
            buf.close()
        except BufferError:  # pragma: no cover - a view held by an error's traceback; freed with it
            pass
    if reader.header is None:
        raise DatasetFileError(f"{name}: holds no header line; expected a stream recording")
    return reader.recording()


def _read_lines(reader: _Reader, buf: mmap.mmap, size: int) -> None:
    name = reader.name
    pos = 3 if buf[:3] == b"\xef\xbb\xbf" else 0  # a UTF-8 byte order mark is tolerated
    lineno = 0
    while pos < size:
        nl = buf.find(b"\n", pos)
        end = size if nl < 0 else nl + 1
        lineno += 1
        if end - pos > MAX_LINE_BYTES:
            raise DatasetFileError(f"{name} line {lineno} (byte {pos}): longer than {MAX_LINE_BYTES} bytes; "
                                   "not a stream recording line")
        if nl >= 0:
            _read_one(reader, buf, pos, end, lineno)
            pos = end
            continue
        # the last line has no newline: whole (the newline alone missing) or cut by an interrupted write
        raw = buf[pos:end]
        try:
            whole = isinstance(_parse(raw), dict)
        except ValueError:
            whole = False
        if whole:
            _read_one(reader, buf, pos, end, lineno)
        elif lineno == 1:
            raise DatasetFileError(f"{name}: the file ends inside its header (line 1 is incomplete, {len(raw)} bytes): "
                                   "the acquisition stopped before writing anything usable")
        elif raw.strip():
            warnings.warn(
                f"{name}: line {lineno} is incomplete (the file ends without its newline): dropped {len(raw)} bytes "
                f"from byte {pos} on; loaded the {_counts(reader)} before it. The acquisition was probably "
                "interrupted while writing that line.", TruncatedFileWarning, stacklevel=3)
        break


def _counts(reader: _Reader) -> str:
    return f"{len(reader.prof_t)} whole profiles and {sum(len(t) for t in reader.pose_t)} pose samples"


def _read_one(reader: _Reader, buf: mmap.mmap, a: int, b: int, lineno: int) -> None:
    """The line ``buf[a:b]`` (line ``lineno``)."""
    name = reader.name
    if lineno == 1:
        try:
            obj = _parse(buf[a:b])
        except ValueError as exc:
            raise DatasetFileError(f"{name}: not a spherecal stream recording: line 1 is not valid JSON ({exc})") \
                from None
        reader.read_header(obj)
        return
    if buf[a:a + 10] == b'{"profile"':
        cut = _split_points(buf, a, b)
        if cut is not None:
            rest, points = cut
            try:
                try:
                    obj = _parse(rest)
                except ValueError:
                    obj = None
                blk = obj.get("profile") if isinstance(obj, dict) and len(obj) == 1 else None
                if isinstance(blk, dict) and blk.get("points_yz_mm_f32le") == "":
                    reader.read_line(obj, lineno, points)
                    return
            finally:
                points.release()
    raw = buf[a:b]
    if not raw.strip():
        return
    try:
        obj = _parse(raw)
    except ValueError as exc:
        raise DatasetFileError(
            f"{name} line {lineno} (byte {a}): not valid JSON ({exc}). Only the last line of a file may be "
            "incomplete (an interrupted write); this one is followed by more lines, so the file is damaged") from None
    reader.read_line(obj, lineno)


# ---------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------


def _dumps(doc: Any) -> bytes:
    """One JSON line (with its newline): numbers at full precision (shortest round trip)."""
    if _orjson is not None:
        return _orjson.dumps(doc, option=_orjson.OPT_SERIALIZE_NUMPY | _orjson.OPT_APPEND_NEWLINE)
    return (json.dumps(json_safe(doc, ""), allow_nan=False, separators=(",", ":")) + "\n").encode()


class RecordingWriter:
    """Write a stream recording as it is acquired, one whole line at a time.

    ``RecordingWriter(path, mounting=..., sphere_radius_mm=..., clocks={"robot": ...,
    "sensor": ...}, sweeps=[...], provenance=...)`` creates ``path`` (it must not exist)
    and writes the header. :meth:`add_poses` appends a block of pose samples (robot
    clock), :meth:`add_profile` one profile and :meth:`add_profiles` many (sensor
    clock); each call writes whole lines in one write and flushes them to the operating
    system, and with ``fsync=True`` waits until they are on the disk. Stamps must
    increase within each stream across calls; what a call refuses (:class:`InputError`)
    leaves the file as it was.

    Use it as a context manager, or call :meth:`close`::

        with RecordingWriter("run.stream.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.05,
                             clocks={"robot": "abb-egm", "sensor": "nxsensor-i"}) as out:
            out.add_poses(t_robot_s, translation_mm, quaternion_wxyz)   # (n,), (n, 3), (n, 4) w first
            out.add_profile(t_sensor_s, points_yz_mm, frame=17)          # (k, 2) mm
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        mounting: str,
        sphere_radius_mm: float,
        clocks: dict[str, str] | None = None,
        sweeps: Sequence[SweepInfo] = (),
        provenance: dict[str, Any] | None = None,
        fsync: bool = False,
        created: datetime | None = None,
    ):
        self.path = Path(path)
        self.fsync = bool(fsync)
        name = os.fspath(path)
        problem = _check_mounting_radius(mounting, sphere_radius_mm)
        if problem:
            raise InputError(f"{name}: {problem}")
        try:
            self.clocks = _check_clocks(dict(clocks) if clocks is not None else {"robot": "robot", "sensor": "sensor"})
            self.sweeps = [_check_sweep(s, f"sweeps[{i}]") for i, s in enumerate(sweeps)]
        except FieldError as exc:
            raise InputError(f"{name}: {exc}") from None
        created = created or datetime.now(timezone.utc)
        if created.tzinfo is None or created.utcoffset() is None:
            raise InputError(f"{name}: created {created.isoformat()} has no time zone")
        header = {
            "format": DATASET_FORMAT, "version": STREAM_VERSION, "form": STREAM_FORM, "mounting": mounting,
            "sphere_radius_mm": float(sphere_radius_mm), "clocks": self.clocks,
            "sweeps": [{"station": s.station, "speed_mm_s": s.speed_mm_s, "direction": list(s.direction)}
                       for s in self.sweeps],
            "provenance": json_safe(provenance or {}, "provenance"),
            "created": created.isoformat(), "written_by": f"spherecal {__version__}",
        }
        line = json.dumps(header, ensure_ascii=False, allow_nan=False, separators=(", ", ": ")) + "\n"
        self._last_pose_t: float | None = None
        self._last_profile_t: float | None = None
        self._n_joints: int | None = None
        self._has_seq: bool | None = None
        self._has_frame: bool | None = None
        self._has_sweep: bool | None = None
        self.n_pose_samples = 0
        self.n_profiles = 0
        try:
            self._file = open(self.path, "xb")
        except FileExistsError:
            raise DatasetFileError(f"{name} already exists; choose a new file name (nothing is overwritten)") from None
        except OSError as exc:
            where = "its folder does not exist" if not self.path.parent.is_dir() else exc.strerror or str(exc)
            raise FileWriteError(f"{name}: cannot write ({where})") from None
        self._write(line.encode("utf-8"))
        if self.fsync:
            fsync_dir(self.path)

    # -- poses ---------------------------------------------------------------------------

    def add_poses(self, t_robot_s, translation_mm, quaternion_wxyz, joints_deg=None, seq=None) -> None:
        """Append pose samples: robot-clock stamps (n,) s, base_from_flange translations
        (n, 3) mm and quaternions (n, 4) **(w, x, y, z)**, joints (n, J) deg and the
        controller's sequence numbers (n,) if it sends them (give them on every call or
        on none). Written in lines of at most :data:`POSES_PER_LINE` samples."""
        name = os.fspath(self.path)
        try:
            t = np.atleast_1d(np.asarray(t_robot_s, dtype=float))
            n = len(t)
            tr = np.asarray(translation_mm, dtype=float).reshape(n, 3) if n else np.zeros((0, 3))
            q = np.asarray(quaternion_wxyz, dtype=float).reshape(n, 4) if n else np.zeros((0, 4))
            j = None if joints_deg is None else np.asarray(joints_deg, dtype=float).reshape(n, -1)
            s = None if seq is None else np.asarray(seq).reshape(n)
        except ValueError as exc:
            raise InputError(f"{name}: poses: {len(np.atleast_1d(t_robot_s))} stamps, but the other arrays do not "
                             f"have one row per stamp ({exc})") from None
        if n == 0:
            return
        if s is not None and s.dtype.kind not in "iu":
            raise InputError(f"{name}: poses.seq: sequence numbers must be whole numbers, got dtype {s.dtype}")
        if self._has_seq is not None:  # not the first call: the same fields as before
            for k, has, had in (("joints_deg", j is not None, self._n_joints is not None),
                                ("seq", s is not None, self._has_seq)):
                if has != had:
                    raise InputError(f"{name}: poses.{k}: {'given' if has else 'missing'} here but "
                                     f"{'given' if had else 'missing'} on the earlier calls: give it on every call "
                                     "or on none")
        if j is not None and self._n_joints is not None and j.shape[1] != self._n_joints:
            raise InputError(f"{name}: poses.joints_deg: {j.shape[1]} joints, the earlier samples had {self._n_joints}")
        try:
            for field, a, limit in (("t_robot_s", t, None), ("translation_mm", tr, MAX_ABS_VALUE),
                                    ("quaternion_wxyz", q, MAX_ABS_VALUE), ("joints_deg", j, MAX_ABS_VALUE)):
                if a is None:
                    continue
                bad = ~np.isfinite(a) if limit is None else ~(np.abs(a) <= limit)
                if bad.any():
                    i = int(np.flatnonzero(bad.ravel())[0])
                    raise FieldError(field, f"item {_item(i, a.shape)} is {float(a.ravel()[i])!r}: not a finite "
                                            "number" + ("" if limit is None else f" of at most {limit:g}"))
            q = _check_quaternions(q, "quaternion_wxyz")
            _check_stamps(t, self._last_pose_t, "t_robot_s", "robot")
        except FieldError as exc:
            raise InputError(f"{name}: poses.{exc}") from None
        lines = []
        for a in range(0, n, POSES_PER_LINE):
            b = min(n, a + POSES_PER_LINE)
            blk: dict[str, Any] = {"t_robot_s": t[a:b], "translation_mm": tr[a:b], "quaternion_wxyz": q[a:b]}
            if j is not None:
                blk["joints_deg"] = np.ascontiguousarray(j[a:b])
            if s is not None:
                blk["seq"] = s[a:b].astype(np.int64)
            lines.append(_dumps({"poses": blk}))
        self._write(b"".join(lines))
        self._last_pose_t = float(t[-1])
        self._n_joints = None if j is None else j.shape[1]
        self._has_seq = s is not None
        self.n_pose_samples += n

    # -- profiles ------------------------------------------------------------------------

    def add_profile(self, t_sensor_s: float, points_yz_mm, *, frame: int | None = None,
                    sweep: int | None = None) -> None:
        """Append one profile: its sensor-clock stamp (s, the exposure's middle) and its
        points (k, 2) (y, z) mm in the sensor's laser plane (stored as float32)."""
        pts = np.asarray(points_yz_mm, dtype=float).reshape(-1, 2)
        self.add_profiles([t_sensor_s], pts, [0, len(pts)], frame=None if frame is None else [frame],
                          sweep=None if sweep is None else [sweep])

    def add_profiles(self, t_sensor_s, points_yz_mm, start, *, frame=None, sweep=None) -> None:
        """Append m profiles laid out as :class:`ProfileStream` holds them: stamps (m,),
        points (N, 2) (y, z) mm, profile j being ``points_yz_mm[start[j]:start[j + 1]]``,
        frame counters and sweep indices (m,) or None (given on every call or on none).
        One line per profile, all written in one write."""
        name = os.fspath(self.path)
        t = np.atleast_1d(np.asarray(t_sensor_s, dtype=float))
        m = len(t)
        start = np.asarray(start, dtype=np.int64)
        pts = np.asarray(points_yz_mm)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise InputError(f"{name}: profiles: points must be (N, 2) (y, z) mm, got shape {pts.shape}")
        if len(start) != m + 1 or (m and (start[0] != 0 or start[-1] != len(pts))) or np.any(np.diff(start) < 0):
            raise InputError(f"{name}: profiles: {m} stamps need {m + 1} increasing starts from 0 to {len(pts)}")
        if m == 0:
            return
        extras = {}
        for k, v, has in (("frame", frame, self._has_frame), ("sweep", sweep, self._has_sweep)):
            if has is not None and (v is not None) != has:
                raise InputError(f"{name}: profile.{k}: {'given' if v is not None else 'missing'} here but not on the "
                                 "earlier profiles: give it for every profile or for none")
            if v is not None:
                a = np.atleast_1d(np.asarray(v))
                if a.shape != (m,) or a.dtype.kind not in "iu":
                    raise InputError(f"{name}: profile.{k}: expected {m} whole numbers, got {a.dtype} {a.shape}")
                extras[k] = a.astype(np.int64)
        if "sweep" in extras:
            bad = np.flatnonzero((extras["sweep"] < -1) | (extras["sweep"] >= len(self.sweeps)))
            if bad.size:
                raise InputError(f"{name}: profile.sweep: {int(extras['sweep'][bad[0]])} (profile {int(bad[0])} of "
                                 f"this call) is not -1 or an index into the {len(self.sweeps)} sweeps of the header")
        try:
            _check_stamps(t, self._last_profile_t, "t_sensor_s", "sensor")
        except FieldError as exc:
            raise InputError(f"{name}: profile.{exc}") from None
        frames = extras["frame"].tolist() if "frame" in extras else None
        sweeps_ = extras["sweep"].tolist() if "sweep" in extras else None
        bounds = start.tolist()
        ts = t.tolist()
        begin = self._file.tell()
        try:
            for a in range(0, m, 256):  # in batches: checked and converted in the cache, written as they go
                b = min(m, a + 256)
                batch = pts[bounds[a]:bounds[b]]
                f32 = np.ascontiguousarray(batch, dtype="<f4")
                if not _within_limit(f32):  # (a value beyond float32's range becomes infinite: refused too)
                    i = bounds[a] + int(np.flatnonzero(~(np.abs(batch) <= MAX_ABS_VALUE).all(axis=1))[0])
                    j = int(np.searchsorted(start, i, side="right") - 1)
                    raise InputError(f"{name}: profile {j} of this call (t_sensor_s {ts[j]!r}): point {i - bounds[j]} "
                                     f"is {pts[i].tolist()} mm: not a finite number of at most {MAX_ABS_VALUE:g} mm; "
                                     "nothing of this call was written")
                raw = memoryview(f32).cast("B") if f32.size else memoryview(b"")  # (no cast of an empty view)
                base = bounds[a]
                parts: list[bytes] = []
                for i in range(a, b):
                    mid = (f', "frame": {frames[i]}' if frames is not None else "") + \
                        (f', "sweep": {sweeps_[i]}' if sweeps_ is not None else "")
                    parts += (f'{{"profile": {{"t_sensor_s": {ts[i]!r}{mid}, "points_yz_mm_f32le": "'.encode("ascii"),
                              _b64encode(raw[8 * (bounds[i] - base):8 * (bounds[i + 1] - base)]), b'"}}\n')
                self._write(b"".join(parts), flush=b == m)
        except InputError:
            self._file.truncate(begin)  # a refused call leaves the file as it was
            self._file.seek(begin)
            raise
        self._last_profile_t = float(t[-1])
        self._has_frame = "frame" in extras
        self._has_sweep = "sweep" in extras
        self.n_profiles += m

    # -- file ------------------------------------------------------------------------------

    def _write(self, data: bytes, flush: bool = True) -> None:
        if self._file.closed:
            raise DatasetFileError(f"{os.fspath(self.path)}: the writer is closed")
        try:
            self._file.write(data)
            if flush:
                self._file.flush()
                if self.fsync:
                    os.fsync(self._file.fileno())
        except OSError as exc:
            raise FileWriteError(f"{os.fspath(self.path)}: cannot write ({exc.strerror or exc}); the lines written "
                                 "before are kept") from None

    @property
    def closed(self) -> bool:
        return self._file.closed

    def close(self) -> None:
        """Flush (and fsync if asked) and close; the file is closed either way."""
        if self._file.closed:
            return
        try:
            self._file.flush()
            if self.fsync:
                os.fsync(self._file.fileno())
        except OSError as exc:
            raise FileWriteError(f"{os.fspath(self.path)}: cannot write ({exc.strerror or exc})") from None
        finally:
            try:
                self._file.close()
            except OSError:
                pass

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, exc_type, *_) -> None:
        if exc_type is not None:
            try:
                self._file.close()
            except OSError:
                pass
        else:
            self.close()

    def __repr__(self) -> str:
        return (f"RecordingWriter({os.fspath(self.path)!r}, {self.n_pose_samples} pose samples, "
                f"{self.n_profiles} profiles, {'closed' if self.closed else 'open'})")


def write_recording(path: str | os.PathLike, recording: Recording, *, overwrite: bool = False,
                    fsync: bool = False) -> None:
    """Write a whole recording to ``path`` (stream form): the header, the pose stream in
    lines of :data:`POSES_PER_LINE` samples, then one line per profile. Written under a
    temporary name and renamed into place, so ``path`` never holds half a recording; an
    existing file is replaced only with ``overwrite=True``."""
    path = Path(path)
    tmp = atomic_temporary(path, overwrite)
    try:
        with RecordingWriter(tmp, mounting=recording.mounting, sphere_radius_mm=recording.sphere_radius_mm,
                             clocks=recording.clocks, sweeps=recording.sweeps, provenance=recording.provenance) as out:
            p = recording.poses
            out.add_poses(p.t_robot_s, p.t_mm, p.quaternion_wxyz, p.joints_deg, p.seq)
            pr = recording.profiles
            out.add_profiles(pr.t_sensor_s, pr.points_yz_mm, pr.start, frame=pr.frame, sweep=pr.sweep)
            if fsync:
                os.fsync(out._file.fileno())
        os.replace(tmp, path)
        if fsync:
            fsync_dir(path)
    except (InputError, DatasetFileError) as exc:  # name the file asked for, not the temporary one
        raise type(exc)(str(exc).replace(os.fspath(tmp), os.fspath(path))) from None
    finally:
        if tmp.exists():
            tmp.unlink()


# ---------------------------------------------------------------------------------------
# which reader
# ---------------------------------------------------------------------------------------


def recording_kind(path: str | os.PathLike) -> Literal["dataset", "stream", "rosbag"]:
    """What ``path`` holds, to choose its reader: ``"rosbag"`` (a rosbag2 folder with
    ``metadata.yaml``, or a ``.mcap`` / ``.db3`` file: :func:`spherecal.io.rosbag.read_bag`),
    ``"stream"`` (a stream recording: :func:`read_recording`) or ``"dataset"`` (anything
    else: :func:`spherecal.io.dataset.read_dataset`, which names what is wrong with it).
    Reads at most the first line."""
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").is_file():
            return "rosbag"
        raise DatasetFileError(f"{os.fspath(path)} is a folder without metadata.yaml: not a rosbag2 recording "
                               "(give the bag's folder, its .mcap or .db3 file, or a dataset file)")
    if p.suffix.lower() in (".mcap", ".db3"):
        return "rosbag"
    if not p.is_file():  # a pipe, a device, nothing: read_dataset's checks name it
        return "dataset"
    try:
        with open(p, "rb") as f:
            first = f.readline(MAX_LINE_BYTES)
    except OSError:
        return "dataset"  # read_dataset names the problem
    try:
        obj = loads_json(first.removeprefix(b"\xef\xbb\xbf"))
    except ValueError:
        return "dataset"
    if isinstance(obj, dict) and obj.get("format") == DATASET_FORMAT and obj.get("form") == STREAM_FORM:
        return "stream"
    return "dataset"
