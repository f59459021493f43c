"""The ``spherecal`` command line: the parser (:mod:`~spherecal.cli.parser`), the
dispatcher (:mod:`~spherecal.cli.dispatch`) and one module per command, which calls
:mod:`spherecal.app` and prints through :mod:`spherecal.report`; nothing else. Exit
codes: :mod:`spherecal.cli.output` (``spherecal --help``, docs/cli.md)."""

from __future__ import annotations

import os

# Before numpy loads: one BLAS thread unless the user sets another count. A solve is a
# stream of small products (thousands of shots by tens of columns) that threads do not
# speed up, and on a busy machine a thread waiting for its core stalls each one: an
# eye-to-hand recording with the kinematic model took 42 s with two OpenBLAS threads and
# 17 s with one while another process kept a core busy (docs/cli.md, "Threads").
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from spherecal.cli.dispatch import console, main  # noqa: E402 - after the thread settings
from spherecal.cli.output import (EXIT_DATA, EXIT_DEVICE, EXIT_DRIFT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_MEANING,
                                  EXIT_OK, EXIT_PIPE, EXIT_PLUGIN, EXIT_RED, EXIT_USAGE, EXIT_VALIDATION, JSON_SCHEMA)
from spherecal.cli.parser import build_parser

__all__ = ["EXIT_DATA", "EXIT_DEVICE", "EXIT_DRIFT", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_MEANING", "EXIT_OK",
           "EXIT_PIPE", "EXIT_PLUGIN", "EXIT_RED", "EXIT_USAGE", "EXIT_VALIDATION", "JSON_SCHEMA", "build_parser",
           "console", "main"]
