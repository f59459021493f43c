"""Dataset and calibration-result files (the formats are specified in docs/file-formats.md).

Datasets are JSON Lines (UTF-8): line 1 is a header object, then one object per
observation. A file grows one observation at a time (:class:`DatasetWriter` appends a
whole line and flushes it, with an optional ``os.fsync``), so an acquisition that is
interrupted leaves a file that :func:`read_dataset` still loads up to its last whole
observation, with a :class:`TruncatedFileWarning` saying what was dropped.

Results are one pretty-printed JSON document (:func:`write_result`, :func:`read_result`).

Conventions (docs/conventions.md): lengths in mm, angles in degrees in ``*_deg`` fields,
poses ``A_from_B`` with ``quaternion_wxyz`` scalar first (ABB order), timestamps ISO 8601
with a time zone. Numbers are written at full precision (shortest round-trip form), so a
file read back gives exactly the values that were written.

Public API::

    write_dataset(path, dataset)            read_dataset(path) -> Dataset
    DatasetWriter(path, mounting=..., sphere_radius_mm=..., resume=...)
    read_dataset_header(path) -> DatasetHeader
    write_result(path, result)              read_result(path) -> CalibrationResult
"""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from spherecal import __version__
from spherecal.core.errors import DatasetFileError, FileWriteError, InputError
from spherecal.core.models import CalibrationResult, Dataset, MountingMode, Observation, Pose

try:  # optional accelerator: parses full-precision floats about 7x faster than json
    import orjson as _orjson
except ImportError:  # pragma: no cover - exercised only where orjson is missing
    _orjson = None

__all__ = [
    "DATASET_FORMAT",
    "DATASET_VERSION",
    "RESULT_FORMAT",
    "RESULT_VERSION",
    "DatasetHeader",
    "DatasetWriter",
    "TruncatedFileWarning",
    "read_dataset",
    "read_dataset_header",
    "write_dataset",
    "read_result",
    "write_result",
]

#: ``format`` value on line 1 of every dataset file.
DATASET_FORMAT = "spherecal-dataset"
#: Newest dataset format version this module reads and the one it writes. Version 2 adds
#: centre observations (``circle``, ``sphere_centre_mm``) beside ``profile``.
DATASET_VERSION = 2
#: Observation fields that need format version 2.
_VERSION_2_FIELDS = ("circle", "sphere_centre_mm", "sphere_centre_covariance_mm2")
#: ``format`` value of every result file.
RESULT_FORMAT = "spherecal-result"
#: Newest result format version this module reads and the one it writes. Version 2 adds
#: the centre observations' figures to ``residuals``.
RESULT_VERSION = 2

_OBSERVATION_KIND = "observation"
#: Longest line of a dataset file (a profile of 3200 points is about 130 kB).
MAX_LINE_BYTES = 64 << 20
#: Largest magnitude of a coordinate (mm) or joint angle (deg) in a file: beyond it the
#: value is not a measurement (and would overflow the fits).
MAX_ABS_VALUE = 1e6


class TruncatedFileWarning(UserWarning):
    """A dataset file ended in the middle of a line (an interrupted write); the partial
    line was dropped. The message names the file, the line, the byte offset and size."""


class DatasetHeader(BaseModel):
    """Line 1 of a dataset file: what the file is and what the observations are of."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    format: Literal["spherecal-dataset"] = Field(description="always 'spherecal-dataset'")
    version: int = Field(ge=1, le=DATASET_VERSION, description="format version the file was written in")
    mounting: MountingMode = Field(description="eye_in_hand or eye_to_hand")
    sphere_radius_mm: float = Field(gt=0, description="certified radius of the reference sphere, mm")
    provenance: dict[str, Any] = Field(default={}, description="where the data came from (free form)")
    created: datetime = Field(description="when the file was started, ISO 8601 with a time zone")
    written_by: str = Field("", description="software that started the file, e.g. 'spherecal 0.1.0'")


# ---------------------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------------------


class _FieldError(Exception):
    """A problem with one field of one line; turned into a DatasetFileError by the caller."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}" if field else message)


#: The components of the fixed-length number lists of the format, by field name: a list
#: of the wrong length is reported as "needs 3 numbers (x, y, z), got 2".
_COMPONENTS = {"translation_mm": "x, y, z", "quaternion_wxyz": "w, x, y, z", "sphere_centre_mm": "x, y, z",
               "centre_yz_mm": "y, z"}


def _loc_text(loc) -> str:
    text = ""
    for item in loc:
        text += f"[{item}]" if isinstance(item, int) else (f".{item}" if text else str(item))
    return text


def _wrong_length(loc, given, needed: int | None) -> str | None:
    """"needs N numbers (names), got M" for a fixed-length list of the wrong length, else None."""
    name = next((x for x in reversed(loc) if isinstance(x, str)), "")
    if not isinstance(given, (list, tuple)):
        return None
    parts = _COMPONENTS.get(name)
    n = len(parts.split(", ")) if parts else needed
    if n is None:
        return None
    names = f" ({parts})" if parts else ""
    return f"needs {n} numbers{names}, got {len(given)}"


