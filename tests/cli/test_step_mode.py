"""``calibrate --step``: a question before each station, answered on standard input; any
answer but yes stops the run before the station's first move, the journal kept and the
command that continues it printed."""

import io
import os
import subprocess
import sys

import pytest

from spherecal.cli import EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, main
from spherecal.io import dataset as dataio
from spherecal.motion import acquisition

S1_PROMPT = "station S1: 10 shots from flange (1132.0, 163.3, 583.3) mm in base; go? [y/N/q] "
S2_PROMPT = "station S2: 10 shots from flange (1074.6, 263.0, 576.4) mm in base; go? [y/N/q] "
S3_PROMPT = "station S3: 10 shots from flange (1060.8, 110.0, 560.1) mm in base; go? [y/N/q] "


class _Terminal(io.StringIO):
    """Standard input at a terminal, holding what the operator types."""

    def isatty(self) -> bool:
        return True


def _typed(monkeypatch, text: str) -> None:
    monkeypatch.setattr(sys, "stdin", _Terminal(text))


def _shots(out):
    return [o.target for o in dataio.read_dataset(out / "journal.jsonl").observations]


def test_a_no_stops_before_the_station_and_the_printed_command_continues(sim_config, monkeypatch, capsys):
    cfg = sim_config()
    out = cfg.parent / "out"
    _typed(monkeypatch, "y\nY\nn\n")
    assert main(["calibrate", str(cfg), "--no-report", "--step"]) == EXIT_INTERRUPTED
    captured = capsys.readouterr()
    assert captured.out.count("go? [y/N/q] ") == 3
    assert S1_PROMPT in captured.out and S2_PROMPT in captured.out and S3_PROMPT in captured.out
    resume = f"spherecal calibrate {cfg} --out {out} --resume"
    assert (f"spherecal: error: stopped before station S3 (--step, answered 'n'); nothing more was moved; what was "
            f"taken is in the journal ({out / 'journal.jsonl'}): continue with {resume}") in captured.err
    assert _shots(out) == list(range(20))  # S1 and S2, nothing of S3
    # the printed command, run as it is (here with --step, answered yes twice), ends the run
    _typed(monkeypatch, "y\ny\n")
    assert main([*resume.split()[1:], "--no-report", "--step"]) == EXIT_OK
    asked = capsys.readouterr().out
    assert asked.count("go? [y/N/q] ") == 2 and S3_PROMPT in asked and "station S4: 10 shots" in asked
    assert _shots(out) == list(range(40)) and (out / "result.json").exists()


@pytest.mark.parametrize("typed, answered", [("q\n", "'q'"), ("\n", "''"), ("", "'(no input)'")])
def test_stopped_before_the_first_station_the_printed_command_starts_it(sim_config, monkeypatch, capsys, typed,
                                                                         answered):
    """q, an empty line and the end of input all stop; nothing is taken, and the journal
    (the plan only) is started by the printed command, not by the same command again."""
    cfg = sim_config()
    out = cfg.parent / "out"
    _typed(monkeypatch, typed)
    assert main(["calibrate", str(cfg), "--no-report", "--step"]) == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    resume = f"spherecal calibrate {cfg} --out {out} --resume"
    assert (f"stopped before station S1 (--step, answered {answered}); nothing more was moved; no shot was taken yet; "
            f"start again with {resume}") in err, err
    assert _shots(out) == []
    assert main([*resume.split()[1:], "--no-report"]) == EXIT_OK
    assert len(_shots(out)) == 40


def test_step_needs_a_terminal_on_standard_input(sim_config, monkeypatch, capsys):
    cfg = sim_config()
    monkeypatch.setattr(sys, "stdin", io.StringIO("y\ny\ny\ny\n"))  # a pipe or a file: not a terminal
    assert main(["calibrate", str(cfg), "--step"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert ("--step asks before each station and needs a terminal on standard input to answer at; standard input is "
            "not one (a pipe, a file, a script): run it at a terminal, or leave out --step; nothing was opened or "
            "moved") in err
    assert not (cfg.parent / "out" / "journal.jsonl").exists()


def test_step_with_manual_is_refused(sim_config, monkeypatch, capsys):
    _typed(monkeypatch, "y\n")
    assert main(["calibrate", str(sim_config()), "--step", "--manual"]) == EXIT_USAGE
    assert "--step asks before each planned station; --manual has no plan" in capsys.readouterr().err


def test_a_resumed_station_is_asked_for_with_the_shots_it_has_left(monkeypatch):
    """Targets 0-2 of S1 taken: the question before the rest of S1 counts its 7 shots and
    gives the first of them; then S2's 10."""
    from spherecal.core.models import Pose, Profile
    import numpy as np

    asked = []
    profile = Profile(y_mm=np.linspace(-5, 5, 30), z_mm=np.full(30, 10.0))
    monkeypatch.setattr(acquisition, "move_and_shoot", lambda *a: (Pose.identity(), None, profile, 0))
    targets = [acquisition.Target(k, "S1" if k < 10 else "S2", Pose.from_rt(np.eye(3), [k, 0.0, 0.0]), k in (0, 10),
                                  10.0) for k in range(20)]

    class _Writer:
        next_index = 0

        def append(self, obs):
            self.next_index += 1

    acquisition.acquire(None, None, targets, _Writer(), None, {0, 1, 2}, log=lambda s: None,
                        progress=acquisition.Progress(20, io.StringIO()),
                        before_station=lambda station, left: asked.append((station, [t.index for t in left])))
    assert asked == [("S1", list(range(3, 10))), ("S2", list(range(10, 20)))]


@pytest.mark.slow
def test_answers_typed_at_a_real_terminal(sim_config, tmp_path):
    """The program itself, its standard input a pseudo-terminal the answers are typed into."""
    cfg = sim_config()
    primary, secondary = os.openpty()
    try:
        os.write(primary, b"y\nn\n")
        run = subprocess.run([sys.executable, "-m", "spherecal.cli", "calibrate", str(cfg), "--no-report", "--step"],
                             stdin=secondary, capture_output=True, text=True, timeout=300)
    finally:
        os.close(secondary)
        os.close(primary)
    assert run.returncode == EXIT_INTERRUPTED, run.stderr
    assert S1_PROMPT in run.stdout and S2_PROMPT in run.stdout
    assert "stopped before station S2 (--step, answered 'n')" in run.stderr
    assert _shots(cfg.parent / "out") == list(range(10))
