"""The command line in scripts: --json summaries, run.log, -v/-q, options after the
command, a closed pipe, shell completion, CLI wording in messages."""

import json
import logging
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_DATA, EXIT_DRIFT, EXIT_OK, EXIT_PIPE, build_parser, main
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov


@pytest.fixture(scope="module")
def dataset_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("scripting") / "d.jsonl"
    dataio.write_dataset(path, simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=reference_fov()),
                                                SweepPlan(profiles_per_station=6)))
    return path


@pytest.fixture(scope="module")
def solved(dataset_path):
    """``solve --json`` of the dataset: (output folder, its stdout, its stderr, exit code)."""
    out = dataset_path.parent / "run"
    proc = subprocess.run([sys.executable, "-m", "spherecal.cli", "solve", str(dataset_path), "-o", str(out),
                           "--json"], capture_output=True, text=True, timeout=600)
    return out, proc.stdout, proc.stderr, proc.returncode


@pytest.mark.slow
def test_solve_json_is_the_only_stdout_and_its_transform_is_result_json(solved):
    out, stdout, stderr, code = solved
    assert code == EXIT_OK, stderr
    summary = json.loads(stdout)  # the whole of stdout is one JSON document
    assert summary["schema"] == "spherecal-cli-summary/1"
    assert summary["command"] == "solve" and summary["exit_code"] == 0 and summary["error"] is None
    result = json.loads((out / "result.json").read_text())
    t = summary["transform"]
    assert t["name"] == result["transform_name"] == "flange_from_sensor"
    assert t["translation_mm"] == result["transform"]["translation_mm"]
    assert t["quaternion_wxyz"] == result["transform"]["quaternion_wxyz"]
    assert t["quaternion_order"].startswith("w, x, y, z")
    u = summary["uncertainty"]
    assert u["std_translation_mm"] == result["std_translation_mm"]
    assert u["expanded_rotation_deg"] == [2 * v for v in result["std_rotation_deg"]]
    assert summary["verdict"]["level"] in ("green", "amber")
    assert summary["result_written"] is True
    assert summary["files"]["result.json"] == str(out / "result.json")
    assert summary["files"]["run.log"] == str(out / "run.log")
    assert {"report.html", "flange_from_sensor_4x4.txt"} <= set(summary["files"])
    # the human text went to stderr
    assert "quaternion_wxyz = [" in stderr and f"results in {out}" in stderr


def test_run_log_names_what_ran_its_input_and_what_was_measured(solved, dataset_path):
    out, _, _, _ = solved
    text = (out / "run.log").read_text()
    assert "spherecal" in text and " solve, started " in text and "exit code 0 (success)" in text
    assert f"command line: spherecal solve {dataset_path} -o {out} --json" in text
    from spherecal.app.provenance import sha256_of

    assert f"dataset: {dataset_path} (sha256 {sha256_of(dataset_path)})" in text
    assert '"fit_radius":false' in text  # the options it ran with
    assert "spherecal.run: joint refinement over" in text  # the progress
    assert "quaternion_wxyz = [" in text and "verdict: " in text  # what was measured


@pytest.mark.slow
def test_calibrate_run_log_names_the_configuration_and_appends(sim_config, capsys):
    cfg = sim_config()
    out = cfg.parent / "elsewhere"
    assert main(["calibrate", str(cfg), "-o", str(out), "--no-report", "-q"]) == EXIT_OK
    captured = capsys.readouterr()
    # -q: no progress, no bar; warnings still (the export's tool load left for the user to give)
    assert [ln for ln in captured.err.splitlines() if not ln.startswith("warning: ")] == []
    assert "quaternion_wxyz = [" in captured.out  # the result still goes to stdout
    log = (out / "run.log").read_text()
    assert f"configuration: {cfg} (sha256 " in log
    assert "[simulation]" in log  # the configuration's text
    assert "spherecal.run: plan: " in log and "journal.jsonl" in log
    assert not (cfg.parent / "out").exists()  # -o is the output folder
    # a second command in the folder appends its record
    assert main(["calibrate", str(cfg), "-o", str(out), "--resume"]) == EXIT_OK
    log2 = (out / "run.log").read_text()
    assert log2.startswith(log) and log2.count(" calibrate, started ") == 2
    assert "nothing to resume" in log2[len(log):]


