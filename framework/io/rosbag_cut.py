"""A rosbag2 storage file cut short (a recording interrupted: the recorder killed, the
disk full, the computer off) told apart from other damage, so that the error says so and
names the tools that repair it, instead of the storage library's own words ("File end
magic is invalid.", "database disk image is malformed").

- MCAP: a complete file begins and ends with the magic bytes; a cut one begins with them
  and ends anywhere else (its footer and summary missing). ``mcap recover`` (the mcap
  CLI) rebuilds a file from its whole chunks.
- SQLite (``.db3``): the header declares the page size and the database's size in pages;
  a file shorter than that (or not a whole number of pages) lost its end. SQLite's
  ``.recover`` copies the readable rows into a new database.

Either way ``ros2 bag reindex`` then writes the bag folder's ``metadata.yaml`` anew.
"""

from __future__ import annotations

from pathlib import Path
from struct import unpack_from

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SQLITE_MAGIC = b"SQLite format 3\x00"


def _storage_files(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file())
    return []


def _mcap_cut(path: Path) -> str | None:
    size = path.stat().st_size
    with open(path, "rb") as f:
        if f.read(8) != _MCAP_MAGIC:
            return None  # not an MCAP file at all: the reader's own message says so
        f.seek(max(size - 8, 8))
        if f.read(8) == _MCAP_MAGIC:
            return None
    return f"{path} ends after {size} bytes without the MCAP end magic (its footer and summary are missing)"


def _sqlite_cut(path: Path) -> str | None:
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(100)
    if len(head) < 100 or not head.startswith(_SQLITE_MAGIC):
        return None
    (page_bytes,) = unpack_from(">H", head, 16)
    page_bytes = 65536 if page_bytes == 1 else page_bytes
    change_counter, pages = unpack_from(">II", head, 24)
    (valid_for,) = unpack_from(">I", head, 92)
    declared = pages * page_bytes if valid_for == change_counter and pages else 0
    if size < declared:
        return f"{path} holds {size} bytes of the {declared} its SQLite header declares ({pages} pages)"
    if page_bytes and size % page_bytes:
        return f"{path} holds {size} bytes, not a whole number of its {page_bytes}-byte SQLite pages"
    return None


def cut_short(path: Path) -> tuple[str, str] | None:
    """(what is missing, what repairs it) when a storage file of the bag at ``path`` (a
    bag folder, or one ``.mcap`` or ``.db3`` file) looks cut short; None otherwise."""
    folder = path if path.is_dir() else None
    for file in _storage_files(path):
        try:
            if file.suffix == ".mcap":
                found, repair = _mcap_cut(file), (f"`mcap recover {file} -o recovered.mcap` (the mcap CLI) rebuilds "
                                                  "it from its whole chunks")
            else:
                found, repair = _sqlite_cut(file), (f"`sqlite3 {file} .recover | sqlite3 recovered.db3` copies its "
                                                    "readable rows into a new file")
        except OSError:
            continue
        if found is None:
            continue
        if folder is None and (file.parent / "metadata.yaml").is_file():
            folder = file.parent  # a file of a bag folder, given alone
        if folder is not None:
            repair += (f"; put the repaired file in the cut one's place and rewrite the folder's metadata.yaml with "
                       f"`ros2 bag reindex {folder}`")
        return found, repair
    return None


def cut_short_text(path: Path, name: str, library_says: str) -> str | None:
    """The error text for a bag that looks cut short, naming the file and the repair;
    None when no storage file of it does."""
    cut = cut_short(path)
    if cut is None:
        return None
    found, repair = cut
    return (f"{name}: the bag looks cut short (a recording interrupted): {found}. Repair it: {repair} "
            f"(the storage library says: {library_says})")
