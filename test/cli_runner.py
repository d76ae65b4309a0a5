"""`srmosaic ...` run in the test's own process, for the checks of what a command refuses.

A command that stops on bad input stops before any work, and the console script is only
``sys.exit(srmosaic_ros.cli.main())``: calling ``main(argv)`` here runs the same code and prints the same
lines, without paying a fresh interpreter's import of torch, filterpy and scipy for each case. The runs
that do the work, and the checks of what only a separate process shows (exit status of the
interpreter, signals, resource limits), keep `subprocess`.
"""
from __future__ import annotations

import contextlib
import io
import logging
import subprocess

from srmosaic_ros.cli import main


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """``srmosaic *args`` in this process: its exit status, stdout and stderr, as subprocess.run gives them."""
    out, err = io.StringIO(), io.StringIO()
    # In a process of its own the command configures no logging, so its warnings reach stderr through
    # logging.lastResort: WARNING and above, the message alone. Here pytest's handlers would take them.
    said = logging.StreamHandler(err)
    said.setLevel(logging.WARNING)
    logging.getLogger().addHandler(said)
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's usage errors and --help
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        finally:
            logging.getLogger().removeHandler(said)
    return subprocess.CompletedProcess(['srmosaic', *args], code, out.getvalue(), err.getvalue())