def _describe_validation_error(exc: ValidationError) -> str:
    parts = []
    short: dict[tuple, int] = {}  # a list too short: its location -> how many items the errors ask for
    errors = exc.errors()
    for err in errors:
        loc = err["loc"]
        if err["type"] == "missing" and loc and isinstance(loc[-1], int) and isinstance(err.get("input"), (list, tuple)):
            short[tuple(loc[:-1])] = max(short.get(tuple(loc[:-1]), 0), loc[-1] + 1)
    done: set[tuple] = set()
    for err in errors:
        loc = err["loc"]
        msg = err["msg"]
        for prefix in ("Value error, ", "Assertion failed, "):
            if msg.startswith(prefix):
                msg = msg[len(prefix):]
        if err["type"] == "extra_forbidden":
            msg = "unknown field (not part of the format; check the spelling)"
        elif err["type"] == "missing" and tuple(loc[:-1]) in short:
            loc = tuple(loc[:-1])
            if loc in done:
                continue
            done.add(loc)
            msg = _wrong_length(loc, err["input"], short[loc]) or "missing (required)"
        elif err["type"] == "missing":
            msg = "missing (required)"
        elif err["type"] == "too_long" and (ctx := err.get("ctx")) and ctx.get("field_type") == "Tuple":
            msg = _wrong_length(loc, err.get("input"), ctx.get("max_length")) or msg
        text = _loc_text(loc)
        parts.append(f"{text}: {msg}" if text else msg)
    return "; ".join(parts)


def _loads(raw: bytes) -> Any:
    """Parse one JSON text. orjson when available (fast, strict JSON); the standard
    library as the fallback and for what orjson rejects but Python's json reads (NaN,
    Infinity), so that such a file fails in validation with a field path, not here."""
    if _orjson is not None:
        try:
            return _orjson.loads(raw)
        except ValueError:
            pass
    try:
        return json.loads(raw)
    except RecursionError:
        raise ValueError("nested too deeply (hundreds of levels of lists or objects)") from None


def _parse_timestamp(value: Any) -> datetime:
    if isinstance(value, datetime):
        ts = value
    elif isinstance(value, str):
        try:
            ts = datetime.fromisoformat(value)
        except ValueError:
            raise _FieldError("timestamp", f"{value!r} is not an ISO 8601 date and time") from None
    else:
        raise _FieldError("timestamp", f"expected an ISO 8601 string, got {value!r}")
    if ts.tzinfo is None or ts.utcoffset() is None:
        raise _FieldError(
            "timestamp", f"{value!r} has no time zone; write it with one (UTC: end it with 'Z' or '+00:00')"
        )
    return ts


def _within_limit(v: int | float) -> bool:
    """A finite number of magnitude at most MAX_ABS_VALUE (a huge int overflows float)."""
    try:
        return abs(float(v)) <= MAX_ABS_VALUE
    except OverflowError:
        return False


def _number_array(value: Any, field: str) -> np.ndarray:
    """A JSON list of numbers as a float array, refusing strings, booleans and nulls
    (which NumPy would otherwise convert, or keep as objects)."""
    if not isinstance(value, list):
        raise _FieldError(field, f"expected a list of numbers, got {type(value).__name__} {value!r:.60}")
    try:
        arr = np.asarray(value)
    except ValueError:
        raise _FieldError(field, "expected a flat list of numbers, got nested lists of unequal length") from None
    kind = arr.dtype.kind
    if kind in "fiu" and arr.size and arr.ndim == 1:
        with np.errstate(invalid="ignore", over="ignore"):
            a = arr.astype(float)
            big = np.flatnonzero(np.isfinite(a) & (np.abs(a) > MAX_ABS_VALUE))  # NaN, inf: the model says
        if big.size:
            i = int(big[0])
            raise _FieldError(field, f"item {i} is {float(arr[i])!r}: beyond {MAX_ABS_VALUE:g} mm, not a "
                                     "measurement (check the units)")
    if kind == "f" and arr.ndim == 1:
        # NumPy turns true/false mixed with floats into 1.0/0.0: look only at those values
        suspects = np.flatnonzero((arr == 1.0) | (arr == 0.0))
        if not any(type(value[i]) is bool for i in suspects):
            return arr
    elif kind in "iu":
        return arr.astype(float)
    elif kind == "f":
        return arr  # not flat: the model reports the shape
    for i, v in enumerate(value):
        if type(v) is bool or not isinstance(v, (int, float)):
            if isinstance(v, list):
                raise _FieldError(field, f"expected a flat list of numbers, item {i} is a list")
            shown = "null" if v is None else json.dumps(v) if isinstance(v, (bool, str)) else repr(v)
            raise _FieldError(field, f"must hold only numbers; item {i} is {shown} ({type(v).__name__})")
        if not _within_limit(v):
            raise _FieldError(field, f"item {i} is {v!r:.40}: not a finite number of at most {MAX_ABS_VALUE:g} mm "
                                     "(check the units)")
    return np.asarray(value, dtype=float)


def _small_numbers(value: Any, field: str) -> Any:
    """Poses and joint readings: JSON lists -> tuples (what the strict model expects)."""
    if isinstance(value, list):
        for i, v in enumerate(value):
            if type(v) is bool or not isinstance(v, (int, float)):
                raise _FieldError(field, f"must hold only numbers; item {i} is {json.dumps(v)}")
            if not _within_limit(v):
                raise _FieldError(field, f"item {i} is {v!r:.40}: not a finite number of at most {MAX_ABS_VALUE:g} "
                                         "(check the units)")
        return tuple(value)
    return value


def _pose_input(value: Any, field: str) -> Any:
    if isinstance(value, dict):
        value = dict(value)
        for key in ("translation_mm", "quaternion_wxyz"):
            if key in value:
                value[key] = _small_numbers(value[key], f"{field}.{key}")
    return value


