"""What makes a report one can sign and keep: its version, the SIMULATED mark, the
provenance as a table.

- **Versions.** The calibration writes ``report.html`` (version 1). A later report of the
  same calibration (``spherecal validate``) is a new file, ``report-2.html``,
  ``report-3.html``, ..., never a rewrite: each says which version it supersedes (with
  that file's SHA-256) and what it adds to the calibration's report, so a report once
  signed stays as it was signed (:func:`report_versions`, :func:`next_version`).
- **A simulated run** (the result's provenance says ``simulated``, or its data come from
  spherecal's simulator) carries a banner at the top and a mark repeated on every printed
  page (``position: fixed``) and in the page's title (:func:`is_simulated`).
- **Provenance** is shown as rows of a table, nested entries flattened into labelled rows
  (:func:`provenance_rows`), not as JSON.
"""

from __future__ import annotations

import html
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spherecal.io.files import sha256_of
from spherecal.report import export

#: The calibration's own report: version 1.
REPORT_NAME = "report.html"
_LATER_VERSION = re.compile(r"report-([1-9][0-9]*)\.html")
#: Where the data of a result come from when spherecal's simulator made them (the
#: provenance's ``dataset``, from the simulated dataset's ``source``).
SIMULATOR_SOURCE = "spherecal simulator"


@dataclass(frozen=True)
class ReportVersion:
    """A report's place among the reports of one calibration: its ``number`` (1: the
    calibration's own ``report.html``), what it ``added`` to the calibration's report (one
    sentence), and the file name and SHA-256 of the version it ``supersedes`` (None for
    the first)."""

    number: int
    added: str = ""
    supersedes: str | None = None
    supersedes_sha256: str | None = None

    @property
    def filename(self) -> str:
        return version_filename(self.number)


#: The version the calibration writes.
CALIBRATION_VERSION = ReportVersion(1)


def version_filename(number: int) -> str:
    """``report.html`` for version 1, ``report-<number>.html`` after it."""
    if number < 1:
        raise ValueError(f"a report version is a number from 1, got {number}")
    return REPORT_NAME if number == 1 else f"report-{number}.html"


def report_versions(out: Path) -> dict[int, Path]:
    """The calibration reports in folder ``out`` by version number, lowest first."""
    out = Path(out)
    found = {1: out / REPORT_NAME} if (out / REPORT_NAME).is_file() else {}
    if out.is_dir():
        for path in out.glob("report-*.html"):
            match = _LATER_VERSION.fullmatch(path.name)
            if match and int(match.group(1)) >= 2 and path.is_file():
                found[int(match.group(1))] = path
    return dict(sorted(found.items()))




def next_version(out: Path, added: str, after: int | None = None) -> ReportVersion:
    """The next report version in ``out``: one above the highest there (at least 2: a
    later report never takes the calibration's ``report.html``), superseding the highest
    with its SHA-256; ``after``: at least one above this number too (a name taken since)."""
    versions = report_versions(out)
    latest = max(versions, default=None)
    number = max(2, (latest or 1) + 1, (after or 0) + 1)
    previous = versions.get(latest) if latest is not None else None
    return ReportVersion(number, added, previous.name if previous else None,
                         sha256_of(previous) if previous else None)


def version_html(version: ReportVersion) -> str:
    """Which version the report is, which it supersedes and what it adds."""
    if version.number == 1:
        return ('<p class="version" id="version">Report version 1, as the calibration wrote it. A later report of this '
                "calibration (a validation's) is written beside it as report-2.html, report-3.html, ... and never "
                "rewrites this file.</p>")
    if version.supersedes is None:
        before = f"No earlier report of this calibration was found beside it (the calibration wrote no {REPORT_NAME})."
    else:
        before = (f"It supersedes <code>{_e(version.supersedes)}</code> (SHA-256 <code class=\"hash\">"
                  f"{_e(version.supersedes_sha256 or '')}</code>), which stays as it was written.")
    return (f'<div class="version" id="version"><b>Report version {version.number}</b> of this calibration. {before} '
            f"Added to the calibration's report ({REPORT_NAME}, version 1): {_e(version.added)}</div>")


# --- a simulated run -------------------------------------------------------------------------------
def is_simulated(provenance: Mapping[str, Any] | None) -> bool:
    """Whether a result's provenance says its data are simulated: ``simulated`` true (the
    devices were simulated), or the data come from spherecal's simulator."""
    p = provenance or {}
    return p.get("simulated") is True or str(p.get("dataset") or "").startswith(SIMULATOR_SOURCE)


def simulated_html() -> str:
    """The SIMULATED banner (top of the page) and mark (fixed: on screen wherever one
    scrolls, and on every printed page)."""
    return ('<div class="simulated-banner" id="simulated"><b>SIMULATED</b>: the data of this calibration come from '
            "spherecal's simulated cell, not from a real robot and sensor. It calibrates no real cell: do not sign it "
            "as one.</div>"
            '<div class="simulated-mark" aria-hidden="true">SIMULATED</div>')


# --- provenance as a table -------------------------------------------------------------------------
#: Unit endings of provenance keys, and how a label says them.
_UNIT_SUFFIXES = (("_sha256", " (SHA-256)"), ("_mm_k2", " (mm, k = 2)"), ("_mm", " (mm)"), ("_deg", " (deg)"),
                  ("_ms", " (ms)"), ("_s", " (s)"))


def provenance_label(key: str) -> str:
    """``radius_uncertainty_mm_k2`` -> ``radius uncertainty (mm, k = 2)``."""
    for suffix, unit in _UNIT_SUFFIXES:
        if key.endswith(suffix) and len(key) > len(suffix):
            return key[: -len(suffix)].replace("_", " ") + unit
    return key.replace("_", " ")


def provenance_value_html(key: str, value: Any) -> str:
    """One provenance value as table text: a dash for none, yes / no, millimetres with the
    exports' decimals, a list joined by commas."""
    if value is None or value == "" or value == [] or value == {}:
        return "&ndash;"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return export.fixed(value, export.MM_DECIMALS) if key.endswith(("_mm", "_mm_k2")) else f"{value:g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(provenance_value_html(key, v) for v in value)
    if key.endswith("_sha256"):
        return f'<code class="hash">{_e(value)}</code>'
    return _e(value)


def provenance_rows(provenance: Mapping[str, Any] | None, leave_out: tuple[str, ...] = ()) -> list[tuple[str, str]]:
    """The provenance as (label, HTML value) rows in its order, nested mappings flattened
    (``robot: serial number``); keys in ``leave_out`` are left out (shown elsewhere)."""
    rows: list[tuple[str, str]] = []

    def add(prefix: str, mapping: Mapping[str, Any]) -> None:
        for key, value in mapping.items():
            label = f"{prefix}{provenance_label(str(key))}"
            if isinstance(value, Mapping) and value:
                add(f"{label}: ", value)
            else:
                rows.append((_e(label), provenance_value_html(str(key), value)))

    add("", {k: v for k, v in (provenance or {}).items() if k not in leave_out})
    return rows


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)
