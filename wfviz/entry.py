"""Console-script entry point. Ctrl-C while wfviz is still loading (numpy, OpenCV, Rerun take a
moment to import) or after the command's own handling ends the program with one line and exit
130, never a traceback."""

from __future__ import annotations

import os
import signal
import sys


def _interrupted() -> None:
    sys.stderr.write("wfviz: error: interrupted\n")
    sys.exit(130)


def _exit_now(signum: int, frame: object) -> None:
    """SIGINT while loading: nothing is written yet, so leave at once. Raising KeyboardInterrupt
    here could be swallowed by a third-party import's bare ``except`` (seen: exit 0)."""
    sys.stderr.write("wfviz: error: interrupted\n")
    sys.stderr.flush()
    os._exit(130)


def main() -> None:
    """Run the command line (:mod:`wfviz.cli`)."""
    for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 is printed, not fatal
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    previous = signal.signal(signal.SIGINT, _exit_now)
    try:
        from wfviz.cli import main as cli_main
    except KeyboardInterrupt:
        _interrupted()
    signal.signal(signal.SIGINT, previous)
    try:
        cli_main()
    except KeyboardInterrupt:
        _interrupted()


if __name__ == "__main__":
    main()
