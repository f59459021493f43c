"""The messages of MCAP files read in one pass, for bags that convert at tens of millions
of points a second.

MCAP (mcap.dev/spec) is a sequence of records, each an opcode byte, a little-endian
uint64 length and the content; messages sit in chunk records (possibly compressed) or at
the top level, each naming its channel, and a channel record (topic, id) comes before the
first message on it. :func:`scan_messages` walks the records in file order and hands out
each wanted message's bytes as a zero-copy view of its chunk.

It is a fast path, not a second reader: it answers ``None`` (the caller then reads through
``rosbags``) whenever the files do not look as it expects: a compression it cannot undo,
a record that runs past its chunk, a topic's messages not in log-time order (a reader
hands them out sorted by log time; in file order a recorder that writes as it receives
keeps each topic's in that order), or counts that differ from the bag's own.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from struct import error as struct_error, unpack_from

_MAGIC = b"\x89MCAP0\r\n"
_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER = 0x04, 0x05, 0x06, 0x02


class NotPlain(Exception):
    """The files are not what the fast path reads: the caller reads them another way."""


def _decompressor(name: str):
    """The chunk decompressor for ``name`` (the libraries rosbags itself reads with)."""
    if name == "":
        return None
    if name == "zstd":
        try:
            from compression import zstd
        except ImportError:
            try:
                from backports import zstd
            except ImportError:
                raise NotPlain from None
        return lambda data, size: zstd.decompress(data)
    if name == "lz4":
        try:
            from lz4.frame import decompress
        except ImportError:
            raise NotPlain from None
        return lambda data, size: decompress(data)
    raise NotPlain


def _records(buf, p: int, end: int, topics: dict[int, str], wanted: set[str]):
    """The channel and message records of ``buf[p:end]``: channels into ``topics`` (id ->
    topic); yields the wanted messages as (topic, log time ns, bytes view)."""
    while p < end:
        if p + 9 > end:
            raise NotPlain
        op = buf[p]
        (n,) = unpack_from("<Q", buf, p + 1)
        body, p = p + 9, p + 9 + n
        if p > end:
            raise NotPlain
        if op == _OP_MESSAGE:
            channel, _seq, log_ns = unpack_from("<HIQ", buf, body)
            topic = topics.get(channel)
            if topic is None:
                raise NotPlain  # a message before its channel
            if topic in wanted:
                yield topic, log_ns, buf[body + 22:p]
        elif op == _OP_CHANNEL:
            channel, _schema, k = unpack_from("<HHI", buf, body)
            topics[channel] = bytes(buf[body + 8:body + 8 + k]).decode("utf-8")


def _scan_file(path: Path, wanted: set[str]):
    with open(path, "rb") as f:
        head = f.read(8)
        if head != _MAGIC:
            raise NotPlain
        topics: dict[int, str] = {}
        while True:
            rec = f.read(9)
            if len(rec) < 9:
                raise NotPlain  # no footer: a file cut short
            op = rec[0]
            (n,) = unpack_from("<Q", rec, 1)
            if op == _OP_FOOTER:
                return
            if op == _OP_CHUNK:
                content = f.read(n)
                if len(content) != n:
                    raise NotPlain
                _start, _end, size, _crc, k = unpack_from("<QQQII", content, 0)
                compression = bytes(content[32:32 + k]).decode("ascii", "replace")
                p = 32 + k
                (m,) = unpack_from("<Q", content, p)
                data = memoryview(content)[p + 8:p + 8 + m]
                undo = _decompressor(compression)
                if undo is not None:
                    data = memoryview(undo(bytes(data), size))
                if len(data) != size:
                    raise NotPlain
                yield from _records(data, 0, len(data), topics, wanted)
            elif op in (_OP_CHANNEL, _OP_MESSAGE):
                content = memoryview(f.read(n))
                yield from _records(memoryview(rec + bytes(content)), 0, 9 + n, topics, wanted)
            else:
                f.seek(n, 1)


def scan_messages(files: Iterable[Path], counts: dict[str, int]):
    """Yields every message on the topics of ``counts`` (topic -> the number of messages
    the bag says it has) from the MCAP ``files`` (in recording order) as (topic, log time
    ns, CDR bytes view), each topic's in the order a reader sorting by log time gives.
    Raises :class:`NotPlain` (possibly after some messages) where the files are not read
    this way (see the module docstring): the caller then starts again another way."""
    seen = dict.fromkeys(counts, 0)
    last = dict.fromkeys(counts, -1)
    files = list(files)
    if not files:
        raise NotPlain
    try:
        for path in files:
            for topic, log_ns, raw in _scan_file(Path(path), set(counts)):
                if log_ns < last[topic]:
                    raise NotPlain
                last[topic] = log_ns
                seen[topic] += 1
                yield topic, log_ns, raw
    except (OSError, UnicodeDecodeError, ValueError, IndexError, struct_error):
        raise NotPlain from None
    except Exception as exc:  # a decompressor's own error: the other reader reports it
        if type(exc).__module__.split(".")[0] in ("zstandard", "lz4"):
            raise NotPlain from None
        raise
    if seen != counts:
        raise NotPlain