def test_quiet_verbose_and_debug_also_after_the_command(dataset_path, tmp_path, capsys):
    assert main(["solve", str(dataset_path), "-o", str(tmp_path / "q"), "-q", "--no-report"]) == EXIT_OK
    q = capsys.readouterr()
    # -q leaves out progress, not warnings: only the export's missing tool load is said
    assert [ln for ln in q.err.splitlines() if not ln.startswith("warning: ")] == [] and "results in" in q.out
    assert "spherecal.run: fitting circles" in (tmp_path / "q" / "run.log").read_text()  # recorded all the same
    assert main(["-v", "solve", str(dataset_path), "-o", str(tmp_path / "v"), "--no-report"]) == EXIT_OK
    v = capsys.readouterr()
    assert "fitting circles" in v.err and "spherecal 0." in v.err  # the debug line of -v
    assert main(["solve", str(dataset_path), "-o", str(tmp_path / "n"), "--no-report"]) == EXIT_OK
    n = capsys.readouterr()
    assert "fitting circles" in n.err and "spherecal 0." not in n.err
    parser = build_parser()
    for argv in (["--debug", "plugins"], ["plugins", "--debug"]):
        assert parser.parse_args(argv).debug is True
    assert parser.parse_args(["plugins"]).debug is False
    assert parser.parse_args(["solve", "d.jsonl", "-q"]).quiet is True
    assert parser.parse_args(["-q", "solve", "d.jsonl"]).quiet is True
    assert parser.parse_args(["solve", "d.jsonl", "-o", "x"]).out == "x"


def test_a_dataset_cut_off_mid_line_is_one_warning_line_and_is_in_run_log(dataset_path, tmp_path, capsys):
    """A file whose last line the acquisition did not finish: the whole observations are
    solved, and the command says what it dropped once, as a ``warning:`` line (not
    Python's warning with its source line) that run.log keeps too."""
    cut = tmp_path / "cut.jsonl"
    data = dataset_path.read_bytes()
    cut.write_bytes(data[: len(data) - 500])  # into the last observation's line
    assert main(["solve", str(cut), "-o", str(tmp_path / "o"), "--no-report"]) == EXIT_OK
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "is incomplete" in ln]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {cut}: line ")
    assert "Warning" not in err and "cli.py" not in err  # no class name, no source line
    log = (tmp_path / "o" / "run.log").read_text()
    assert "WARNING spherecal.run: warning: " in log and "is incomplete" in log


