"""What calibrate and solve print of their result, their last line, and their exit code
(a RED result exits 7)."""

from __future__ import annotations

from pathlib import Path

from spherecal.cli.output import EXIT_OK, EXIT_RED
from spherecal.cli.session import Session
from spherecal.report.terminal import details, summary


def say_result(session: Session, solution, graded, verbose: bool = False) -> None:
    """The result as the terminal gives it (:func:`spherecal.report.terminal.summary`),
    its details too with ``verbose`` (-v); without, the details go to run.log only."""
    session.say(summary(solution, graded, verbose=verbose))
    if not verbose:
        session.note("details (-v prints them):\n" + details(solution))


def finish(session: Session, out: Path, graded, written: bool, force: str = "--force", report: bool = True) -> int:
    """Where the results are, or why the result was not written; the exit code.
    ``report``: whether report.html was written (solve --no-report writes none)."""
    if graded.level != "red":
        session.say(f"results in {out}" + (f" (the report: {out / 'report.html'})" if report else ""))
        return EXIT_OK
    if written:
        session.say(f"results in {out} (written with --force although the result is RED: do not use it in "
                    "production)")
    else:
        where = f"report in {out}" if report else "no report either: --no-report"
        session.say(f"the result is RED: result.json and the exports were NOT written ({where}); fix the cause "
                    f"and run again, or give {force} to write them anyway")
    session.err("the result is RED (exit 7): see the verdict" + ("" if session.json else " above"))
    return EXIT_RED
