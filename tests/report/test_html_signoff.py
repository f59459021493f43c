"""What a report needs to be signed: identity and traceability, the verdict with the
validation, expanded uncertainty, correlations, the uncertainty of a point, print styles
(and, where Chromium is installed, the printed PDF)."""

import hashlib
import html
import importlib.util
import re
import shutil
import subprocess

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core.errors import DatasetFileError, InputError
from spherecal.estimation import solve
from spherecal.core.models import correlation_matrix
from spherecal.report.assess import Verdict, verdict, with_validation
from spherecal.report.html import point_uncertainty, write_report
from spherecal.app.provenance import traceability
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

PLAN = SweepPlan(profiles_per_station=6)


@pytest.fixture(scope="module")
def dataset_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("ds") / "run.jsonl"
    ds = simulate_dataset(standard_cell("eye_in_hand", seed=4, fov=reference_fov()), PLAN)
    ds = ds.model_copy(update={"provenance": {
        **ds.provenance, "source": "spherecal calibrate", "robot": "abb_irb2400", "sensor": "nxsensor_i",
        "robot_identity": {"manufacturer": "ABB", "model": "IRB 2400"},
        "sensor_identity": {"model": "nxSensor-I", "serial_number": "NXS-0042"}}})
    dataio.write_dataset(path, ds)
    return path


@pytest.fixture(scope="module")
def solution(dataset_file):
    import dataclasses

    ds = dataio.read_dataset(dataset_file)
    sol = solve(ds)
    prov = traceability(ds, dataset_file, operator="A. Operator")
    return dataclasses.replace(sol, result=sol.result.model_copy(update={"provenance": prov}))


POSITIONS = [
    {"position": "P1", "artefact": "sphere", "figure": "P_F", "error (mm)": 0.11, "MPE (mm)": 0.25, "passed": True},
    {"position": "P1", "artefact": "sphere", "figure": "P_S", "error (mm)": 0.081, "MPE (mm)": 0.06, "passed": False},
    {"position": "F1", "artefact": "flat", "figure": "F", "error (mm)": 0.05, "MPE (mm)": None, "passed": None},
]
FIGURES = {"P_F": {"max error (mm)": 0.11, "worst position": "P1", "positions": 1, "MPE (mm)": 0.25, "passed": True},
           "P_S": {"max error (mm)": 0.081, "worst position": "P1", "positions": 1, "MPE (mm)": 0.06, "passed": False}}


