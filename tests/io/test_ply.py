"""Streaming PLY writer and reader: round trips, header count, interrupted writers."""

import subprocess
import sys

import numpy as np
import pytest

from spherecal.core.errors import InputError
from spherecal.io.ply import COUNT_WIDTH, PlyWriter, read_ply, read_ply_header, recover_ply


def _chunks(rng, sizes, dtype=np.float32):
    return [rng.uniform(-1500, 1500, (k, 3)).astype(dtype) for k in sizes]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_binary_round_trip_in_chunks_is_exact(tmp_path, dtype):
    rng = np.random.default_rng(0)
    chunks = _chunks(rng, [100, 0, 1, 2500], dtype)
    intens = [rng.uniform(0, 1, len(c)).astype(np.float32) for c in chunks]
    path = tmp_path / "scan.ply"
    with PlyWriter(path, dtype=dtype, with_intensity=True, with_profile=True) as w:
        for i, (c, a) in enumerate(zip(chunks, intens)):
            w.write(c, intensity=a, profile=np.full(len(c), i))
    data = read_ply(path)
    xyz = np.concatenate(chunks)
    assert read_ply_header(path).vertex_count == len(xyz) == len(data)
    np.testing.assert_array_equal(np.column_stack([data["x"], data["y"], data["z"]]), xyz)
    assert data["x"].dtype == dtype
    np.testing.assert_array_equal(data["intensity"], np.concatenate(intens))
    np.testing.assert_array_equal(data["profile"], np.repeat(np.arange(4), [100, 0, 1, 2500]))
    # the file is exactly header + records: nothing else was written
    h = read_ply_header(path)
    assert path.stat().st_size == h.data_offset + len(xyz) * h.record.itemsize


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_ascii_round_trip_default_precision_is_exact(tmp_path, dtype):
    rng = np.random.default_rng(1)
    chunks = _chunks(rng, [50, 70], dtype)
    path = tmp_path / "scan.ply"
    with PlyWriter(path, format="ascii", dtype=dtype, with_profile=True) as w:
        for i, c in enumerate(chunks):
            w.write(c, profile=np.full(len(c), i))
    data = read_ply(path)
    np.testing.assert_array_equal(np.column_stack([data["x"], data["y"], data["z"]]), np.concatenate(chunks))
    np.testing.assert_array_equal(data["profile"], np.repeat([0, 1], [50, 70]))


def test_ascii_with_fewer_digits_matches_to_the_printed_precision(tmp_path):
    xyz = np.random.default_rng(2).uniform(-1500, 1500, (200, 3))
    path = tmp_path / "scan.ply"
    with PlyWriter(path, format="ascii", dtype=np.float64, ascii_precision=6) as w:
        w.write(xyz)
    data = read_ply(path)
    got = np.column_stack([data["x"], data["y"], data["z"]])
    # 6 significant digits: relative error at most half a unit in the 6th digit
    assert np.all(np.abs(got - xyz) <= 0.5e-5 * np.abs(xyz) + 1e-12)
    assert np.any(got != xyz)


def test_nan_points_are_skipped_and_counted_out(tmp_path):
    xyz = np.arange(30, dtype=np.float64).reshape(10, 3)
    xyz[[2, 7], 1] = np.nan
    path = tmp_path / "scan.ply"
    with PlyWriter(path, dtype=np.float64) as w:
        w.write(xyz)
    assert w.n_written == 8
    data = read_ply(path)
    np.testing.assert_array_equal(data["x"], np.delete(xyz[:, 0], [2, 7]))


def test_header_count_field_is_fixed_width_and_patched_in_place(tmp_path):
    path = tmp_path / "scan.ply"
    w = PlyWriter(path)
    header_len = read_ply_header(path).data_offset
    assert f"element vertex {'0'.ljust(COUNT_WIDTH)}\n".encode() in path.read_bytes()[:header_len]
    w.write(np.zeros((12345, 3)))
    w.close()
    assert read_ply_header(path).data_offset == header_len
    assert read_ply_header(path).vertex_count == 12345


_INTERRUPTED = """
import os, sys
import numpy as np
from spherecal.io.ply import PlyWriter
w = PlyWriter(sys.argv[1], format=sys.argv[2], dtype=np.float64)
for i in range(3):
    w.write(np.full((1000, 3), float(i)))
w._file.write(b"1.5 2.5" if sys.argv[2] == "ascii" else b"\\x01" * 11)  # a chunk cut short
w._file.flush()
os._exit(0)  # killed: no close()
"""


@pytest.mark.parametrize("fmt", ["binary_little_endian", "ascii"])
def test_interrupted_writer_leaves_a_readable_file_and_recover_trims_it(tmp_path, fmt):
    path = tmp_path / "scan.ply"
    subprocess.run([sys.executable, "-c", _INTERRUPTED, str(path), fmt], check=True, timeout=60)
    # the header counts the completed chunks; the partial one after them is ignored
    data = read_ply(path)
    assert len(data) == 3000
    np.testing.assert_array_equal(data["x"], np.repeat([0.0, 1.0, 2.0], 1000))
    assert recover_ply(path) == 3000
    assert read_ply_header(path).vertex_count == 3000
    h = read_ply_header(path)
    if fmt == "binary_little_endian":
        assert path.stat().st_size == h.data_offset + 3000 * h.record.itemsize
    else:
        assert path.read_bytes().endswith(b"2 2 2\n")


def test_recover_counts_vertices_a_writer_without_header_updates_left(tmp_path):
    path = tmp_path / "scan.ply"
    w = PlyWriter(path, dtype=np.float64, update_header_every_chunk=False)
    w.write(np.ones((40, 3)))
    w._file.flush()  # data on disk, header still says 0, writer never closed
    assert read_ply_header(path).vertex_count == 0
    assert recover_ply(path) == 40
    assert len(read_ply(path)) == 40
    w._file.close()


def test_misuse_is_reported(tmp_path):
    path = tmp_path / "scan.ply"
    with pytest.raises(InputError, match="format must be 'binary_little_endian' or 'ascii'"):
        PlyWriter(path, format="binary_big_endian")
    w = PlyWriter(path, with_profile=True)
    with pytest.raises(InputError, match=r"declares 'profile': pass profile= with shape \(2,\)"):
        w.write(np.zeros((2, 3)))
    with pytest.raises(InputError, match="'intensity' was not declared"):
        w.write(np.zeros((2, 3)), intensity=np.zeros(2), profile=np.zeros(2))
    with pytest.raises(InputError, match=r"expects \(N, 3\) points in mm"):
        w.write(np.zeros((2, 2)), profile=np.zeros(2))
    w.close()
    with pytest.raises(InputError, match="the PLY writer is closed"):
        w.write(np.zeros((1, 3)), profile=np.zeros(1))
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply\n")
    with pytest.raises(InputError, match="not a PLY file"):
        read_ply(bad)
    # a header that counts more than is there says so and points at recover_ply
    short = tmp_path / "short.ply"
    with PlyWriter(short, dtype=np.float64) as w2:
        w2.write(np.ones((10, 3)))
    short.write_bytes(short.read_bytes()[:-24])
    with pytest.raises(InputError, match="only 9 are present.*recover_ply"):
        read_ply(short)
