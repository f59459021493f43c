"""``validate`` of an on-the-fly configuration: it says and checks only the passes it
takes (not the stop-and-go shots it does not), and writes the calibration's report anew
with its figures (``report-2.html``), as a stop-and-go validation does."""

import pytest

from spherecal.app import validate as validate_app
from spherecal.app.validate import run_validate
from spherecal.cli import EXIT_OK, EXIT_VALIDATION, main
from spherecal.config import load_config
from tests.cli.test_scan_on_the_fly import EXAMPLE, cell_truth  # noqa: F401 (a fixture)


class Opened(Exception):
    """Raised where the devices would open: what was said before it is the plan."""


def test_the_plan_said_and_checked_is_the_passes_only(cell_truth, monkeypatch):  # noqa: F811
    cfg, *_ = cell_truth

    def refuse(*args, **kwargs):
        raise Opened

    monkeypatch.setattr(validate_app, "open_devices", refuse)
    lines = []
    with pytest.raises(Opened):
        run_validate(load_config(cfg), report=False, yes=True, log=lambda m: lines.append(str(m)))
    said = [x for x in lines if x.startswith("validating ")]
    assert len(said) == 1 and ": 4 passes on the fly at 100 mm/s, one per validation sweep" in said[0], lines
    assert not any("shots" in x for x in lines), lines
    # the keep-out check ran on the passes (targets named by their pass), once
    keep_out = [x for x in lines if x.startswith("keep-out")]
    assert len(keep_out) == 1 and "-sphere, sweep " in keep_out[0], keep_out


@pytest.mark.slow
def test_validate_after_an_on_the_fly_calibration_writes_report_2(sim_config, capsys):
    cfg = sim_config(EXAMPLE)
    assert main(["calibrate", str(cfg), "--yes"]) == EXIT_OK
    out = cfg.parent / "out"
    assert (out / "journal.stream.jsonl").is_file() and not (out / "journal.jsonl").exists()
    capsys.readouterr()
    assert main(["validate", str(cfg), "--yes"]) in (EXIT_OK, EXIT_VALIDATION)
    printed = capsys.readouterr().out
    assert (out / "report-2.html").is_file() and f"report: {out / 'report-2.html'}, a new version" in printed
    page = (out / "report-2.html").read_text()
    assert "P_F" in page and "centre spread" in page
