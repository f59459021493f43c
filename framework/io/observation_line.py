"""One observation as one line of a dataset file (JSON) and back. Every number is
checked on the way in (a string, a boolean or an implausible size is refused, naming the
field); what is written reads back bit for bit."""

from __future__ import annotations

import json
import math
from datetime import datetime
from typing import Any

import numpy as np
from pydantic import ValidationError

from spherecal.core.errors import InputError
from spherecal.core.models import Observation
from spherecal.core.validation_errors import validation_error_lines
from spherecal.io.json_files import MAX_ABS_VALUE, keep_written_quaternion, within_limit

try:  # optional accelerator: parses full-precision floats about 7x faster than json
    import orjson as _orjson
except ImportError:  # pragma: no cover - exercised only where orjson is missing
    _orjson = None

#: Observation fields that need format version 2.
VERSION_2_FIELDS = ("circle", "sphere_centre_mm", "sphere_centre_covariance_mm2")
_OBSERVATION_KIND = "observation"


class FieldError(Exception):
    """A problem with one field of one line; turned into a DatasetFileError by the caller."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}" if field else message)


def loads_json(raw: bytes) -> Any:
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


def parse_timestamp(value: Any) -> datetime:
    if isinstance(value, datetime):
        ts = value
    elif isinstance(value, str):
        try:
            ts = datetime.fromisoformat(value)
        except ValueError:
            raise FieldError("timestamp", f"{value!r} is not an ISO 8601 date and time") from None
    else:
        raise FieldError("timestamp", f"expected an ISO 8601 string, got {value!r}")
    if ts.tzinfo is None or ts.utcoffset() is None:
        raise FieldError(
            "timestamp", f"{value!r} has no time zone; write it with one (UTC: end it with 'Z' or '+00:00')"
        )
    return ts


def _number_array(value: Any, field: str) -> np.ndarray:
    """A JSON list of numbers as a float array, refusing strings, booleans and nulls
    (which NumPy would otherwise convert, or keep as objects)."""
    if not isinstance(value, list):
        raise FieldError(field, f"expected a list of numbers, got {type(value).__name__} {value!r:.60}")
    try:
        arr = np.asarray(value)
    except ValueError:
        raise FieldError(field, "expected a flat list of numbers, got nested lists of unequal length") from None
    kind = arr.dtype.kind
    if kind in "fiu" and arr.size and arr.ndim == 1:
        with np.errstate(invalid="ignore", over="ignore"):
            a = arr.astype(float)
            big = np.flatnonzero(np.isfinite(a) & (np.abs(a) > MAX_ABS_VALUE))  # NaN, inf: the model says
        if big.size:
            i = int(big[0])
            raise FieldError(field, f"item {i} is {float(arr[i])!r}: beyond {MAX_ABS_VALUE:g} mm, not a "
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
                raise FieldError(field, f"expected a flat list of numbers, item {i} is a list")
            shown = "null" if v is None else json.dumps(v) if isinstance(v, (bool, str)) else repr(v)
            raise FieldError(field, f"must hold only numbers; item {i} is {shown} ({type(v).__name__})")
        if not within_limit(v):
            raise FieldError(field, f"item {i} is {v!r:.40}: not a finite number of at most {MAX_ABS_VALUE:g} mm "
                                     "(check the units)")
    return np.asarray(value, dtype=float)


def _small_numbers(value: Any, field: str) -> Any:
    """Poses and joint readings: JSON lists -> tuples (what the strict model expects)."""
    if isinstance(value, list):
        for i, v in enumerate(value):
            if type(v) is bool or not isinstance(v, (int, float)):
                raise FieldError(field, f"must hold only numbers; item {i} is {json.dumps(v)}")
            if not within_limit(v):
                raise FieldError(field, f"item {i} is {v!r:.40}: not a finite number of at most {MAX_ABS_VALUE:g} "
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


def _scalar_number(value: Any, field: str) -> Any:
    """One JSON number, finite and at most MAX_ABS_VALUE (null passes: the model says
    whether it may be absent)."""
    if value is None:
        return value
    if type(value) is bool or not isinstance(value, (int, float)):
        shown = json.dumps(value) if isinstance(value, (str, bool)) else repr(value)
        raise FieldError(field, f"must be a number, got {shown:.40}")
    if not within_limit(value):
        raise FieldError(field, f"{value!r:.40} is not a finite number of at most {MAX_ABS_VALUE:g} (check the units)")
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
            raise FieldError(field, "expected a 3x3 matrix: a list of 3 rows of 3 numbers, mm^2")
        data[field] = tuple(_small_numbers(row, f"{field}[{i}]") for i, row in enumerate(cov))


def observation_from_json(obj: Any, version: int) -> Observation:
    """The observation one line holds (parsed JSON) in a file of format ``version``;
    :class:`FieldError` naming the field at fault."""
    if not isinstance(obj, dict):
        raise FieldError("", f"expected a JSON object, got {type(obj).__name__}")
    if "format" in obj and "kind" not in obj:
        raise FieldError(
            "", f"a second header (format {obj.get('format')!r}); two files were joined into one? "
            "Keep one dataset per file"
        )
    data = dict(obj)
    kind = data.pop("kind", None)
    if kind != _OBSERVATION_KIND:
        raise FieldError("kind", f"expected 'observation', got {json.dumps(kind)}")
    if "timestamp" not in data:
        raise FieldError("timestamp", "missing (required in files: ISO 8601 with a time zone)")
    data["timestamp"] = parse_timestamp(data["timestamp"])
    if data.get("base_from_flange") is not None:
        data["base_from_flange"] = _pose_input(data["base_from_flange"], "base_from_flange")
    if data.get("joints_deg") is not None:
        data["joints_deg"] = _small_numbers(data["joints_deg"], "joints_deg")
    if version < 2:
        late = [k for k in VERSION_2_FIELDS if k in data]
        if late:
            raise FieldError(late[0], f"needs dataset format version 2 (the header says version {version}): "
                                       "write \"version\": 2 on line 1")
        if "profile" not in data:
            raise FieldError("profile", "missing (required in version 1 files)")
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
        raise FieldError("", "; ".join(validation_error_lines(exc, model=Observation))) from None
    if obs.base_from_flange is not None:
        pose = keep_written_quaternion(obs.base_from_flange, obj["base_from_flange"])
        if pose is not obs.base_from_flange:
            obs = obs.model_copy(update={"base_from_flange": pose})
    return obs


def observation_line(obs: Observation) -> bytes:
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