@pytest.fixture(scope="module")
def report(solution, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    ver = with_validation(verdict(solution.result), FIGURES)
    path = write_report(solution, out, validation=FIGURES, validation_positions=POSITIONS, verdict_override=ver,
                        point_distance_mm=150.0)
    return path, path.read_text(encoding="utf-8")


# --- traceability ----------------------------------------------------------------------------------
def test_the_provenance_names_what_was_calibrated_and_hashes_the_dataset(solution, dataset_file):
    p = solution.result.provenance
    assert p["dataset_sha256"] == hashlib.sha256(dataset_file.read_bytes()).hexdigest()
    assert p["dataset_file"] == str(dataset_file) and p["configuration_sha256"] is None
    assert p["robot"] == {"type": "abb_irb2400", "manufacturer": "ABB", "model": "IRB 2400"}
    assert p["sensor"]["serial_number"] == "NXS-0042" and p["operator"] == "A. Operator"
    assert p["sphere"] == {"radius_mm": 19.1} and p["software"].startswith("spherecal ")


@pytest.mark.slow
def test_the_report_shows_identity_traceability_and_a_signature_block(solution, report):
    _, text = report
    section = text[text.index('id="identity"'):text.index('id="advice"')]
    p = solution.result.provenance
    for needle in ("abb_irb2400", "IRB 2400", "nxsensor_i", "NXS-0042", "A. Operator", p["dataset_sha256"],
                   p["calibrated_at"], p["software"], "radius 19.1000 mm", "uncertainty not given"):
        assert html.escape(needle) in section, needle
    assert "serial number not reported" in section  # the robot reported none
    sign = text[text.index('id="signature"'):]
    assert sign.count('class="signature"') == 2 and "Calibrated by" in sign and "Approved by" in sign


# --- verdict with the validation ---------------------------------------------------------------------
def test_a_failed_figure_makes_the_verdict_red_and_names_it():
    base = Verdict("green", "Good.", [("green", "residuals as expected")])
    v = with_validation(base, FIGURES)
    assert v.level == "red" and v.headline.startswith("Validation failed: P_S 0.0810 mm exceeds its MPE 0.06 mm")
    assert ("red", "validation: P_S 0.0810 mm at P1 exceeds its MPE 0.06 mm") in v.reasons
    assert ("green", "validation: P_F 0.1100 mm at P1, within its MPE 0.25 mm") in v.reasons
    passed = {"P_F": FIGURES["P_F"], "F": {"max error (mm)": 0.05, "MPE (mm)": None, "passed": None}}
    v = with_validation(Verdict("amber", "Usable with care.", []), passed)
    assert v.level == "amber" and v.headline.endswith("Validation passed: every judged figure within its MPE.")
    assert ("green", "validation: F 0.0500 mm (no MPE: not judged)") in v.reasons


def test_a_p_s_beyond_its_mpe_by_less_than_its_uncertainty_passes_and_says_so():
    """P_S -0.0726 mm against its MPE 0.06 mm with U 0.0527 mm (k = 2) from the noise
    of its view: the validation passed, the calibration's grade stands, and the headline
    and the per-position table say that P_S is not shown to exceed its MPE."""
    from spherecal.report.html.sections import positions_html

    row = {"max error (mm)": -0.0726, "worst position": "P2", "positions": 4, "MPE (mm)": 0.06, "passed": True,
           "U (mm, k = 2)": 0.0527}
    v = with_validation(Verdict("green", "Good: a clean cell.", []), {"P_F": FIGURES["P_F"], "P_S": row})
    assert v.level == "green" and "Validation failed" not in v.headline
    assert v.headline.endswith("Validation passed: every other judged figure within its MPE; P_S -0.0726 mm at P2 "
                               "lies beyond its MPE 0.06 mm by less than its uncertainty from the noise (U 0.0527 mm, "
                               "k = 2): not shown to exceed it.")
    table = positions_html([{"position": "P2", "artefact": "sphere", "figure": "P_S", "error (mm)": -0.0726,
                             "MPE (mm)": 0.06, "passed": True, "U (mm, k = 2)": 0.0527}])
    assert "within U (0.0527 mm, k = 2)" in table and 'class="bad"' not in table


def test_the_report_verdict_includes_the_validation_with_a_per_position_table(report):
    _, text = report
    assert 'class="verdict red"' in text and "Validation failed: P_S 0.0810 mm" in text
    section = text[text.index('id="validation"'):text.index('id="details"')]
    assert "Per position" in section
    rows = re.findall(r"<tr( class=\"bad\")?><td>(P1|F1)</td><td>(\w+)</td><td>(\w+)</td>", section)
    assert [(r[1], r[3], bool(r[0])) for r in rows] == [("P1", "P_F", False), ("P1", "P_S", True), ("F1", "F", False)]
    assert "not judged" in section


# --- uncertainty -----------------------------------------------------------------------------------
def test_expanded_uncertainty_next_to_the_one_sigma(solution, report):
    _, text = report
    r = solution.result
    section = text[text.index('id="uncertainty"'):text.index('id="correlation"')]
    for sd in (*r.std_rotation_deg, *r.std_translation_mm, *r.std_sphere_centre_mm):
        assert f"<td>{sd:.4f}</td><td>{2 * sd:.4f}</td>" in section
    assert "expanded U (k = 2)" in section


def test_the_correlation_matrix_is_derived_labelled_and_kept_in_result_json(solution, report, tmp_path):
    r = solution.result
    cov = np.asarray(r.covariance)
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(r.correlation.matrix, cov / np.outer(sd, sd), atol=1e-6)
    assert r.correlation.parameters[:4] == ["rotation about flange x", "rotation about flange y",
                                            "rotation about flange z", "translation along flange x"]
    assert r.correlation.parameters[-1] == "sphere centre z (base)"
    dataio.write_result(tmp_path / "result.json", r)
    back = dataio.read_result(tmp_path / "result.json")
    assert back.correlation == r.correlation
    # a hand-edited correlation that no longer matches the covariance is refused
    doc = (tmp_path / "result.json").read_text().replace('"matrix": [\n      [1.0', '"matrix": [\n      [0.5', 1)
    (tmp_path / "bad.json").write_text(doc)
    with pytest.raises(DatasetFileError, match="correlation does not match the covariance"):
        dataio.read_result(tmp_path / "bad.json")
    _, text = report
    section = text[text.index('id="correlation"'):text.index('id="point"')]
    m = np.asarray(r.correlation.matrix)
    i, j = max(((i, j) for i in range(9) for j in range(i)), key=lambda ij: abs(m[ij]))
    assert f"Largest correlation: {m[i, j]:+.2f} between {r.correlation.parameters[i]}" in section


def test_correlation_of_a_parameter_without_variance_is_zero():
    c = correlation_matrix([[4.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(c, [[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])


def test_the_uncertainty_of_a_point_at_a_distance(solution):
    """Known answers: at the sensor's origin the point is as uncertain as the translation;
    with a rotation uncertainty alone (sigma rad about each axis), a point d mm along the
    line of sight moves sigma d along each of the two axes across it: RMS sqrt(2) sigma d."""
    r = solution.result
    at0 = point_uncertainty(r, 0.0)
    np.testing.assert_allclose(at0["sd_mm"], r.std_translation_mm, rtol=1e-9)
    s = 1e-4
    cov = np.zeros((9, 9))
    cov[:3, :3] = np.eye(3) * s**2
    rot_only = r.model_copy(update={"covariance": cov.tolist(), "correlation": None})
    u = point_uncertainty(rot_only, 200.0)
    assert u["rms_mm"] == pytest.approx(np.sqrt(2) * s * 200.0, rel=1e-9)
    assert u["expanded_k2_mm"] == pytest.approx(2 * u["rms_mm"])


def test_the_report_gives_the_point_uncertainty_at_the_chosen_distance(solution, report):
    _, text = report
    section = text[text.index('id="point"'):text.index('id="stations"')]
    u = point_uncertainty(solution.result, 150.0)
    assert f"<b>150 mm</b> from the sensor" in section and f"<b>{u['expanded_k2_mm']:.4f} mm</b>" in section
    assert '<tr class="chosen"><td>150</td>' in section
    with pytest.raises(InputError, match="point_distance_mm must be a positive number"):
        write_report(solution, section and "/tmp", point_distance_mm=-1.0)


# --- print -----------------------------------------------------------------------------------------
def test_print_styles(report):
    _, text = report
    css = text[text.index("@media print"):]
    for rule in ("break-after: avoid", "white-space: pre-wrap", "overflow: visible", "break-inside: avoid",
                 "display: none"):
        assert rule in css, rule


def _pdf_text(pdf) -> str | None:
    """The PDF's text with pypdf, else poppler's pdftotext, where installed (else None)."""
    if importlib.util.find_spec("pypdf") is not None:
        import pypdf

        return "\n".join(page.extract_text() or "" for page in pypdf.PdfReader(str(pdf)).pages)
    if shutil.which("pdftotext"):
        return subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True, text=True,
                              timeout=60).stdout
    return None


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not installed (apt-get install chromium)")
@pytest.mark.parametrize("paper", ["A4", "letter"])
def test_the_printed_pdf_holds_every_number_of_the_transform(solution, report, tmp_path, paper):
    path, text = report
    page = tmp_path / "report.html"
    page.write_text(text.replace("</style>", f"@page {{ size: {paper}; }}\n</style>", 1), encoding="utf-8")
    pdf = tmp_path / "report.pdf"
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-pdf-header-footer",
                    f"--print-to-pdf={pdf}", page.as_uri()], capture_output=True, timeout=180, check=False)
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF") and len(re.findall(rb"/Type\s*/Page[^s]", data)) >= 3
    found = _pdf_text(pdf)
    if found is None:
        pytest.skip("the PDF was printed; no pypdf nor pdftotext to read its text")
    flat = re.sub(r"\s+", " ", found)
    r = solution.result
    from spherecal.report import export

    # every line of the 4x4 block, whole (both matrices, every entry, and its long comment lines, which
    # an unwrapped <pre> cuts at the page's edge: text cut off is not in the PDF's text), and the cards'
    # numbers; lines wrapped on the page read back with a space where they broke
    lines = [re.sub(r"\s+", " ", line).strip() for line in export.matrix_text(r).splitlines() if line.strip()]
    lines += [f"{v:.4f}" for v in r.transform.translation_mm] + [f"{v:.6f}" for v in r.transform.quaternion_wxyz]
    assert len(re.findall(r"-?\d+\.\d{10}", export.matrix_text(r))) == 32
    missing = [line for line in lines if line not in flat]
    assert not missing, f"not in the {paper} PDF's text (cut off?): {missing}"
