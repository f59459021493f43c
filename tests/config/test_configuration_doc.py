"""docs/configuration.md: every table names each key once (a key listed twice, with two
meanings or defaults, leaves the reader to guess which holds)."""

from collections import Counter
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "configuration.md"


def tables(text: str) -> list[tuple[str, list[str]]]:
    """Each table's heading (the last heading or line before it) and its rows' first cells."""
    found, rows, before = [], None, ""
    for line in text.splitlines():
        if line.startswith("|"):
            if rows is None:
                rows = []
                found.append((before, rows))
            cell = line.split("|")[1].strip()
            if cell and set(cell) - set("-: "):
                rows.append(cell)
        else:
            rows = None
            if line.strip():
                before = line.strip()
    return found


def test_each_table_lists_each_key_once():
    doubled = {head: [k for k, n in Counter(rows[1:]).items() if n > 1]  # rows[0]: the header
               for head, rows in tables(DOC.read_text(encoding="utf-8"))}
    assert {head: keys for head, keys in doubled.items() if keys} == {}
    assert len(tables(DOC.read_text(encoding="utf-8"))) > 5  # the tables were found
