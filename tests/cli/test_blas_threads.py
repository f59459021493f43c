"""The command line runs BLAS on one thread unless the user sets a count: its small
products only stall when a thread waits for a busy core (docs/cli.md, "Threads")."""

import os
import subprocess
import sys

import pytest

PROBE = ("import sys, os; import spherecal; loaded = 'numpy' in sys.modules; import spherecal.cli; "
         "print(loaded, os.environ.get('OPENBLAS_NUM_THREADS'), os.environ.get('OMP_NUM_THREADS'))")


@pytest.mark.parametrize("given, expected", [(None, "1"), ("3", "3")])
def test_the_command_line_sets_one_blas_thread_before_numpy_loads(given, expected):
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True).stdout
    numpy_before, openblas, omp = out.split()
    assert numpy_before == "False"  # numpy reads the variable when it loads: it must not have loaded yet
    assert (openblas, omp) == (expected, "1")
