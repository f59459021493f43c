"""``calibrate --resume``: the acquisition line of a resumed on-the-fly run gives the whole
journal's figures and what this run took, and a journal line cut by the interruption is
said once, stop-and-go and on the fly."""

import warnings

import pytest

from spherecal.app import calibrate_on_the_fly as otf_app
from spherecal.app.calibrate import run_calibrate
from spherecal.config import load_config
from spherecal.io import dataset as dataio
from spherecal.io.dataset import TruncatedFileWarning
from spherecal.motion.acquisition import robot_time_line
from spherecal.motion.on_the_fly import SweepJournal
from tests.cli.test_calibrate_on_the_fly import EXAMPLE, SMALL, after_sweep


def kill():
    raise KeyboardInterrupt


def resumed(cfg, log):
    """``run_calibrate`` with --resume, and the TruncatedFileWarnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = run_calibrate(load_config(cfg), report=False, yes=True, log=log, resume=True, force=True)
    return outcome, [w for w in caught if issubclass(w.category, TruncatedFileWarning)]


def test_a_resumed_on_the_fly_run_says_the_whole_journal_and_a_cut_line_once(sim_config, monkeypatch):
    cfg = sim_config(EXAMPLE, **SMALL)
    out = cfg.parent / "out"
    with pytest.raises(KeyboardInterrupt):
        run_calibrate(load_config(cfg), report=False, yes=True, log=after_sweep(4, kill))
    before = SweepJournal.finished(out / "journal.sweeps.jsonl")
    with open(out / "journal.stream.jsonl", "ab") as fh:  # a line the interruption cut
        fh.write(b'{"poses": {"t_robot_s": [12.5')
    monkeypatch.setattr(otf_app, "_solved", lambda run, journal, outcome, **kw: outcome)  # the acquisition only
    log = after_sweep(-1, lambda: None)
    outcome, cut = resumed(cfg, log)
    rows = SweepJournal.finished(out / "journal.sweeps.jsonl")
    now = [r for k, r in rows.items() if k not in before]
    assert len(before) == 5 and len(rows) == 12 and len(now) == 7
    profiles, seconds = sum(r["profiles"] for r in rows.values()), sum(r["robot_time_s"] for r in rows.values())
    said = [x for x in log.lines if x.startswith("acquisition: ")]
    assert said == [f"acquisition: {robot_time_line(profiles, seconds, True)} on the fly (12 sweeps; this run took "
                    f"7 of them, {sum(r['profiles'] for r in now)} profiles in "
                    f"{sum(r['robot_time_s'] for r in now):.1f} s)"]
    assert outcome.acquisition["profiles"] == profiles and outcome.acquisition["sweeps"] == 12
    assert outcome.acquisition["sweeps_this_run"] == 7
    assert any(x.startswith("streams: ") and "over 12 sweeps" in x for x in log.lines)
    assert len(cut) == 1 and "is incomplete" in str(cut[0].message)


def test_a_stop_and_go_journal_cut_mid_line_is_said_once_on_resume(sim_config):
    cfg = sim_config()
    out = cfg.parent / "out"
    run_calibrate(load_config(cfg), report=False, yes=True, log=lambda _: None)
    journal = out / "journal.jsonl"
    data = journal.read_bytes()
    for path in out.iterdir():  # the run as a kill in its last shot leaves it: its journal alone
        if path != journal:
            path.unlink()
    journal.write_bytes(data[: len(data) - 500])
    lines = []
    outcome, cut = resumed(cfg, lines.append)
    assert len(cut) == 1 and "is incomplete" in str(cut[0].message)
    assert outcome.solution is not None and len(dataio.read_dataset(journal).observations) == \
        data.count(b"\n") - 1