def _keep_written_quaternion(pose: Pose, raw: Any) -> Pose:
    """Pose normalises its quaternion; re-normalising an already unit quaternion can move
    its last bit. When the file's quaternion is unit to rounding and has w >= 0, keep it
    bit for bit so that round trips are exact. Anything further off keeps the model's
    normalised value."""
    try:
        q_file = tuple(float(c) for c in raw["quaternion_wxyz"])
    except (TypeError, KeyError, ValueError):
        return pose
    if q_file == pose.quaternion_wxyz:
        return pose
    if q_file[0] >= 0 and max(abs(a - b) for a, b in zip(q_file, pose.quaternion_wxyz)) <= 1e-15:
        return Pose.model_construct(translation_mm=pose.translation_mm, quaternion_wxyz=q_file)
    return pose


def _scalar_number(value: Any, field: str) -> Any:
    """One JSON number, finite and at most MAX_ABS_VALUE (null passes: the model says
    whether it may be absent)."""
    if value is None:
        return value
    if type(value) is bool or not isinstance(value, (int, float)):
        shown = json.dumps(value) if isinstance(value, (str, bool)) else repr(value)
        raise _FieldError(field, f"must be a number, got {shown:.40}")
    if not _within_limit(value):
        raise _FieldError(field, f"{value!r:.40} is not a finite number of at most {MAX_ABS_VALUE:g} (check the units)")
    return value


def _centre_input(data: dict) -> None:
    """The version-2 fields of an observation, checked number by number (in place)."""
    circle = data.get("circle")
    if isinstance(circle, dict):
        circle = dict(circle)
        if "centre_yz_mm" in circle:
            circle["centre_yz_mm"] = _small_numbers(circle["centre_yz_mm"], "circle.centre_yz_mm")
        for key in ("radius_mm", "centre_std_mm", "radius_std_mm"):
            if key in circle:
                circle[key] = _scalar_number(circle[key], f"circle.{key}")
        data["circle"] = circle
    if data.get("sphere_centre_mm") is not None:
        data["sphere_centre_mm"] = _small_numbers(data["sphere_centre_mm"], "sphere_centre_mm")
    cov = data.get("sphere_centre_covariance_mm2")
    if cov is not None:
        field = "sphere_centre_covariance_mm2"
        if not isinstance(cov, list) or len(cov) != 3 or not all(isinstance(r, list) and len(r) == 3 for r in cov):
            raise _FieldError(field, "expected a 3x3 matrix: a list of 3 rows of 3 numbers, mm^2")
        data[field] = tuple(_small_numbers(row, f"{field}[{i}]") for i, row in enumerate(cov))


def _observation_from_json(obj: Any, version: int = DATASET_VERSION) -> Observation:
    if not isinstance(obj, dict):
        raise _FieldError("", f"expected a JSON object, got {type(obj).__name__}")
    if "format" in obj and "kind" not in obj:
        raise _FieldError(
            "", f"a second header (format {obj.get('format')!r}); two files were joined into one? "
            "Keep one dataset per file"
        )
    data = dict(obj)
    kind = data.pop("kind", None)
    if kind != _OBSERVATION_KIND:
        raise _FieldError("kind", f"expected 'observation', got {json.dumps(kind)}")
    if "timestamp" not in data:
        raise _FieldError("timestamp", "missing (required in files: ISO 8601 with a time zone)")
    data["timestamp"] = _parse_timestamp(data["timestamp"])
    if data.get("base_from_flange") is not None:
        data["base_from_flange"] = _pose_input(data["base_from_flange"], "base_from_flange")
    if data.get("joints_deg") is not None:
        data["joints_deg"] = _small_numbers(data["joints_deg"], "joints_deg")
    if version < 2:
        late = [k for k in _VERSION_2_FIELDS if k in data]
        if late:
            raise _FieldError(late[0], f"needs dataset format version 2 (the header says version {version}): "
                                       "write \"version\": 2 on line 1")
        if "profile" not in data:
            raise _FieldError("profile", "missing (required in version 1 files)")
    _centre_input(data)
    profile = data.get("profile")
    if isinstance(profile, dict):
        profile = dict(profile)
        for key in ("y_mm", "z_mm"):
            if key in profile:
                profile[key] = _number_array(profile[key], f"profile.{key}")
        data["profile"] = profile
    try:
        obs = Observation.model_validate(data, strict=True)
    except ValidationError as exc:
        raise _FieldError("", _describe_validation_error(exc)) from None
    if obs.base_from_flange is not None:
        pose = _keep_written_quaternion(obs.base_from_flange, obj["base_from_flange"])
        if pose is not obs.base_from_flange:
            obs = obs.model_copy(update={"base_from_flange": pose})
    return obs


