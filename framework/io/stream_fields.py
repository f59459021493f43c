"""The stream form's shared pieces: its constants, the checks of its fields and the
growing buffer of points, for :mod:`spherecal.io.streams` (reading) and
:mod:`spherecal.io.stream_writer` (writing). The format: docs/file-formats.md."""

from __future__ import annotations

import binascii
import json
import math
from typing import Any

import numpy as np
from pydantic import ValidationError

from spherecal.core.models import Dataset
from spherecal.core.streams import SweepInfo
from spherecal.core.validation_errors import validation_error_lines
from spherecal.io.dataset import STREAM_DATASET_VERSION
from spherecal.io.json_files import MAX_ABS_VALUE
from spherecal.io.observation_line import FieldError

try:  # the fast serialiser (a dependency; the standard library is the fallback)
    import orjson as _orjson
except ImportError:  # pragma: no cover
    _orjson = None
try:  # SIMD base64, about 15 times binascii's speed (a dependency; binascii is the fallback)
    import pybase64 as _pybase64
except ImportError:  # pragma: no cover
    _pybase64 = None

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
    """Profile points (y, z) appended profile by profile into one array (float64, or
    float32 where the points are single precision from end to end), with the profiles'
    starts. The array grows by doubling; ``np.empty`` only reserves address space (a page
    costs when it is first written), so a generous first capacity, such as an upper bound
    from a file's size, is free, and no point is copied twice."""

    def __init__(self, capacity: int, dtype=np.float64):
        self._a = np.empty((max(int(capacity), 1024), 2), dtype)
        self.n = 0
        self.starts = [0]

    def reserve(self, k: int) -> np.ndarray:
        """Room for k more points; returns the (k, 2) block to fill (then call :meth:`added`)."""
        need = self.n + k
        if need > len(self._a):
            grown = np.empty((max(need, 2 * len(self._a)), 2), self._a.dtype)
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


