"""A report one can sign stays as signed: a later report of a calibration is a new,
numbered file that says what it supersedes and what it adds; a simulated run is marked
on every page; the provenance is a table; the report's numbers have the exports'
decimals; tiles that do not apply to the data are left out."""

import dataclasses
import hashlib
import html
import re

import pytest

from spherecal.app.provenance import traceability
from spherecal.core.errors import InputError
from spherecal.estimation import solve
from spherecal.report.export import xyz_quaternion_text
from spherecal.report.html import CALIBRATION_VERSION, report_versions, write_report, write_report_version
from spherecal.report.html.signing import is_simulated, provenance_rows, version_filename
from spherecal.sim import NoiseModel, SweepPlan, simulate_centre_dataset, simulate_dataset, standard_cell
from reference_sensor import reference_fov

PLAN = SweepPlan(profiles_per_station=6)


@pytest.fixture(scope="module")
def dataset():
    return simulate_dataset(standard_cell("eye_in_hand", seed=5, fov=reference_fov()), PLAN)


def _with_provenance(solution, provenance):
    return dataclasses.replace(solution, result=solution.result.model_copy(update={"provenance": provenance}))


@pytest.fixture(scope="module")
def real_solution(dataset):
    """The simulated data's solution, its provenance a real cell's (no truth, devices real)."""
    prov = {"dataset": "spherecal calibrate", "software": "spherecal test", "calibrated_at": "2026-01-02T03:04:05+00:00",
            "robot": {"type": "abb_irb2400", "serial_number": "R-7", "extra_note": "left arm"}, "simulated": False,
            "dataset_sha256": "ab" * 32, "station_plan": {"stations": 4, "tilt_deg": 30.0},
            "sphere": {"radius_mm": 19.1, "radius_uncertainty_mm_k2": 0.0015}}
    return _with_provenance(solve(dataset), prov)


@pytest.fixture(scope="module")
def simulated_solution(dataset, tmp_path_factory):
    path = tmp_path_factory.mktemp("ds") / "sim.jsonl"
    from spherecal.io import dataset as dataio

    dataio.write_dataset(path, dataset)
    return _with_provenance(solve(dataset), traceability(dataset, path))


def _text(page: str) -> str:
    page = re.sub(r'src="data:image/png;base64,[^"]*"', "", page)
    page = re.sub(r"<(style|script)[^>]*>.*?</\1>", "", page, flags=re.DOTALL)
    return html.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page)))


# --- versions ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_later_report_is_a_new_numbered_version_and_the_calibrations_is_left_as_it_was(real_solution, tmp_path):
    first = write_report(real_solution, tmp_path, version=CALIBRATION_VERSION)
    assert first.name == "report.html" and "Report version 1, as the calibration wrote it" in _text(first.read_text())
    signed = first.read_bytes()
    pngs = {p.name: p.read_bytes() for p in tmp_path.glob("report_*.png")}

    second = write_report_version(real_solution, tmp_path, "the validation of today (validation-1.json): FAILED.",
                                  validation={"P_S": {"max error (mm)": 0.08, "MPE (mm)": 0.06, "passed": False}})
    third = write_report_version(real_solution, tmp_path, "the validation of tomorrow (validation-2.json): passed.")
    assert (second.name, third.name) == ("report-2.html", "report-3.html")
    assert first.read_bytes() == signed  # the signed report, byte for byte
    assert {p.name: p.read_bytes() for p in tmp_path.glob("report_*.png")} == pngs
    assert (tmp_path / "report-2_sphere_3d.png").is_file()  # each version's figures beside it, its own names
    text2, text3 = _text(second.read_text()), _text(third.read_text())
    assert (f"Report version 2 of this calibration. It supersedes report.html (SHA-256 "
            f"{hashlib.sha256(signed).hexdigest()} ), which stays as it was written.") in text2
    assert "Added to the calibration's report (report.html, version 1): the validation of today" in text2
    assert f"It supersedes report-2.html (SHA-256 {hashlib.sha256(second.read_bytes()).hexdigest()} )" in text3
    assert "the validation of tomorrow (validation-2.json): passed." in text3
    assert list(report_versions(tmp_path)) == [1, 2, 3]


def test_a_version_never_takes_a_name_already_there(real_solution, tmp_path, monkeypatch):
    """A report-<n>.html already there (an earlier version, or one written since the
    versions were listed) is never overwritten: the next free number is taken."""
    from spherecal.report.html import page, signing

    (tmp_path / "report-4.html").write_text("version 4, signed")
    listed = signing.report_versions

    def stale(out):  # lists the folder as it was before report-5.html appeared
        return {k: v for k, v in listed(out).items() if k != 5}

    (tmp_path / "report-5.html").write_text("written since")
    monkeypatch.setattr(signing, "report_versions", stale)
    monkeypatch.setattr(page, "write_report", lambda solution, out, **kw: out / kw["filename"])
    path = write_report_version(real_solution, tmp_path, "a test")
    assert path.name == "report-6.html"
    assert (tmp_path / "report-4.html").read_text() == "version 4, signed"
    assert (tmp_path / "report-5.html").read_text() == "written since"


