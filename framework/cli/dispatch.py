"""The ``spherecal`` program: parse the arguments, run the chosen command's module with
logging set up for its length, map its errors to exit codes, and write run.log and the
``--json`` summary."""

from __future__ import annotations

import contextlib
import gc
import importlib
import logging
import os
import sys
import time
import traceback
import warnings

from spherecal import __version__
from spherecal.cli.output import (EXIT_DATA, EXIT_DEVICE, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_MEANING, EXIT_PIPE,
                                  EXIT_PLUGIN, EXIT_USAGE, JSON_SCHEMA, json_text)
from spherecal.cli.parser import build_parser
from spherecal.cli.session import Session
from spherecal.core.errors import (ConfigError, DatasetFileError, DegenerateDataError, DeviceError, FileWriteError,
                                   InputError, PluginError)
from spherecal.io.runlog import RUN_LOG_NAME, RunRecord, progress_log

_log = logging.getLogger("spherecal.cli")
#: The commands' ``log``: their progress lines go to logger ``spherecal.run`` (console and run.log).
_RUN_LOG = progress_log("run")
#: The commands whose options come from the installed plugins (a robot type's own name
#: for --controller-frame): for them the run's plugin host is made before parsing.
_PLUGIN_OPTIONS = frozenset({"compare", "validate"})


def console() -> int:
    """The ``spherecal`` program (its console script): :func:`main` with the process's
    arguments. Python's cyclic garbage collector stays off while the command's modules
    are imported (they allocate many long-lived objects, which it would scan again and
    again) and is back on, with what was imported frozen out of its scans, before the
    command reads or computes anything: about 45 ms (9 %) of a small ``solve``, measured
    on the README's install. :func:`main`, the library's entry, leaves the collector as
    it found it."""
    gc.disable()
    try:
        return main(_collector_held=True)
    finally:
        _collector_back()


def _collector_back() -> None:
    if not gc.isenabled():
        gc.freeze()
        gc.enable()


def main(argv: list[str] | None = None, _collector_held: bool = False) -> int:
    """Run one command; returns its exit code (:data:`spherecal.cli.output.EXIT_CODES_HELP`).
    Logging is set up for the command's length only (:func:`_logging`): nothing stays
    installed afterwards. Only the chosen command's modules are imported."""
    argv = sys.argv[1:] if argv is None else list(argv)
    host, frame_options = _plugin_options(argv)
    parser = build_parser(frame_options)
    args = parser.parse_args(argv)
    args._argv = argv
    args._collector_held = _collector_held
    session = Session(json=args.json, quiet=args.quiet, record=RunRecord(), host=host)
    session.summary.update(schema=JSON_SCHEMA, spherecal=__version__, command=args.command)
    started = time.time()
    real_stdout = sys.stdout
    code = EXIT_INTERNAL
    try:
        with _logging(args, session), _terminate_as_interrupt(), (
                contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext()):
            _log.debug("spherecal %s: spherecal %s", __version__, " ".join(args._argv))
            code = _run(args, session)
            if args.json:
                sys.stderr.flush()
            else:
                sys.stdout.flush()  # a reader that closed the pipe shows here, inside the handler below
            _close_record(args, code, started, session)
        if args.json:
            session.summary.update(exit_code=code, exit_meaning=EXIT_MEANING.get(code, "unknown"))
            session.summary.setdefault("error", None)
            print(json_text(session.summary), file=real_stdout)
            real_stdout.flush()
        return code
    except BrokenPipeError:
        _quiet_broken_stdout()
        return EXIT_PIPE


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a service manager stopping the run): taken as Ctrl-C is."""


@contextlib.contextmanager
def _terminate_as_interrupt():
    """While a command runs, SIGTERM stops it as Ctrl-C does: the devices stopped, what was
    taken kept, the resume command and run.log written (exit 130). Python's default would
    end the process on the spot, with none of that. Only from the main thread (the one
    signal handlers run in); the previous handler is restored after."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise Terminated(f"terminated ({signal.Signals(signum).name})")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _plugin_options(argv: list[str]) -> tuple[object | None, dict[str, list[str]]]:
    """For compare and validate: the run's plugin host and its robot types' names for
    --controller-frame, which their parsers offer (``(None, {})`` for the other commands,
    whose parsing loads no plugin)."""
    if not _PLUGIN_OPTIONS & set(argv):
        return None, {}
    return importlib.import_module("spherecal.app.plugins").host_and_frame_options()


