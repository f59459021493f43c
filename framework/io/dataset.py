"""Dataset files (the format is specified in docs/file-formats.md).

Datasets are JSON Lines (UTF-8): line 1 is a header object, then one object per
observation (:mod:`spherecal.io.observation_line`). A file grows one observation at a
time (:class:`DatasetWriter` appends a whole line and flushes it, with an optional
``os.fsync``), so an acquisition that is interrupted leaves a file that
:func:`read_dataset` still loads up to its last whole observation, with a
:class:`TruncatedFileWarning` saying what was dropped.

Conventions (docs/conventions.md): lengths in mm, angles in degrees in ``*_deg`` fields,
poses ``A_from_B`` with ``quaternion_wxyz`` scalar first (ABB order), timestamps ISO 8601
with a time zone. Numbers are written at full precision (shortest round-trip form), so a
file read back gives exactly the values that were written.

Public API (the result file's functions are :mod:`spherecal.io.result`'s, named here too)::

    write_dataset(path, dataset)            read_dataset(path) -> Dataset
    DatasetWriter(path, mounting=..., sphere_radius_mm=..., resume=...)
    read_dataset_header(path) -> DatasetHeader
    write_result(path, result)              read_result(path) -> CalibrationResult
"""

from __future__ import annotations

import json
import os
import re
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from spherecal import __version__
from spherecal.core.errors import DatasetFileError, FileWriteError, InputError
from spherecal.core.models import Dataset, MountingMode, Observation
from spherecal.core.validation_errors import validation_error_lines
from spherecal.io.files import check_input, text_encoding_problem
from spherecal.io.json_files import (
    DATASET_FORMAT,
    RESULT_FORMAT,
    atomic_temporary,
    fsync_dir,
    json_safe,
    read_bytes,
)
from spherecal.io.observation_line import FieldError, loads_json, observation_from_json, observation_line, parse_timestamp
from spherecal.io.result import RESULT_VERSION, read_result, write_result

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
    "recording_kind",
    "write_dataset",
    "read_result",
    "write_result",
]

#: Newest dataset format version this module reads and the one it writes. Version 2 adds
#: centre observations (``circle``, ``sphere_centre_mm``) beside ``profile``.
DATASET_VERSION = 2
#: Dataset format version of the stream form (``"form": "stream"``), which
#: :mod:`spherecal.io.streams` reads and writes; :func:`read_dataset` names it and refuses it.
STREAM_DATASET_VERSION = 3
#: Longest line of a dataset file (a profile of 3200 points is about 130 kB).
MAX_LINE_BYTES = 64 << 20


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
    if version == STREAM_DATASET_VERSION and obj.get("form") == "stream":
        raise DatasetFileError(
            f"{name}: a stream recording (dataset format version {version}, form 'stream': a pose stream and a "
            "profile stream on two clocks), not a dataset of observations: read it with "
            "spherecal.io.streams.read_recording (spherecal.io.streams.recording_kind tells the two apart)"
        )
    if version > DATASET_VERSION:
        raise DatasetFileError(
            f"{name}: dataset format version {version} is newer than this spherecal ({__version__}) "
            f"reads (versions 1 to {DATASET_VERSION}); upgrade spherecal to read it"
        )
    data = dict(obj)
    if "created" not in data:
        raise DatasetFileError(f"{where}: created: missing (required)")
    try:
        data["created"] = parse_timestamp(data["created"])
    except FieldError as exc:
        raise DatasetFileError(f"{where}: {str(exc).replace('timestamp', 'created', 1)}") from None
    try:
        header = DatasetHeader.model_validate(data, strict=True)
        # the dataset's own rules on mounting and radius (e.g. a radius in metres)
        Dataset.model_validate(
            {"mounting": header.mounting, "sphere_radius_mm": header.sphere_radius_mm}, strict=True
        )
    except ValidationError as exc:
        raise DatasetFileError(f"{where}: {'; '.join(validation_error_lines(exc, model=DatasetHeader))}") from None
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
            whole = isinstance(loads_json(tail), dict)
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
        header_obj = loads_json(raw0)
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
            obj = loads_json(raw)
        except ValueError as exc:
            raise DatasetFileError(
                f"{name} line {lineno} (byte {off}): not valid JSON ({exc}). Only the last line of a file "
                "may be incomplete (an interrupted write); this one is followed by more lines, so the "
                "file is damaged: repair or remove this line"
            ) from None
        idx = obj.get("index") if isinstance(obj, dict) else None
        where = f"{name} line {lineno}" + (f" (observation {idx})" if type(idx) is int else "")
        try:
            obs = observation_from_json(obj, header.version)
        except FieldError as exc:
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


def read_dataset(path: str | os.PathLike) -> Dataset:
    """Load a dataset file (JSON Lines, docs/file-formats.md).

    Every observation is validated with the rules of :mod:`spherecal.core.models`. An
    incomplete last line (an interrupted write) is dropped with a
    :class:`TruncatedFileWarning`; any other problem raises :class:`DatasetFileError`
    naming the file, the line, the observation index and the field.
    ``provenance`` comes back as JSON types (tuples written become lists)."""
    scan = _scan(path, read_bytes(path))
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
        obj = loads_json(raw)
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
            raise InputError(f"{name}: {'; '.join(validation_error_lines(exc))}") from None
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
            doc = json_safe(self.header.model_dump(mode="python"), "header")
            line = json.dumps(doc, ensure_ascii=False, allow_nan=False, separators=(", ", ": ")) + "\n"
            self._file = open(self.path, "r+b" if exists else "xb")
            self._write(line.encode("utf-8"))
            if self.fsync:
                fsync_dir(self.path)

    def _resume(self, name: str, mounting: str, radius: float) -> DatasetHeader:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", TruncatedFileWarning)
            scan = _scan(self.path, read_bytes(self.path))
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
        line = observation_line(observation)
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


def write_dataset(
    path: str | os.PathLike, dataset: Dataset, *, overwrite: bool = False, fsync: bool = False
) -> None:
    """Write a whole dataset to ``path`` (JSON Lines, docs/file-formats.md).

    The file is written under a temporary name and renamed into place, so ``path``
    never holds a half-written dataset. An existing file is replaced only with
    ``overwrite=True``."""
    path = Path(path)
    tmp = atomic_temporary(path, overwrite)
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
            fsync_dir(path)
    finally:
        if tmp.exists():
            tmp.unlink()


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
    if isinstance(obj, dict) and obj.get("format") == DATASET_FORMAT and obj.get("form") == "stream":
        return "stream"
    return "dataset"