def test_no_handler_is_left_installed_and_an_application_can_route_the_messages(dataset_path, tmp_path):
    probe = ("import logging, spherecal, spherecal.cli, spherecal.app.solving, spherecal.motion.validation; "
             "lg = logging.getLogger('spherecal'); print(len(lg.handlers), lg.level)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert proc.stdout.split() == ["0", "0"], proc.stderr  # nothing installed on import, no level set
    root = logging.getLogger("spherecal")
    before = list(root.handlers)
    assert main(["plugins", "-q"]) == EXIT_OK
    assert root.handlers == before and root.level == logging.NOTSET  # main() leaves nothing behind
    # an application embedding spherecal routes the commands' messages with its own handler
    from spherecal.estimation import CalibrationOptions
    from spherecal.app.solving import solve_and_write
    from spherecal.plugins.host import PluginHost

    seen = []

    class Collect(logging.Handler):
        def emit(self, record):
            seen.append((record.name, record.getMessage()))

    handler = Collect(logging.INFO)
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    try:
        dataset = dataio.read_dataset(dataset_path)
        exports = PluginHost().export_plan(None, dataset.mounting, None)
        solve_and_write(dataset, CalibrationOptions(), tmp_path / "api", exports, report=False)
    finally:
        root.removeHandler(handler)
        root.setLevel(logging.NOTSET)
    assert ("spherecal.run", "fitting circles to 24 profiles") in seen


def test_compare_json_and_its_exit_code(dataset_path, solved, tmp_path, capsys):
    out, _, _, _ = solved
    result = dataio.read_result(out / "result.json")
    X = result.transform
    moved = X.model_copy(update={"translation_mm": tuple(np.add(X.translation_mm, [0.0, 0.0, 0.5]))})
    (tmp_path / "b").mkdir()
    dataio.write_result(tmp_path / "b" / "result.json", result.model_copy(update={"transform": moved}))
    code = main(["compare", str(out), str(tmp_path / "b"), "--json", "--fail-on-drift", "--uncertainty", "full"])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert code == EXIT_DRIFT == summary["exit_code"] and summary["exit_meaning"] == "drift found"
    c = summary["comparison"]
    assert c["translation_mm"] == pytest.approx([0.0, 0.0, 0.5], abs=1e-9) and c["drift"] is True
    assert summary["transform"]["translation_mm"] == pytest.approx(list(moved.translation_mm))
    assert summary["reference"]["source"] == str(out / "result.json")
    assert summary["files"] == {} and summary["out_dir"] is None
    assert "B relative to A" in captured.err and "drift found (exit 8)" in captured.err


def test_json_on_an_error_still_prints_one_summary(tmp_path, capsys):
    missing = tmp_path / "none.jsonl"
    code = main(["solve", str(missing), "--json", "-o", str(tmp_path / "r")])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert code == EXIT_DATA == summary["exit_code"]
    assert str(missing) in summary["error"] and "transform" not in summary
    assert "spherecal: error:" in captured.err


@pytest.mark.slow
def test_validate_json(sim_config, capsys):
    from spherecal.config import load_config
    from tests.cli.cells import simulated_cell

    cfg = sim_config("sim-eye-in-hand.toml", exact_arm=True)
    out = cfg.parent / "out"
    true = simulated_cell(load_config(cfg).config).true_transform
    write_result_with(out, cfg, true)
    code = main(["validate", str(cfg), "--json", "--no-report"])
    summary = json.loads(capsys.readouterr().out)
    assert code == EXIT_OK == summary["exit_code"]
    assert summary["validation"]["passed"] is True and summary["validation"]["transform_given"] is False
    assert summary["transform"]["source"] == str(out / "result.json")
    assert summary["transform"]["translation_mm"] == list(true.translation_mm)
    assert summary["validation"]["figures"]["P_F"]["passed"] is True
    assert "validation.json" in summary["files"] and "run.log" in summary["files"]
    assert summary["validation"]["report"] is None  # --no-report: no new version of the report
    assert summary["validation"]["figures_file"] in {str(out / n) for n in summary["files"]}
    assert any(name.startswith("validation-") and name.endswith(".jsonl") for name in summary["files"])
    assert summary["verdict"]["headline"].endswith("Validation passed.") or "Validation passed" in \
        summary["verdict"]["headline"]


@pytest.mark.slow
def test_scan_records_the_result_it_used_with_out(sim_config, capsys):
    from spherecal.config import load_config
    from spherecal.io.ply import read_ply_header
    from tests.cli.cells import simulated_cell

    cfg = sim_config("sim-eye-in-hand.toml", exact_arm=True, **{r"^passes = 2$": "passes = 1"})
    other = cfg.parent / "other-run"
    write_result_with(other, cfg, simulated_cell(load_config(cfg).config).true_transform)
    assert main(["scan", str(cfg), "--out", str(other)]) == EXIT_OK
    header = read_ply_header(other / "scan.ply")
    assert f"spherecal scan, flange_from_sensor from {other / 'result.json'}" in header.comments
    assert not (cfg.parent / "out").exists()
    assert "exit code 0" in (other / "run.log").read_text()


def test_a_closed_pipe_exits_141_without_an_error(tmp_path):
    """``spherecal plugins | head``: the reader goes away; no traceback, no 'internal error'.
    The reader is gone before the first write (a pipe whose read end is closed): with
    ``head`` it depends on timing whether the ~18 KB of output still fit in the pipe."""
    import os

    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "spherecal.cli", "plugins"], stdout=write_end,
                                stderr=subprocess.PIPE)
    finally:
        os.close(write_end)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == EXIT_PIPE == 141
    assert "internal error" not in err and "BrokenPipe" not in err and "Traceback" not in err


