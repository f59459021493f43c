"""What the dataset and result files share: their format names, the range of their
numbers, plain JSON values, quaternions kept as written, and replacing a file atomically."""

from __future__ import annotations

import math
import os
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from spherecal.core.errors import DatasetFileError, InputError
from spherecal.core.models import Pose
from spherecal.io.files import read_input

#: ``format`` value on line 1 of every dataset file.
DATASET_FORMAT = "spherecal-dataset"
#: ``format`` value of every result file.
RESULT_FORMAT = "spherecal-result"
#: Largest magnitude of a coordinate (mm) or joint angle (deg) in a file: beyond it the
#: value is not a measurement (and would overflow the fits).
MAX_ABS_VALUE = 1e6


def within_limit(v: int | float) -> bool:
    """A finite number of magnitude at most MAX_ABS_VALUE (a huge int overflows float)."""
    try:
        return abs(float(v)) <= MAX_ABS_VALUE
    except OverflowError:
        return False


def keep_written_quaternion(pose: Pose, raw: Any) -> Pose:
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


def json_safe(value: Any, where: str) -> Any:
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
        return json_safe(value.item(), where)
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist(), where)
    if isinstance(value, BaseModel):
        return json_safe(value.model_dump(mode="python"), where)
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise InputError(f"{where}: key {k!r} is not a string; JSON object keys must be strings")
            out[k] = json_safe(v, f"{where}.{k}" if where else k)
        return out
    if isinstance(value, (list, tuple)):
        return [json_safe(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, Path):
        return str(value)
    raise InputError(f"{where}: a {type(value).__name__} cannot be written to a JSON file")


def fsync_dir(path: Path) -> None:
    """Flush the folder holding ``path`` to disk (its new name survives a power cut)."""
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


def atomic_temporary(path: Path, overwrite: bool) -> Path:
    """The temporary name ``path`` is written under before it is renamed into place;
    :class:`DatasetFileError` when ``path`` exists and ``overwrite`` is false."""
    if path.exists() and not overwrite:
        raise DatasetFileError(f"{os.fspath(path)} already exists; pass overwrite=True to replace it")
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def read_bytes(path: str | os.PathLike) -> bytes:
    """The bytes of a spherecal file, read with the input checks."""
    return read_input(path, DatasetFileError, "a spherecal file")