def _observation_line(obs: Observation) -> bytes:
    """One observation as one line of JSON (with its newline)."""
    if not isinstance(obs, Observation):
        raise InputError(f"expected an Observation, got {type(obs).__name__}")
    ts = obs.timestamp
    if ts.tzinfo is None or ts.utcoffset() is None:
        raise InputError(
            f"observation {obs.index}: timestamp {ts.isoformat()} has no time zone; "
            "files hold ISO 8601 with a time zone (use datetime.now(timezone.utc))"
        )
    profile = obs.profile
    if profile is not None:
        y, z = profile.y_mm, profile.z_mm
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(z))):
            raise InputError(f"observation {obs.index}: profile contains NaN or infinite values; not written")
    pose = obs.base_from_flange
    doc = {
        "kind": _OBSERVATION_KIND,
        "index": obs.index,
        "station": obs.station,
        "timestamp": ts.isoformat(),
        "base_from_flange": None
        if pose is None
        else {"translation_mm": list(pose.translation_mm), "quaternion_wxyz": list(pose.quaternion_wxyz)},
        "joints_deg": None if obs.joints_deg is None else list(obs.joints_deg),
    }
    centre_numbers: list[float] = []
    if profile is not None:
        doc["profile"] = {"y_mm": np.ascontiguousarray(y), "z_mm": np.ascontiguousarray(z)}
        if profile.shot_id is not None:
            doc["profile"]["shot_id"] = profile.shot_id
    elif obs.circle is not None:
        c = obs.circle
        doc["circle"] = {"centre_yz_mm": list(c.centre_yz_mm), "radius_mm": c.radius_mm}
        for key in ("centre_std_mm", "radius_std_mm"):
            if getattr(c, key) is not None:
                doc["circle"][key] = getattr(c, key)
        centre_numbers = [*c.centre_yz_mm, c.radius_mm]
    else:
        doc["sphere_centre_mm"] = list(obs.sphere_centre_mm)
        centre_numbers = list(obs.sphere_centre_mm)
        if obs.sphere_centre_covariance_mm2 is not None:
            doc["sphere_centre_covariance_mm2"] = [list(r) for r in obs.sphere_centre_covariance_mm2]
            centre_numbers += [v for r in obs.sphere_centre_covariance_mm2 for v in r]
    if obs.target is not None:
        doc["target"] = obs.target
    small = [*(pose.translation_mm if pose else ()), *(pose.quaternion_wxyz if pose else ()), *(obs.joints_deg or ())]
    if not all(math.isfinite(v) for v in small):
        raise InputError(f"observation {obs.index}: pose or joints contain NaN or infinite values; not written")
    if not all(math.isfinite(v) for v in centre_numbers):
        raise InputError(f"observation {obs.index}: {obs.kind} contains NaN or infinite values; not written")
    if _orjson is not None:
        return _orjson.dumps(doc, option=_orjson.OPT_SERIALIZE_NUMPY | _orjson.OPT_APPEND_NEWLINE)
    if profile is not None:
        doc["profile"].update(y_mm=y.tolist(), z_mm=z.tolist())
    return (json.dumps(doc, ensure_ascii=False, allow_nan=False, separators=(",", ":")) + "\n").encode("utf-8")


