"""``python -m msam_torch`` and the ``msam`` console command (:func:`command`):
:func:`~msam_torch.cli.main.main` on the process's arguments, then the process ends at once with
its status.

Its files are written and closed, its exit handlers run and its streams flushed; the interpreter's
teardown of every module (torch's alone costs about a third of a second, as much as a short
diagnosis's figures) is skipped (:func:`os._exit`), unless a profiler or tracer (cProfile, coverage)
is attached: they write their reports at that teardown.
"""
from __future__ import annotations

import atexit
import os
import sys

from msam_torch.cli.main import main


def command() -> None:
    status = main()
    if sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(status)
    atexit._run_exitfuncs()  # what the interpreter runs at exit before its teardown (logging's flush among them)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed or broken: main has said so on stderr where it could
            pass
    os._exit(status)


if __name__ == "__main__":
    command()
