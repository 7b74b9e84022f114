"""Console-script entry point. Ctrl-C while wfviz is still loading (numpy, OpenCV, Rerun take a
moment to import) or after the command's own handling ends the program with one line and exit
130, never a traceback."""

from __future__ import annotations

import sys


def _interrupted() -> None:
    sys.stderr.write("wfviz: error: interrupted\n")
    sys.exit(130)


def main() -> None:
    """Run the command line (:mod:`wfviz.cli`)."""
    try:
        from wfviz.cli import main as cli_main
    except KeyboardInterrupt:
        _interrupted()
    try:
        cli_main()
    except KeyboardInterrupt:
        _interrupted()


if __name__ == "__main__":
    main()