def _check_json_safe(value: Any, where: str) -> Any:
    """Plain JSON types only (dict with str keys, list, str, finite number, bool, None);
    tuples, NumPy arrays and scalars, datetimes and paths are converted. Anything else,
    and NaN or infinity, raises InputError naming the place."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{where} is {value}: a file cannot hold NaN or infinity (standard JSON)")
        return value if type(value) in (int, float) else (float(value) if isinstance(value, float) else int(value))
    if isinstance(value, np.generic):
        return _check_json_safe(value.item(), where)
    if isinstance(value, np.ndarray):
        return _check_json_safe(value.tolist(), where)
    if isinstance(value, BaseModel):
        return _check_json_safe(value.model_dump(mode="python"), where)
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise InputError(f"{where}: key {k!r} is not a string; JSON object keys must be strings")
            out[k] = _check_json_safe(v, f"{where}.{k}" if where else k)
        return out
    if isinstance(value, (list, tuple)):
        return [_check_json_safe(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, Path):
        return str(value)
    raise InputError(f"{where}: a {type(value).__name__} cannot be written to a JSON file")


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # pragma: no cover - e.g. Windows
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


# ---------------------------------------------------------------------------------------
# reading datasets
# ---------------------------------------------------------------------------------------


@dataclass
class _Scan:
    header: DatasetHeader
    observations: list[Observation]
    whole_end: int  # byte offset just past the last whole line
    needs_newline: bool  # the last whole line has no trailing newline
    dropped: tuple[int, int, int] | None  # (line number, byte offset, byte count) of a cut-off tail


def _header_from_json(obj: Any, name: str) -> DatasetHeader:
    where = f"{name} line 1 (header)"
    if not isinstance(obj, dict) or "format" not in obj:
        found = f"a JSON {type(obj).__name__}" if not isinstance(obj, dict) else "an object without 'format'"
        raise DatasetFileError(
            f"{name}: not a spherecal dataset: line 1 should be a header object with "
            f"format {DATASET_FORMAT!r}, found {found}"
        )
    fmt = obj["format"]
    if fmt != DATASET_FORMAT:
        hint = ("; it is a calibration result, not a dataset: give a dataset (a run's journal.jsonl, or a file "
                "spherecal simulate wrote)") if fmt == RESULT_FORMAT else ""
        raise DatasetFileError(
            f"{name}: not a spherecal dataset: line 1 has format {json.dumps(fmt)}, "
            f"expected {DATASET_FORMAT!r}{hint}"
        )
    version = obj.get("version")
    if type(version) is not int or version < 1:
        raise DatasetFileError(f"{where}: version must be a whole number >= 1, found {json.dumps(version)}")
    if version > DATASET_VERSION:
        raise DatasetFileError(
            f"{name}: dataset format version {version} is newer than this spherecal ({__version__}) "
            f"reads (versions 1 to {DATASET_VERSION}); upgrade spherecal to read it"
        )
    data = dict(obj)
    if "created" not in data:
        raise DatasetFileError(f"{where}: created: missing (required)")
    try:
        data["created"] = _parse_timestamp(data["created"])
    except _FieldError as exc:
        raise DatasetFileError(f"{where}: {str(exc).replace('timestamp', 'created', 1)}") from None
    try:
        header = DatasetHeader.model_validate(data, strict=True)
        # the dataset's own rules on mounting and radius (e.g. a radius in metres)
        Dataset.model_validate(
            {"mounting": header.mounting, "sphere_radius_mm": header.sphere_radius_mm}, strict=True
        )
    except ValidationError as exc:
        raise DatasetFileError(f"{where}: {_describe_validation_error(exc)}") from None
    return header


def _is_result_document(data: bytes) -> bool:
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError):
        return False
    return isinstance(doc, dict) and doc.get("format") == RESULT_FORMAT


_NOT_BLANK = re.compile(rb"\S")


def _scan(path: str | os.PathLike, data: bytes) -> _Scan:
    name = os.fspath(path)
    if not data:
        raise DatasetFileError(f"{name}: the file is empty; expected a spherecal dataset (header line first)")
    start = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # tolerate a UTF-8 byte order mark
    if start == len(data) or _NOT_BLANK.search(data, start) is None:
        raise DatasetFileError(f"{name}: the file holds no data (only a byte order mark or blank space); "
                               "expected a spherecal dataset (header line first)")
    from spherecal.io.files import text_encoding_problem

    problem = text_encoding_problem(data)
    if problem:
        raise DatasetFileError(f"{name}: not a spherecal dataset as written: {problem}. A dataset is UTF-8 "
                               "JSON Lines; the data may well be intact")
    # (byte offset, end) of each line's content without its newline; a line's bytes are
    # copied out only while it is parsed (the file is held once, not twice)
    lines: list[tuple[int, int]] = []
    pos = start
    while pos < len(data):
        nl = data.find(b"\n", pos)
        end = len(data) if nl < 0 else nl
        if end - pos > MAX_LINE_BYTES:
            raise DatasetFileError(f"{name} line {len(lines) + 1} (byte {pos}): longer than {MAX_LINE_BYTES} bytes; "
                                   "not a spherecal dataset line (one profile is at most a few hundred kB)")
        lines.append((pos, end))
        if nl < 0:
            break
        pos = nl + 1
    ends_with_newline = data.endswith(b"\n")

    needs_newline = False
    dropped = None
    whole_end = len(data)
    if not ends_with_newline:
        off, end = lines[-1]
        tail = data[off:end]
        try:
            whole = isinstance(_loads(tail), dict)
        except ValueError:
            whole = False
        if whole:  # complete JSON object, only the newline missing (or written by hand)
            needs_newline = True
        else:
            if len(lines) == 1:
                raise DatasetFileError(
                    f"{name}: the file ends inside its header (line 1 is incomplete, {len(data)} bytes): "
                    "the acquisition stopped before writing anything usable; delete the file and start again"
                )
            dropped = (len(lines), off, len(data) - off)
            whole_end = off
            lines.pop()

    off0, end0 = lines[0]
    raw0 = data[off0:end0]
    try:
        header_obj = _loads(raw0)
    except ValueError as exc:
        if _is_result_document(data):
            raise DatasetFileError(
                f"{name}: not a spherecal dataset: it is a calibration result ({RESULT_FORMAT!r}); give a dataset (a "
                "run's journal.jsonl, or a file spherecal simulate wrote)"
            ) from None
        raise DatasetFileError(
            f"{name}: not a spherecal dataset: line 1 is not valid JSON ({exc}); "
            "a dataset is JSON Lines with a header object on line 1"
        ) from None
    header = _header_from_json(header_obj, name)

    observations: list[Observation] = []
    seen: dict[int, int] = {}  # index -> line number
    for k in range(1, len(lines)):
        lineno = k + 1
        off, end = lines[k]
        raw = data[off:end]
        if not raw.strip():
            continue
        try:
            obj = _loads(raw)
        except ValueError as exc:
            raise DatasetFileError(
                f"{name} line {lineno} (byte {off}): not valid JSON ({exc}). Only the last line of a file "
                "may be incomplete (an interrupted write); this one is followed by more lines, so the "
                "file is damaged: repair or remove this line"
            ) from None
        idx = obj.get("index") if isinstance(obj, dict) else None
        where = f"{name} line {lineno}" + (f" (observation {idx})" if type(idx) is int else "")
        try:
            obs = _observation_from_json(obj, header.version)
        except _FieldError as exc:
            raise DatasetFileError(f"{where}: {exc}") from None
        if obs.index in seen:
            raise DatasetFileError(
                f"{where}: index {obs.index} was already used on line {seen[obs.index]}; every observation "
                "of a dataset needs its own index (two acquisitions written into one file?)"
            )
        seen[obs.index] = lineno
        observations.append(obs)

    if dropped is not None:
        lineno, off, nbytes = dropped
        warnings.warn(
            f"{name}: line {lineno} is incomplete (the file ends without its newline): dropped "
            f"{nbytes} bytes from byte {off} on; loaded the {len(observations)} whole observations "
            "before it. The acquisition was probably interrupted while writing that line.",
            TruncatedFileWarning,
            stacklevel=3,
        )
    return _Scan(header, observations, whole_end, needs_newline, dropped)


def _read_bytes(path: str | os.PathLike) -> bytes:
    from spherecal.io.files import read_input

    return read_input(path, DatasetFileError, "a spherecal file")


def read_dataset(path: str | os.PathLike) -> Dataset:
    """Load a dataset file (JSON Lines, docs/file-formats.md).

    Every observation is validated with the rules of :mod:`spherecal.core.models`. An
    incomplete last line (an interrupted write) is dropped with a
    :class:`TruncatedFileWarning`; any other problem raises :class:`DatasetFileError`
    naming the file, the line, the observation index and the field.
    ``provenance`` comes back as JSON types (tuples written become lists)."""
    scan = _scan(path, _read_bytes(path))
    h = scan.header
    return Dataset(
        mounting=h.mounting,
        sphere_radius_mm=h.sphere_radius_mm,
        provenance=h.provenance,
        observations=scan.observations,
    )


def read_dataset_header(path: str | os.PathLike) -> DatasetHeader:
    """Read and check only line 1 of a dataset file (format, version, mounting, radius,
    provenance, creation time)."""
    name = os.fspath(path)
    from spherecal.io.files import check_input

    check_input(path, DatasetFileError, "a dataset file")
    try:
        with open(path, "rb") as f:
            raw = f.readline(MAX_LINE_BYTES + 1)
    except OSError as exc:
        raise DatasetFileError(f"{name}: cannot read ({exc.strerror or exc})") from None
    if len(raw) > MAX_LINE_BYTES:
        raise DatasetFileError(f"{name}: line 1 is longer than {MAX_LINE_BYTES} bytes; not a spherecal dataset")
    if not raw:
        raise DatasetFileError(f"{name}: the file is empty; expected a spherecal dataset (header line first)")
    raw = raw.removeprefix(b"\xef\xbb\xbf")
    try:
        obj = _loads(raw)
    except ValueError as exc:
        if not raw.endswith(b"\n"):
            raise DatasetFileError(f"{name}: the file ends inside its header (line 1 is incomplete)") from None
        raise DatasetFileError(f"{name}: not a spherecal dataset: line 1 is not valid JSON ({exc})") from None
    return _header_from_json(obj, name)


# ---------------------------------------------------------------------------------------
# writing datasets
# ---------------------------------------------------------------------------------------


class DatasetWriter:
    """Write a dataset file one observation at a time.

    ``DatasetWriter(path, mounting=..., sphere_radius_mm=..., provenance=...)`` creates a
    new file and writes its header; the file must not exist. With ``resume=True`` an
    existing file is continued instead (a missing or empty one is created): its header
    must have the same ``mounting`` and ``sphere_radius_mm`` (its own ``provenance``
    stays), every line in it is validated, and an incomplete last line left by an
    interrupted write is cut off (with a :class:`TruncatedFileWarning`) so that the next
    line starts whole.

    :meth:`append` writes one observation as one line and flushes it to the operating
    system; with ``fsync=True`` it also waits until the line is on disk (``os.fsync``),
    which survives a power cut but costs a few milliseconds per line. Indices must be
    unique within the file; :attr:`next_index` is one past the largest so far.

    Use it as a context manager, or call :meth:`close`::

        with DatasetWriter("run.dataset.jsonl", mounting="eye_in_hand",
                           sphere_radius_mm=19.05, resume=True) as out:
            for shot in shots:
                out.append(Observation(index=out.next_index, ...))
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        mounting: MountingMode,
        sphere_radius_mm: float,
        provenance: dict[str, Any] | None = None,
        resume: bool = False,
        fsync: bool = False,
        created: datetime | None = None,
    ):
        self.path = Path(path)
        self.fsync = bool(fsync)
        name = os.fspath(path)
        try:
            Dataset.model_validate({"mounting": mounting, "sphere_radius_mm": sphere_radius_mm}, strict=True)
        except ValidationError as exc:
            raise InputError(f"{name}: {_describe_validation_error(exc)}") from None
        self._indices: dict[int, int] = {}  # index -> line number
        self._lines = 1
        exists = self.path.exists()
        if exists and not resume:
            raise DatasetFileError(
                f"{name} already exists; pass resume=True to append to it, or choose a new file name"
            )
        if exists and self.path.stat().st_size > 0:
            self.header = self._resume(name, mounting, float(sphere_radius_mm))
        else:
            created = created or datetime.now(timezone.utc)
            if created.tzinfo is None:
                raise InputError(f"{name}: created {created.isoformat()} has no time zone")
            self.header = DatasetHeader(
                format=DATASET_FORMAT,
                version=DATASET_VERSION,
                mounting=mounting,
                sphere_radius_mm=float(sphere_radius_mm),
                provenance=provenance or {},
                created=created,
                written_by=f"spherecal {__version__}",
            )
            doc = _check_json_safe(self.header.model_dump(mode="python"), "header")
            line = json.dumps(doc, ensure_ascii=False, allow_nan=False, separators=(", ", ": ")) + "\n"
            self._file = open(self.path, "r+b" if exists else "xb")
            self._write(line.encode("utf-8"))
            if self.fsync:
                _fsync_dir(self.path)

    def _resume(self, name: str, mounting: str, radius: float) -> DatasetHeader:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TruncatedFileWarning)
            scan = _scan(self.path, _read_bytes(self.path))
        for w in caught:  # re-issue, attributed to the caller
            warnings.warn(
                f"{w.message} Resuming: the incomplete line is cut off before appending.",
                w.category,
                stacklevel=3,
            )
        h = scan.header
        if h.version != DATASET_VERSION:
            raise DatasetFileError(
                f"{name} is in dataset format version {h.version}; only version {DATASET_VERSION} files "
                "can be continued: start a new file (read_dataset reads it; write_dataset writes it anew)"
            )
        if h.mounting != mounting or h.sphere_radius_mm != radius:
            raise DatasetFileError(
                f"{name} holds a dataset for mounting={h.mounting}, sphere_radius_mm={h.sphere_radius_mm}; "
                f"this acquisition is mounting={mounting}, sphere_radius_mm={radius}. "
                "Write to a new file instead"
            )
        lineno = 1
        for obs in scan.observations:
            lineno += 1
            self._indices[obs.index] = lineno
        self._lines = lineno
        self._file = open(self.path, "r+b")
        if scan.dropped is not None:
            self._file.truncate(scan.whole_end)
        self._file.seek(scan.whole_end)
        if scan.needs_newline:
            self._write(b"\n")
        return h

    def _write(self, data: bytes) -> None:
        try:
            self._file.write(data)
            self._file.flush()
            if self.fsync:
                os.fsync(self._file.fileno())
        except OSError as exc:  # a full disk, a removed medium: name the file
            raise self._write_error(exc) from None

    def _write_error(self, exc: OSError) -> FileWriteError:
        """A failed write (a full disk, a removed medium), naming the file."""
        return FileWriteError(
            f"{os.fspath(self.path)}: cannot write ({exc.strerror or exc}); the lines written before are kept")

    @property
    def n_observations(self) -> int:
        """Observations in the file so far (those found when resuming included)."""
        return len(self._indices)

    @property
    def next_index(self) -> int:
        """One past the largest observation index in the file (0 for a new file)."""
        return max(self._indices, default=-1) + 1

    @property
    def closed(self) -> bool:
        return self._file.closed

    def append(self, observation: Observation) -> None:
        """Write one observation as one line, then flush (and fsync if asked)."""
        if self._file.closed:
            raise DatasetFileError(f"{os.fspath(self.path)}: the writer is closed; open a new one with resume=True")
        line = _observation_line(observation)
        if observation.index in self._indices:
            raise InputError(
                f"{os.fspath(self.path)}: observation index {observation.index} is already in the file "
                f"(line {self._indices[observation.index]}); use a new index (next free: {self.next_index})"
            )
        self._write(line)
        self._lines += 1
        self._indices[observation.index] = self._lines

    def close(self) -> None:
        """Flush (and fsync if asked) and close; a failure names the file
        (:class:`FileWriteError`), and the file is closed either way."""
        if self._file.closed:
            return
        try:
            self._file.flush()
            if self.fsync:
                os.fsync(self._file.fileno())
        except OSError as exc:
            raise self._write_error(exc) from None
        finally:
            self._close_quietly()

    def _close_quietly(self) -> None:
        try:
            self._file.close()
        except OSError:  # what failed to write is still buffered (a full disk): the lines before are on disk
            pass

    def __enter__(self) -> "DatasetWriter":
        return self

    def __exit__(self, exc_type, *_) -> None:
        if exc_type is not None:
            # the run already failed (a full disk, a device): its error is the one to report, not a
            # second one from flushing what is left
            self._close_quietly()
        else:
            self.close()

    def __repr__(self) -> str:
        state = "closed" if self.closed else "open"
        return f"DatasetWriter({os.fspath(self.path)!r}, {self.n_observations} observations, {state})"