def test_version_names():
    assert [version_filename(n) for n in (1, 2, 12)] == ["report.html", "report-2.html", "report-12.html"]
    with pytest.raises(ValueError, match="from 1"):
        version_filename(0)


def test_a_failed_version_leaves_no_file(real_solution, tmp_path):
    with pytest.raises(InputError, match="point_distance_mm"):
        write_report_version(real_solution, tmp_path, "a test", point_distance_mm=-1.0)
    assert not list(tmp_path.glob("report*"))


# --- simulated --------------------------------------------------------------------------------------
def test_a_simulated_dataset_makes_a_simulated_provenance(dataset, tmp_path):
    """Data from the simulator hold its truth (what the terminal's "simulated truth"
    line reads): the result's provenance says simulated."""
    assert "true_transform" in dataset.provenance and "simulated" not in dataset.provenance
    assert traceability(dataset, None)["simulated"] is True
    real = dataset.model_copy(update={"provenance": {"source": "spherecal calibrate", "simulated": False}})
    assert traceability(real, None)["simulated"] is False
    assert is_simulated({"dataset": "spherecal simulator (centre observations)"})  # a result written before
    assert not is_simulated({"dataset": "spherecal calibrate", "simulated": False}) and not is_simulated(None)


@pytest.mark.slow
def test_a_simulated_run_is_marked_on_every_page(simulated_solution, real_solution, tmp_path):
    page = write_report(simulated_solution, tmp_path / "sim").read_text()
    assert "<title>SIMULATED: spherecal calibration report</title>" in page
    assert 'class="simulated-banner"' in page and "It calibrates no real cell: do not sign it as one." in page
    # the mark is fixed: it stays in view on screen and is printed on every page
    assert page.count('<div class="simulated-mark" aria-hidden="true">SIMULATED</div>') == 1
    assert re.search(r"\.simulated-mark \{ position: fixed;", page)
    identity = _text(page[page.index('id="identity"'):page.index('id="advice"')])
    assert "simulated yes: SIMULATED , not a real cell" in identity
    real = write_report(real_solution, tmp_path / "real").read_text()
    assert 'class="simulated-banner"' not in real and "SIMULATED" not in _text(real) and "<title>spherecal" in real


# --- provenance, decimals, tiles --------------------------------------------------------------------
@pytest.mark.slow
def test_the_provenance_is_a_table_and_the_numbers_have_the_exports_decimals(real_solution, tmp_path):
    page = write_report(real_solution, tmp_path).read_text()
    assert '{"dataset"' not in page and "&quot;dataset&quot;" not in page  # no JSON dump
    identity = _text(page[page.index('id="identity"'):page.index('id="advice"')])
    for row in ("data from spherecal calibrate", "simulated no", "station plan: stations 4",
                "station plan: tilt (deg) 30", "reference sphere radius 19.1000 mm, U = 0.0015 mm (k = 2)"):
        assert row in identity, row
    # the transform as the xyz + quaternion export writes it, to the digit
    export_line = xyz_quaternion_text(real_solution.result).strip().splitlines()[-1].split()
    xyz, quat = export_line[1:4], export_line[4:8]
    cards = _text(page[page.index('id="transform"'):page.index("As 4x4 matrices")])
    assert f"translation (mm) {', '.join(xyz)}" in cards and f"quaternion (w, x, y, z) {', '.join(quat)}" in cards
    assert len(quat[1].split(".")[1]) == 8  # (the exports' quaternion decimals, not fewer)


def test_provenance_rows_flatten_and_say_units():
    rows = dict(provenance_rows({"robot": {"type": "abb", "serial_number": None}, "sphere": {"radius_mm": 19.1},
                                 "dataset_sha256": "00ff", "simulated": True, "cell": "A"}, leave_out=("cell",)))
    assert rows == {"robot: type": "abb", "robot: serial number": "&ndash;", "sphere: radius (mm)": "19.1000",
                    "dataset (SHA-256)": '<code class="hash">00ff</code>', "simulated": "yes"}


@pytest.mark.slow
def test_a_centre_table_shows_no_profile_tiles(tmp_path):
    cell = standard_cell("eye_in_hand", seed=9, noise=NoiseModel(point_noise_mm=0.01), fov=reference_fov())
    solution = solve(simulate_centre_dataset(cell, PLAN, kind="sphere_centre", centre_noise_mm=0.02))
    page = write_report(solution, tmp_path).read_text()
    text = _text(page)
    for tile in ("profiles used / flagged", "points used / rejected", " 0 profiles", "every profile was used",
                 "profile points mapped"):
        assert tile not in text, tile
    assert "observations flagged 0" in text and "24 centre observations" in text
    assert "the centre observations mapped into the sphere frame" in text
    for key in ("residuals_per_profile", "residuals_along_line", "residuals_on_sphere", "view3d"):
        assert f'id="fig-{key}"' not in page and f'id="{key}"' not in page, key
