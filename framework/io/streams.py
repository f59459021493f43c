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
from typing import Any

import numpy as np

from spherecal import __version__
from spherecal.core.errors import DatasetFileError
from spherecal.core.streams import PoseStream, ProfileStream, Recording, SweepInfo
from spherecal.io.dataset import MAX_LINE_BYTES, TruncatedFileWarning
from spherecal.io.files import check_input
from spherecal.io.json_files import DATASET_FORMAT, MAX_ABS_VALUE
from spherecal.io.observation_line import FieldError, loads_json, parse_timestamp

from spherecal.io.stream_fields import (
    STREAM_VERSION,
    STREAM_FORM,
    MAX_STAMP_STEP_S,
    POSES_PER_LINE,
    _HEADER_REQUIRED,
    _HEADER_OPTIONAL,
    _POSE_FIELDS,
    _PROFILE_FIELDS,
    _POINTS_KEY,
    _b64decode,
    _check_mounting_radius,
    _check_clocks,
    _check_sweep,
    _as_numbers,
    _within_limit,
    _check_quaternions,
    _check_stamps,
    PointBuffer,
)
from spherecal.io.dataset import recording_kind
from spherecal.io.stream_writer import RecordingWriter, write_recording

__all__ = [
    "MAX_STAMP_STEP_S",
    "POSES_PER_LINE",
    "STREAM_FORM",
    "STREAM_VERSION",
    "RecordingWriter",
    "TruncatedFileWarning",
    "read_recording",
    "recording_kind",
    "reopen_recording",
    "write_recording",
]


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


def reopen_recording(path: str | os.PathLike, fsync: bool = False) -> RecordingWriter:
    """A :class:`RecordingWriter` that appends to the recording at ``path`` (an
    interrupted acquisition's journal, continued): its lines are read and checked as
    :func:`read_recording` checks them, an incomplete last line (cut by the interruption)
    is dropped from the file with a :class:`TruncatedFileWarning`, and what is appended
    must continue the file (stamps increasing on each clock, the same pose and profile
    fields). It may hold no poses or profiles yet."""
    name = os.fspath(path)
    check_input(path, DatasetFileError, "a stream recording")
    try:
        with open(path, "rb+") as f:
            data = f.read()
            cut = data.rfind(b"\n") + 1
            if cut < len(data):  # a last line without its newline: whole, or cut by the interruption
                try:
                    whole = isinstance(_parse(data[cut:]), dict)
                except ValueError:
                    whole = False
                if whole:
                    f.write(b"\n")
                else:
                    if cut == 0:
                        raise DatasetFileError(f"{name}: the file ends inside its header; nothing to continue")
                    lineno = data.count(b"\n") + 1
                    warnings.warn(f"{name}: line {lineno} is incomplete (the acquisition was "
                                  f"interrupted while writing it): dropped its {len(data) - cut} bytes before "
                                  "continuing", TruncatedFileWarning, stacklevel=2)
                    f.truncate(cut)
    except OSError as exc:
        raise DatasetFileError(f"{name}: cannot read ({exc.strerror or exc})") from None
    reader = _Reader(name)
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        reader.points = PointBuffer(min(size * 3 // 32 + 16, 1 << 26))
        buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            _read_lines(reader, buf, size)
        finally:
            try:
                buf.close()
            except BufferError:  # pragma: no cover - a view held by an error's traceback
                pass
    if reader.header is None:
        raise DatasetFileError(f"{name}: holds no header line; expected a stream recording")
    state = {"clocks": reader.header["clocks"], "sweeps": reader.sweeps, "_last_pose_t": reader.last_pose_t,
             "_last_profile_t": reader.prof_t[-1] if reader.prof_t else None,
             "_n_joints": reader.n_joints if reader.pose_t else None,
             "_has_seq": reader.has_seq if reader.pose_t else None,
             "_has_frame": reader.has_frame if reader.prof_t else None,
             "_has_sweep": reader.has_sweep if reader.prof_t else None,
             "n_pose_samples": sum(len(t) for t in reader.pose_t), "n_profiles": len(reader.prof_t)}
    return RecordingWriter._continuing(path, fsync, state)