def _atomic_target(path: Path, overwrite: bool) -> Path:
    if path.exists() and not overwrite:
        raise DatasetFileError(f"{os.fspath(path)} already exists; pass overwrite=True to replace it")
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_dataset(
    path: str | os.PathLike, dataset: Dataset, *, overwrite: bool = False, fsync: bool = False
) -> None:
    """Write a whole dataset to ``path`` (JSON Lines, docs/file-formats.md).

    The file is written under a temporary name and renamed into place, so ``path``
    never holds a half-written dataset. An existing file is replaced only with
    ``overwrite=True``."""
    path = Path(path)
    tmp = _atomic_target(path, overwrite)
    try:
        try:
            writer = DatasetWriter(
                tmp,
                mounting=dataset.mounting,
                sphere_radius_mm=dataset.sphere_radius_mm,
                provenance=dataset.provenance,
                fsync=False,
            )
        except OSError as exc:  # (the message names the file asked for, not the temporary one)
            where = "its folder does not exist" if not path.parent.is_dir() else exc.strerror or str(exc)
            raise FileWriteError(f"{os.fspath(path)}: cannot write ({where})") from None
        with writer as out:
            out.path = path  # so that error messages name the real file
            for obs in dataset.observations:
                out.append(obs)
            if fsync:
                os.fsync(out._file.fileno())
        os.replace(tmp, path)
        if fsync:
            _fsync_dir(path)
    finally:
        if tmp.exists():
            tmp.unlink()


