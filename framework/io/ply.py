"""Streaming PLY point-cloud files: write scans chunk by chunk, read them back.

The writer keeps memory bounded however long the scan: each chunk of vertices goes
straight to the file. PLY puts the vertex count in the header, before the data, so the
header is written with the count in a fixed-width field (the number left-aligned and
padded with spaces to :data:`COUNT_WIDTH` characters, which every whitespace-splitting
PLY parser accepts) and the count is rewritten in place:

- after every chunk (``update_header_every_chunk=True``, the default): the file is
  flushed, then the count of the vertices written so far goes into the header. A writer
  that is interrupted (a crash, a kill, a full disk) leaves a valid file whose header
  counts every completed chunk. At worst, a chunk being written at that moment is
  partly present after the data the header counts; readers ignore it, and
  :func:`recover_ply` takes in every complete vertex found and drops a partial one.
- on :meth:`PlyWriter.close` in every case.

Formats: ``binary_little_endian`` (exact) and ``ascii`` (``%.{precision}g``; the
default precision, 9 digits for float32 and 17 for float64, round-trips exactly).
Vertex properties: ``x y z`` (float or double, mm, in the frame the caller says in the
``frame`` comment), optionally ``intensity`` (float) and ``profile`` (uint, the index of
the profile a point came from).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Literal

import numpy as np

from spherecal.io import files as safeio
from spherecal.core.errors import InputError

PlyFormat = Literal["binary_little_endian", "ascii"]
#: Width of the vertex-count field in the header.
COUNT_WIDTH = 20
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


class PlyWriter:
    """Write vertices to ``path`` chunk by chunk.

    ``with PlyWriter(path, frame="base") as w: w.write(xyz_mm, intensity=..., profile=...)``

    ``dtype``: float32 or float64 coordinates. ``with_intensity`` / ``with_profile``
    declare the optional properties; each :meth:`write` must then pass them."""

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        format: PlyFormat = "binary_little_endian",
        dtype=np.float32,
        with_intensity: bool = False,
        with_profile: bool = False,
        frame: str = "base",
        comments: tuple[str, ...] = (),
        ascii_precision: int | None = None,
        update_header_every_chunk: bool = True,
    ):
        if format not in ("binary_little_endian", "ascii"):
            raise InputError(f"PLY format must be 'binary_little_endian' or 'ascii', got {format!r}")
        dtype = np.dtype(dtype)
        if dtype not in (np.float32, np.float64):
            raise InputError(f"PLY coordinates must be float32 or float64, got {dtype}")
        self.path = Path(path)
        self.format = format
        self.with_intensity = with_intensity
        self.with_profile = with_profile
        self.update_header_every_chunk = update_header_every_chunk
        fields = [("x", dtype), ("y", dtype), ("z", dtype)]
        if with_intensity:
            fields.append(("intensity", np.float32))
        if with_profile:
            fields.append(("profile", np.uint32))
        self.record = np.dtype([(name, np.dtype(t).newbyteorder("<")) for name, t in fields])
        self.precision = ascii_precision or (9 if dtype == np.float32 else 17)
        self.n_written = 0
        coord = "float" if dtype == np.float32 else "double"
        lines = ["ply", f"format {format} 1.0", "comment written by spherecal", f"comment frame {frame}; units mm"]
        lines += [f"comment {c}" for c in comments]
        lines.append("element vertex " + "0".ljust(COUNT_WIDTH))
        lines += [f"property {coord} {a}" for a in "xyz"]
        if with_intensity:
            lines.append("property float intensity")
        if with_profile:
            lines.append("property uint profile")
        lines.append("end_header")
        header = ("\n".join(lines) + "\n").encode("ascii")
        self._count_offset = header.index(b"element vertex ") + len(b"element vertex ")
        self._file = safeio.open_for_write(self.path)
        self._file.write(header)
        self._file.flush()  # a writer killed before its first chunk leaves a valid empty file

    # writing ----------------------------------------------------------------------------
    def write(self, xyz_mm, intensity=None, profile=None) -> None:
        """Append a chunk: ``xyz_mm`` (N, 3); ``intensity`` (N,) and ``profile`` (N,) when
        declared. Rows with a NaN coordinate are skipped (a sensor's invalid points)."""
        if self._file is None:
            raise InputError(f"{self.path}: the PLY writer is closed")
        xyz = np.asarray(xyz_mm)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise InputError(f"{self.path}: write() expects (N, 3) points in mm, got shape {xyz.shape}")
        n = len(xyz)
        extras = {"intensity": (self.with_intensity, intensity), "profile": (self.with_profile, profile)}
        for name, (declared, value) in extras.items():
            if declared and (value is None or np.shape(value) != (n,)):
                raise InputError(f"{self.path}: the file declares '{name}': pass {name}= with shape ({n},)")
            if not declared and value is not None:
                raise InputError(f"{self.path}: '{name}' was not declared; open the writer with with_{name}=True")
        valid = ~np.any(np.isnan(xyz), axis=1)
        rec = np.empty(int(valid.sum()), dtype=self.record)
        rec["x"], rec["y"], rec["z"] = xyz[valid, 0], xyz[valid, 1], xyz[valid, 2]
        if self.with_intensity:
            rec["intensity"] = np.asarray(intensity)[valid]
        if self.with_profile:
            rec["profile"] = np.asarray(profile)[valid]
        try:
            if self.format == "binary_little_endian":
                self._file.write(rec.tobytes())
            else:
                self._file.write(_ascii_rows(rec, self.precision))
            self.n_written += len(rec)
            if self.update_header_every_chunk:
                self._patch_count()
        except OSError as exc:  # a full disk: name the file; what was counted is in it
            from spherecal.core.errors import FileWriteError

            raise FileWriteError(f"{self.path}: cannot write ({exc.strerror or exc}); the points before are kept "
                                 "(recover_ply restores a consistent count)") from None

    def _patch_count(self) -> None:
        f = self._file
        f.flush()  # the data first: the header never counts vertices that are not there
        end = f.tell()
        f.seek(self._count_offset)
        f.write(str(self.n_written).ljust(COUNT_WIDTH).encode("ascii"))
        f.seek(end)
        f.flush()

    def close(self) -> None:
        """Write the final count into the header and close the file."""
        if self._file is None:
            return
        self._patch_count()
        self._file.close()
        self._file = None

    def __enter__(self) -> "PlyWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _ascii_rows(rec: np.ndarray, precision: int) -> bytes:
    cols = []
    for name in rec.dtype.names:
        col = rec[name]
        if col.dtype.kind == "f":
            cols.append(np.char.mod(f"%.{precision}g", col.astype(np.float64)))
        else:
            cols.append(col.astype(np.int64).astype(str))
    if len(rec) == 0:
        return b""
    lines = cols[0]
    for c in cols[1:]:
        lines = np.char.add(np.char.add(lines, " "), c)
    return ("\n".join(lines.tolist()) + "\n").encode("ascii")


# reading ------------------------------------------------------------------------------
class PlyHeader:
    """What :func:`read_ply_header` found: format, vertex count, record dtype, comments."""

    def __init__(self, format: str, vertex_count: int, record: np.dtype, comments: list[str], data_offset: int):
        self.format = format
        self.vertex_count = vertex_count
        self.record = record
        self.comments = comments
        self.data_offset = data_offset


def read_ply_header(path: str | os.PathLike) -> PlyHeader:
    """Parse the header of a PLY file with one ``vertex`` element of scalar properties."""
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0:
        raise InputError(f"{path}: not a PLY file (no 'ply' / 'end_header' lines)")
    fmt, count, props, comments = None, None, [], []
    for line in head[:end].decode("ascii", "replace").splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "comment":
            comments.append(line[len("comment ") :])
        elif words[0] == "element":
            if words[1] != "vertex":
                raise InputError(f"{path}: element {words[1]!r} is not supported (vertex only)")
            count = int(words[2])
        elif words[0] == "property":
            if words[1] == "list" or words[1] not in _PLY_TYPES:
                raise InputError(f"{path}: property {' '.join(words[1:])!r} is not supported (scalar types only)")
            props.append((words[2], "<" + _PLY_TYPES[words[1]]))
    if fmt not in ("binary_little_endian", "ascii") or count is None:
        raise InputError(f"{path}: format {fmt!r} or vertex count missing or unsupported")
    return PlyHeader(fmt, count, np.dtype(props), comments, end + len(b"end_header\n"))


def read_ply(path: str | os.PathLike) -> np.ndarray:
    """The vertices of a PLY file as a structured array (fields ``x, y, z`` and any others),
    as many as the header counts."""
    h = read_ply_header(path)
    path = Path(path)
    if h.format == "binary_little_endian":
        data = np.fromfile(path, dtype=h.record, count=h.vertex_count, offset=h.data_offset)
    else:
        with open(path, "rb") as f:
            f.seek(h.data_offset)
            table = np.loadtxt(f, dtype=np.float64, max_rows=h.vertex_count, ndmin=2) if h.vertex_count else None
        n = 0 if table is None else len(table)
        data = np.empty(n, dtype=h.record)
        for k, name in enumerate(h.record.names):
            if n:
                data[name] = table[:, k]
    if len(data) < h.vertex_count:
        raise InputError(
            f"{path}: the header counts {h.vertex_count} vertices but only {len(data)} are present; "
            "the file is truncated (recover_ply() rewrites the count to what is there)"
        )
    return data


def recover_ply(path: str | os.PathLike) -> int:
    """Make the header of a file left by an interrupted writer count every complete vertex
    present (a partial last vertex is cut off); returns the count. Safe on a good file."""
    path = Path(path)
    h = read_ply_header(path)
    size = path.stat().st_size
    if h.format == "binary_little_endian":
        n = (size - h.data_offset) // h.record.itemsize
        end = h.data_offset + n * h.record.itemsize
    else:
        with open(path, "rb") as f:
            f.seek(h.data_offset)
            body = f.read()
        n_fields = len(h.record.names)
        n, end = 0, h.data_offset
        pos = 0
        for m in re.finditer(rb"[^\n]*\n", body):
            if len(m.group().split()) != n_fields:
                break
            n += 1
            pos = m.end()
        end = h.data_offset + pos
    with open(path, "r+b") as f:
        head = f.read(h.data_offset)
        start = head.index(b"element vertex ") + len(b"element vertex ")
        stop = head.index(b"\n", start)
        width = stop - start
        text = str(n).ljust(width).encode("ascii")
        if len(text) > width:
            raise InputError(f"{path}: the count {n} does not fit the header's {width}-character field")
        f.seek(start)
        f.write(text)
        f.truncate(end)
    return n
