"""The calibration-result file: one pretty-printed JSON document, format
``spherecal-result`` (docs/file-formats.md). :func:`write_result` writes it whole under a
temporary name and renames it into place; :func:`read_result` checks it field by field."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from spherecal import __version__
from spherecal.core.errors import DatasetFileError, FileWriteError, InputError
from spherecal.core.models import CalibrationResult
from spherecal.core.validation_errors import validation_error_lines
from spherecal.io.files import text_encoding_problem
from spherecal.io.json_files import (
    DATASET_FORMAT,
    MAX_ABS_VALUE,
    RESULT_FORMAT,
    atomic_temporary,
    fsync_dir,
    json_safe,
    keep_written_quaternion,
    read_bytes,
)

__all__ = ["RESULT_FORMAT", "RESULT_VERSION", "read_result", "write_result"]

#: Newest result format version this module reads and the one it writes. Version 2 adds
#: the centre observations' figures to ``residuals``; version 3 adds
#: ``robot_error.point_error_nominal_arm_k2_mm``.
RESULT_VERSION = 3


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
    doc = json_safe(result.model_dump(mode="python"), "")
    text = _pretty(doc, 0) + "\n"
    tmp = atomic_temporary(path, overwrite)
    try:
        with open(tmp, "xb") as f:
            f.write(text.encode("utf-8"))
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
        if fsync:
            fsync_dir(path)
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
    data = read_bytes(path)
    if not data.removeprefix(b"\xef\xbb\xbf").strip():
        raise DatasetFileError(f"{name}: the file holds no data; expected a spherecal result (one JSON document)")
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
        raise DatasetFileError(f"{name}: {'; '.join(validation_error_lines(exc, model=CalibrationResult))}") from None
    update = {}
    for key in ("transform", "two_step_transform"):
        pose = getattr(result, key)
        if pose is not None:
            kept = keep_written_quaternion(pose, doc[key])
            if kept is not pose:
                update[key] = kept
    return result.model_copy(update=update) if update else result
