"""Writing stream recordings (the dataset format's stream form, version 3;
docs/file-formats.md): :class:`RecordingWriter` appends as an acquisition measures,
:func:`write_recording` writes a whole :class:`~spherecal.core.streams.Recording`.
:mod:`spherecal.io.streams` reads them back."""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from spherecal import __version__
from spherecal.core.errors import DatasetFileError, FileWriteError, InputError
from spherecal.core.streams import POSES_ASSUMED_KEY, Recording, SweepInfo
from spherecal.io.json_files import DATASET_FORMAT, MAX_ABS_VALUE, atomic_temporary, fsync_dir, json_safe
from spherecal.io.observation_line import FieldError

try:  # the fast serialiser (a dependency; the standard library is the fallback)
    import orjson as _orjson
except ImportError:  # pragma: no cover
    _orjson = None

from spherecal.io.stream_fields import (
    STREAM_VERSION,
    STREAM_FORM,
    POSES_PER_LINE,
    _b64encode,
    _check_mounting_radius,
    _check_clocks,
    _check_sweep,
    _item,
    _within_limit,
    _check_quaternions,
    _check_stamps,
)


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

    @classmethod
    def _continuing(cls, path: Path, fsync: bool, state: dict[str, Any]) -> "RecordingWriter":
        """A writer appending to the recording at ``path``, whose header and lines were
        read into ``state`` (:func:`spherecal.io.streams.reopen_recording`)."""
        self = cls.__new__(cls)
        self.path, self.fsync = Path(path), bool(fsync)
        self.clocks, self.sweeps = state["clocks"], list(state["sweeps"])
        for k in ("_last_pose_t", "_last_profile_t", "_n_joints", "_has_seq", "_has_frame", "_has_sweep",
                  "n_pose_samples", "n_profiles"):
            setattr(self, k, state[k])
        try:
            self._file = open(self.path, "ab")
        except OSError as exc:
            raise FileWriteError(f"{os.fspath(path)}: cannot write ({exc.strerror or exc})") from None
        return self

    # -- poses ---------------------------------------------------------------------------

    def add_poses(self, t_robot_s, translation_mm, quaternion_wxyz, joints_deg=None, seq=None) -> None:
        """Append pose samples: robot-clock stamps (n,) s, base_from_flange translations
        (n, 3) mm and quaternions (n, 4) **(w, x, y, z)**, joints (n, J) deg and the
        controller's sequence numbers (n,) if it sends them (give them on every call or
        on none). Written in lines of at most :data:`POSES_PER_LINE` samples."""
        name = os.fspath(self.path)
        try:
            # contiguous copies where needed: the JSON encoder takes C-ordered arrays only
            t = np.ascontiguousarray(np.atleast_1d(np.asarray(t_robot_s, dtype=float)))
            n = len(t)
            tr = np.ascontiguousarray(translation_mm, dtype=float).reshape(n, 3) if n else np.zeros((0, 3))
            q = np.ascontiguousarray(quaternion_wxyz, dtype=float).reshape(n, 4) if n else np.zeros((0, 4))
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
    existing file is replaced only with ``overwrite=True``. A pose stream that was not
    measured keeps its ``assumption`` in the provenance (``poses_assumed``)."""
    path = Path(path)
    tmp = atomic_temporary(path, overwrite)
    provenance = recording.provenance
    if recording.poses.assumption and POSES_ASSUMED_KEY not in provenance:
        provenance = {**provenance, POSES_ASSUMED_KEY: recording.poses.assumption}
    try:
        with RecordingWriter(tmp, mounting=recording.mounting, sphere_radius_mm=recording.sphere_radius_mm,
                             clocks=recording.clocks, sweeps=recording.sweeps, provenance=provenance) as out:
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