# ---------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------


def _scalar_json(v: Any) -> str:
    return json.dumps(v, ensure_ascii=False, allow_nan=False)


def _pretty(v: Any, indent: int) -> str:
    """Indented JSON that keeps short lists of numbers (vectors, matrix rows) on one line."""
    pad, inner = "  " * indent, "  " * (indent + 1)
    if isinstance(v, dict):
        if not v:
            return "{}"
        items = [f"{inner}{_scalar_json(k)}: {_pretty(x, indent + 1)}" for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(v, list):
        if all(not isinstance(x, (dict, list)) for x in v):
            return "[" + ", ".join(_scalar_json(x) for x in v) + "]"
        return "[\n" + ",\n".join(inner + _pretty(x, indent + 1) for x in v) + "\n" + pad + "]"
    return _scalar_json(v)


def write_result(
    path: str | os.PathLike, result: CalibrationResult, *, overwrite: bool = False, fsync: bool = False
) -> None:
    """Write a calibration result as one pretty-printed JSON document (UTF-8), format
    ``spherecal-result``. Poses are ``translation_mm`` + ``quaternion_wxyz`` (w first).
    Written under a temporary name and renamed into place; an existing file is replaced
    only with ``overwrite=True``. NaN or infinity anywhere raises InputError naming the
    field (standard JSON cannot hold them)."""
    if not isinstance(result, CalibrationResult):
        raise InputError(f"expected a CalibrationResult, got {type(result).__name__}")
    path = Path(path)
    doc = _check_json_safe(result.model_dump(mode="python"), "")
    text = _pretty(doc, 0) + "\n"
    tmp = _atomic_target(path, overwrite)
    try:
        with open(tmp, "xb") as f:
            f.write(text.encode("utf-8"))
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
        if fsync:
            _fsync_dir(path)
    except OSError as exc:
        raise FileWriteError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None
    finally:
        if tmp.exists():
            tmp.unlink()


def _non_finite(value: Any, where: str) -> str | None:
    """The path of the first NaN or infinite number in a parsed JSON document, or None."""
    stack = [(value, where)]
    while stack:
        v, at = stack.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return at
        if isinstance(v, dict):
            stack.extend((x, f"{at}.{k}" if at else str(k)) for k, x in v.items())
        elif isinstance(v, list):
            stack.extend((x, f"{at}[{i}]") for i, x in enumerate(v))
    return None


def _result_number_problem(doc: dict) -> str | None:
    """What is wrong with the numbers of a result document (NaN or infinity anywhere, a
    negative standard deviation or variance, an implausibly large position), or None."""
    at = _non_finite(doc, "")
    if at:
        return f"{at}: NaN or infinity is not a number a result can hold (standard JSON has neither)"
    for key in ("std_rotation_deg", "std_translation_mm", "std_sphere_centre_mm"):
        v = doc.get(key)
        if isinstance(v, list) and any(isinstance(x, (int, float)) and x < 0 for x in v):
            return f"{key}: a standard deviation cannot be negative, got {v}"
    radius = doc.get("sphere_radius_mm")
    if isinstance(radius, (int, float)) and not isinstance(radius, bool) and radius <= 0:
        return f"sphere_radius_mm: must be greater than 0, got {radius}"
    cov = doc.get("covariance")
    if isinstance(cov, list):
        n = 10 if doc.get("radius_fitted") is True else 9
        if len(cov) != n or not all(isinstance(r, list) and len(r) == n for r in cov):
            return (f"covariance: expected a {n} x {n} matrix (rotation, translation, sphere centre"
                    f"{', radius' if n == 10 else ''}), got {len(cov)} rows")
    if isinstance(cov, list) and all(isinstance(r, list) for r in cov):
        for i, row in enumerate(cov):
            if i < len(row) and isinstance(row[i], (int, float)) and row[i] < 0:
                return f"covariance[{i}][{i}]: a variance cannot be negative, got {row[i]}"
    for key, value in (("transform.translation_mm", (doc.get("transform") or {}).get("translation_mm")),
                       ("sphere_centre_mm", doc.get("sphere_centre_mm")),
                       ("sphere_radius_mm", [doc.get("sphere_radius_mm")])):
        if isinstance(value, list):
            for x in value:
                if isinstance(x, (int, float)) and not isinstance(x, bool):
                    try:
                        ok = abs(float(x)) <= MAX_ABS_VALUE
                    except OverflowError:
                        ok = False
                    if not ok:
                        return f"{key}: {x!r:.40} is beyond {MAX_ABS_VALUE:g} mm: not a plausible value (units?)"
    return None


def read_result(path: str | os.PathLike) -> CalibrationResult:
    """Load a result file written by :func:`write_result` (format ``spherecal-result``).
    Raises :class:`DatasetFileError` naming the file and the field at fault; a result
    of a newer format version asks for a newer spherecal."""
    name = os.fspath(path)
    data = _read_bytes(path)
    if not data.removeprefix(b"\xef\xbb\xbf").strip():
        raise DatasetFileError(f"{name}: the file holds no data; expected a spherecal result (one JSON document)")
    from spherecal.io.files import text_encoding_problem

    problem = text_encoding_problem(data)
    if problem:
        raise DatasetFileError(f"{name}: not a spherecal result as written: {problem}")
    data = data.removeprefix(b"\xef\xbb\xbf")
    try:
        doc = json.loads(data)
    except RecursionError:
        raise DatasetFileError(f"{name}: not a spherecal result: nested too deeply") from None
    except ValueError as exc:
        first = data.split(b"\n", 1)[0]
        try:
            is_dataset = json.loads(first).get("format") == DATASET_FORMAT
        except (ValueError, AttributeError):
            is_dataset = False
        if is_dataset:
            raise DatasetFileError(
                f"{name}: not a spherecal result: it is a dataset ({DATASET_FORMAT!r}); give a result.json or a run "
                "folder holding one (spherecal solve makes one from a dataset)"
            ) from None
        raise DatasetFileError(f"{name}: not valid JSON ({exc}); a result file is one JSON document") from None
    if not isinstance(doc, dict) or "format" not in doc:
        raise DatasetFileError(
            f"{name}: not a spherecal result: expected a JSON object with format {RESULT_FORMAT!r}"
        )
    fmt = doc["format"]
    if fmt != RESULT_FORMAT:
        hint = ("; it is a dataset, not a result: give a result.json or a run folder holding one (spherecal solve "
                "makes one from a dataset)") if fmt == DATASET_FORMAT else ""
        raise DatasetFileError(
            f"{name}: not a spherecal result: format is {json.dumps(fmt)}, expected {RESULT_FORMAT!r}{hint}"
        )
    version = doc.get("version")
    if type(version) is not int or version < 1:
        raise DatasetFileError(f"{name}: version must be a whole number >= 1, found {json.dumps(version)}")
    if version > RESULT_VERSION:
        raise DatasetFileError(
            f"{name}: result format version {version} is newer than this spherecal ({__version__}) reads "
            f"(versions 1 to {RESULT_VERSION}); upgrade spherecal to read it"
        )
    bad = _result_number_problem(doc)
    if bad:
        raise DatasetFileError(f"{name}: {bad}")
    try:
        result = CalibrationResult.model_validate_json(data, strict=True)
    except ValidationError as exc:
        raise DatasetFileError(f"{name}: {_describe_validation_error(exc)}") from None
    update = {}
    for key in ("transform", "two_step_transform"):
        pose = getattr(result, key)
        if pose is not None:
            kept = _keep_written_quaternion(pose, doc[key])
            if kept is not pose:
                update[key] = kept
    return result.model_copy(update=update) if update else result
