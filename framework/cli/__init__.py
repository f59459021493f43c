"""The ``spherecal`` command line: the parser (:mod:`~spherecal.cli.parser`), the
dispatcher (:mod:`~spherecal.cli.dispatch`) and one module per command, which calls
:mod:`spherecal.app` and prints through :mod:`spherecal.report`; nothing else. Exit
codes: :mod:`spherecal.cli.output` (``spherecal --help``, docs/cli.md)."""

from __future__ import annotations

from spherecal.cli.dispatch import console, main
from spherecal.cli.output import (EXIT_DATA, EXIT_DEVICE, EXIT_DRIFT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_MEANING,
                                  EXIT_OK, EXIT_PIPE, EXIT_PLUGIN, EXIT_RED, EXIT_USAGE, EXIT_VALIDATION, JSON_SCHEMA)
from spherecal.cli.parser import build_parser

__all__ = ["EXIT_DATA", "EXIT_DEVICE", "EXIT_DRIFT", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_MEANING", "EXIT_OK",
           "EXIT_PIPE", "EXIT_PLUGIN", "EXIT_RED", "EXIT_USAGE", "EXIT_VALIDATION", "JSON_SCHEMA", "build_parser",
           "console", "main"]