def test_simulate_says_force_not_the_python_keyword(tmp_path, capsys):
    path = tmp_path / "d.jsonl"
    path.write_text("")
    assert main(["simulate", str(path)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert f"{path} already exists; give --force" in err and "=True" not in err
    assert main(["simulate", str(path), "--profiles", "4", "--force"]) == EXIT_OK


def test_solve_of_a_result_file_says_what_to_give(solved, tmp_path, capsys):
    out, _, _, _ = solved
    assert main(["solve", str(out / "result.json"), "-o", str(tmp_path / "x")]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "it is a calibration result" in err and "give a dataset" in err and "()" not in err


def write_result_with(out, cfg_path, transform):
    """A result.json claiming ``transform`` (from a quick solve of the cell's data, so the
    other fields are genuine)."""
    from spherecal.config import load_config
    from spherecal.estimation import calibrate
    from tests.cli.cells import simulated_cell

    result = calibrate(simulate_dataset(simulated_cell(load_config(cfg_path).config), SweepPlan(profiles_per_station=6)))
    out.mkdir(parents=True, exist_ok=True)
    dataio.write_result(out / "result.json", result.model_copy(update={"transform": transform}))


def _complete(script: str, words: list[str]) -> list[str]:
    """What the bash completion function offers for ``words`` (the last one being typed)."""
    array = " ".join(f"'{w}'" for w in words)
    cmd = f'source /dev/stdin <<\'EOF\'\n{script}\nEOF\nCOMP_WORDS=({array}); COMP_CWORD={len(words) - 1}; ' \
          '_spherecal; printf "%s\\n" "${COMPREPLY[@]}"'
    proc = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return [w for w in proc.stdout.splitlines() if w]


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_bash_completion_is_valid_and_completes_commands_options_and_choices(tmp_path, capsys):
    assert main(["completion", "bash"]) == EXIT_OK
    script = capsys.readouterr().out
    path = tmp_path / "spherecal.bash"
    path.write_text(script)
    check = subprocess.run(["bash", "-n", str(path)], capture_output=True, text=True, timeout=60)
    assert check.returncode == 0, check.stderr
    commands = ["calibrate", "solve", "simulate", "validate", "scan", "compare", "plugins", "completion"]
    assert _complete(script, ["spherecal", ""]) == commands
    assert _complete(script, ["spherecal", "ca"]) == ["calibrate"]
    assert _complete(script, ["spherecal", "solve", "d.jsonl", "--pose-from", ""]) == ["reported", "joints"]
    assert _complete(script, ["spherecal", "compare", "a", "--fail"]) == ["--fail-on-drift"]
    assert set(_complete(script, ["spherecal", "calibrate", "--j"])) == {"--json"}
    assert _complete(script, ["spherecal", "completion", ""]) == ["bash", "zsh"]
    os.mkdir(tmp_path / "runs")
    (tmp_path / "runs.txt").write_text("")
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        assert _complete(script, ["spherecal", "solve", "d", "-o", "ru"]) == ["runs"]  # folders only
    finally:
        os.chdir(cwd)


def test_zsh_completion_names_every_command_and_option(capsys):
    assert main(["completion", "zsh"]) == EXIT_OK
    script = capsys.readouterr().out
    assert script.startswith("#compdef spherecal\n")
    for name in ["calibrate", "solve", "simulate", "validate", "scan", "compare", "plugins", "completion"]:
        assert f"'{name}:" in script and f"            {name})" in script
    assert "'--pose-from[" in script and ":(reported joints)'" in script and "_files -/" in script
    if shutil.which("zsh"):
        check = subprocess.run(["zsh", "-n", "/dev/stdin"], input=script, capture_output=True, text=True)
        assert check.returncode == 0, check.stderr


def test_the_json_summary_is_strict_json():
    from pathlib import Path

    from spherecal.cli.output import json_text

    text = json_text({"command": "x", "a": float("nan"), "b": np.float64(1.5), "c": np.array([1, 2]),
                       "d": {"e": float("inf"), "f": (np.bool_(True), Path("p"))}})
    assert json.loads(text) == {"command": "x", "a": None, "b": 1.5, "c": [1, 2], "d": {"e": None, "f": [True, "p"]}}
    assert list(json.loads(text)) == ["command", "a", "b", "c", "d"]


def _truth_printed(text: str) -> tuple[float, float]:
    import re

    m = re.search(r"simulated truth: error ([\d.]+) deg, ([\d.]+) mm", text)
    return float(m[1]), float(m[2])


def test_json_gives_the_error_against_the_simulated_truth(dataset_path, tmp_path, capsys):
    """solve --json of simulated data holds the error the terminal prints, with the true
    transform; a dataset without a truth gives null."""
    assert main(["solve", str(dataset_path), "-o", str(tmp_path / "r"), "--json", "--no-report"]) == EXIT_OK
    captured = capsys.readouterr()
    truth = json.loads(captured.out)["simulated_truth"]
    rot, dt = _truth_printed(captured.err)
    assert round(truth["rotation_error_deg"], 4) == rot and round(truth["translation_error_mm"], 4) == dt
    true = dataio.read_dataset(dataset_path).provenance["true_transform"]
    assert truth["true_translation_mm"] == pytest.approx(true["translation_mm"])
    assert truth["true_quaternion_wxyz"] == pytest.approx(true["quaternion_wxyz"])
    # the same data without the simulator's truth
    plain_path = tmp_path / "plain.jsonl"
    ds = dataio.read_dataset(dataset_path)
    dataio.write_dataset(plain_path, ds.model_copy(update={"provenance": {"source": "a real cell"}}))
    assert main(["solve", str(plain_path), "-o", str(tmp_path / "p"), "--json", "--no-report"]) == EXIT_OK
    captured = capsys.readouterr()
    assert json.loads(captured.out)["simulated_truth"] is None and "simulated truth" not in captured.err


@pytest.mark.slow
def test_calibrate_json_gives_the_error_against_the_simulated_truth(sim_config, capsys):
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "-o", str(cfg.parent / "j"), "--no-report", "--json"]) == EXIT_OK
    captured = capsys.readouterr()
    truth = json.loads(captured.out)["simulated_truth"]
    rot, dt = _truth_printed(captured.err)
    assert round(truth["rotation_error_deg"], 4) == rot and round(truth["translation_error_mm"], 4) == dt
