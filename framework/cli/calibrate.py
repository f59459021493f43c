"""``spherecal calibrate CONFIG``: calls :mod:`spherecal.app.calibrate` and prints the
result, its verdict and what to do next."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from shlex import quote

from spherecal.app.calibrate import run_calibrate
from spherecal.app.outputs import interrupted_runs, journal_holds_shots, journal_of
from spherecal.cli.finish import finish, say_result
from spherecal.cli.output import EXIT_OK, result_json
from spherecal.cli.session import Session, ask
from spherecal.config import load_config
from spherecal.core.errors import ConfigError
from spherecal.io.runlog import progress_log
from spherecal.report.terminal import truth_check, truth_errors

_log = logging.getLogger("spherecal.cli")


def run(args, session: Session) -> int:
    if args.step:
        check_step_mode(args)
    loaded = load_config(args.config)
    out = Path(args.out) if args.out else loaded.output_dir
    session.run_folder(out)
    session.resume_command = f"spherecal calibrate {quote(str(args.config))} --out {quote(str(out))} --resume"
    _log.debug("configuration %s", loaded.path)
    session.note_file("configuration", loaded.path, with_text=True)
    outcome = run_calibrate(
        loaded, dry_run=args.dry_run, resume=args.resume, manual=args.manual,
        out_dir=Path(args.out) if args.out else None, log=progress_log("run"),
        progress_stream=session.progress_stream(), report=not args.no_report, force=args.force, yes=args.yes,
        ask=ask, operator=args.operator, step=args.step,
    )
    if outcome.finished:
        session.say(f"{out} holds a finished run ({out / 'result.json'}): nothing to resume; its result, exports "
                    "and report were left as they are")
        if not args.out:  # an interrupted run given its own folder is not here: say where it is
            for folder in interrupted_runs(loaded.path, [out.parent, loaded.path.parent, Path.cwd()]):
                session.say(f"an interrupted run of this configuration is in {folder}: continue it with "
                            f"spherecal calibrate {quote(str(args.config))} --out {quote(str(folder))} --resume")
        return EXIT_OK
    if outcome.solution is None:
        return EXIT_OK
    say_result(session, outcome.solution, outcome.verdict, verbose=bool(args.verbose))
    session.summary.update(result_json(outcome.solution.result, outcome.verdict, outcome.exports_written))
    if outcome.acquisition is not None:
        session.summary["acquisition"] = outcome.acquisition
    session.summary["simulated_truth"] = None
    if outcome.files.get("journal") is not None:
        check = truth_check(outcome.solution, outcome.dataset)
        if check:
            session.say(check)
            session.summary["simulated_truth"] = truth_errors(outcome.solution, outcome.dataset)
    if loaded.config.validation is not None and outcome.verdict.level != "red":
        folder = f" -o {quote(str(args.out))}" if args.out else ""  # (the run validate is to check)
        session.say(f"acceptance test: spherecal validate {quote(str(args.config))}{folder} (its figures then join "
                    "this verdict, in the terminal and the report)")
    return finish(session, out, outcome.verdict, outcome.exports_written,
                  "--resume --force" if outcome.files.get("journal") else "--force", report=not args.no_report)


def check_step_mode(args) -> None:
    """``--step`` asks before each station: a ConfigError before anything else when no one
    can answer (standard input is not a terminal) or there are no stations (``--manual``)."""
    if args.manual:
        raise ConfigError("--step asks before each planned station; --manual has no plan (the operator jogs): give "
                          "one of the two")
    try:
        interactive = sys.stdin is not None and sys.stdin.isatty()
    except (ValueError, OSError):  # closed
        interactive = False
    if not interactive:
        raise ConfigError("--step asks before each station and needs a terminal on standard input to answer at; "
                          "standard input is not one (a pipe, a file, a script): run it at a terminal, or leave out "
                          "--step; nothing was opened or moved")


def after_failure(session: Session) -> str:
    """What to do after a calibration stopped half-way."""
    if not journal_holds_shots(session.out_dir):
        if session.out_dir is not None and journal_of(session.out_dir).is_file() and session.resume_command:
            # the journal holds the plan only (stopped before the first shot): a new run there would be refused
            return f"; no shot was taken yet; start again with {session.resume_command}"
        return "; no shot was taken yet: nothing to resume, run the same command again"
    return (f"; what was taken is in the journal ({journal_of(session.out_dir)}): continue with "
            f"{session.resume_command or '--resume'}")
