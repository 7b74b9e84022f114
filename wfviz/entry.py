"""Console-script entry point. Ctrl-C while wfviz is still loading (numpy, OpenCV, Rerun take a
moment to import) or after the command's own handling ends the program with one line and exit
130, never a traceback."""

from __future__ import annotations

import codecs
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


def _escape(exc: UnicodeError) -> tuple[str, int]:
    """Output error handler: a byte of a non-UTF-8 file name (a lone surrogate U+DC80-U+DCFF, as
    Python holds it) printed as ``\\xff``, any other unprintable character backslash-escaped."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    text = exc.object[exc.start:exc.end]
    if all(0xDC80 <= ord(c) <= 0xDCFF for c in text):
        return "".join(f"\\x{ord(c) - 0xDC00:02x}" for c in text), exc.end
    return codecs.backslashreplace_errors(exc)


#: commands whose process writes a recording and ends: pyarrow need not import pandas there
#: (:func:`wfviz.record.arrow.arrow_without_pandas`)
WRITE_ONLY = ("record", "demo")


def _command(argv: list[str]) -> str | None:
    """The command named on the command line (its first word that is not an option)."""
    return next((a for a in argv if not a.startswith("-")), None)


def main() -> None:
    """Run the command line (:mod:`wfviz.cli`)."""
    codecs.register_error("wfviz-escape", _escape)
    for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 is printed, not fatal
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="wfviz-escape")
    previous = signal.signal(signal.SIGINT, _exit_now)
    try:
        if _command(sys.argv[1:]) in WRITE_ONLY and not {"--help", "-h"} & set(sys.argv[1:]):
            from wfviz.record.arrow import arrow_without_pandas

            arrow_without_pandas()
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