def _run(args, session: Session) -> int:
    """The command's module (:mod:`spherecal.cli` ``.<command>``) run; its errors as exit codes."""
    command = None
    try:
        command = importlib.import_module(f"spherecal.cli.{args.command}")
        if getattr(args, "_collector_held", False):
            _collector_back()
        return command.run(args, session)
    except BrokenPipeError:
        raise
    except KeyboardInterrupt as exc:  # Ctrl-C, or the operator's stop at a --step prompt (which says so)
        session.err((str(exc) or "interrupted") + _after_failure(command, session))
        return EXIT_INTERRUPTED
    except ConfigError as exc:
        session.err(str(exc))
        return EXIT_USAGE
    except FileWriteError as exc:
        session.err(f"{exc}" + _after_failure(command, session))
        return EXIT_DATA
    except (InputError, DegenerateDataError, DatasetFileError, FileExistsError) as exc:
        session.err(str(exc))
        return EXIT_DATA
    except DeviceError as exc:
        session.err(f"{exc}\n" + _after_failure(command, session).lstrip("; "))
        return EXIT_DEVICE
    except PluginError as exc:
        session.err(str(exc))
        return EXIT_PLUGIN
    except OSError as exc:
        if exc.filename:  # a file that cannot be read or written (a full disk, no permission): name it
            session.err(f"{exc.filename}: {exc.strerror or exc}" + _after_failure(command, session))
            return EXIT_DATA
        return _internal(args, exc, session)
    except Exception as exc:  # noqa: BLE001
        return _internal(args, exc, session)


def _after_failure(command, session: Session) -> str:
    """What to do after a run stopped half-way: the command module's ``after_failure``."""
    after = getattr(command, "after_failure", None)
    return after(session) if after is not None else ""


def _internal(args, exc: BaseException, session: Session) -> int:
    if args.debug:
        traceback.print_exc()
    session.err(f"internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback; please report it)")
    if session.record is not None:
        session.record.note("".join(traceback.format_exception(exc)), "spherecal.cli")
    return EXIT_INTERNAL


def _close_record(args, code: int, started: float, session: Session) -> None:
    """The end of the run: the files written into the summary, and the run's record
    appended to run.log in its output folder (when the folder exists)."""
    out = session.out_dir
    files = session.files_written()
    record = session.record
    # the record goes into a folder this run made, wrote into, or that keeps a record already: a
    # folder refused as someone else's (it holds their result) is left untouched
    ours = out is not None and (files or not session.out_existed or RUN_LOG_NAME in session.before)
    if ours and record is not None:
        head = [f"=== spherecal {__version__} {args.command}, started "
                f"{record._stamp(started)}, exit code {code} ({EXIT_MEANING.get(code, 'unknown')}) after "
                f"{time.time() - started:.1f} s",
                f"command line: spherecal {' '.join(args._argv)}"]
        if files:
            head.append("files written: " + ", ".join(sorted(files)))
        record.lines[:0] = head
        try:
            written = record.append_to(out)
        except (OSError, FileWriteError, InputError) as exc:  # the record must not hide the run's own outcome
            print(f"spherecal: warning: {out / RUN_LOG_NAME} not written: {exc}", file=sys.stderr)
            written = None
        if written is not None:
            files.setdefault(RUN_LOG_NAME, str(written))
    session.summary.update(files=files, out_dir=str(out) if out is not None else None)


@contextlib.contextmanager
def _logging(args, session: Session):
    """For one command: logger ``spherecal`` at DEBUG, a console handler on standard
    error (INFO; DEBUG with -v; WARNING with -q) and the run's record (everything).
    spherecal's own Python warnings (a dataset file cut off mid-line:
    :class:`~spherecal.io.dataset.TruncatedFileWarning`) become a ``warning:`` line on that
    logger, once each however often the file is read, so that they reach run.log too;
    other warnings are shown as Python shows them."""
    root = logging.getLogger("spherecal")
    console = logging.StreamHandler(sys.stderr)
    console.setFormatter(logging.Formatter("%(message)s"))
    console.setLevel(logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO)
    saved = root.level
    root.setLevel(logging.DEBUG)
    root.addHandler(console)
    root.addHandler(session.record)
    shown: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if not (getattr(category, "__module__", "") or "").startswith("spherecal."):
            return python_show(message, category, filename, lineno, file, line)
        text = str(message)
        if text not in shown:
            shown.add(text)
            _RUN_LOG(f"warning: {text}")

    with warnings.catch_warnings():
        python_show = warnings.showwarning
        warnings.showwarning = show
        try:
            yield
        finally:
            root.removeHandler(console)
            root.removeHandler(session.record)
            root.setLevel(saved)


def _quiet_broken_stdout() -> None:
    """Standard output's reader went away (``spherecal plugins | head``): point it at
    /dev/null so that the interpreter's last flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # not a real file (a test's capture): nothing to protect
        pass
