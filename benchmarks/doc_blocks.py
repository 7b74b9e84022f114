"""Helpers for generated docs: replace a marked block in a page, describe the machine."""

from __future__ import annotations

import importlib.metadata as md
import os
import platform
import re
import sys
from pathlib import Path


def write_block(doc: Path, begin: str, end: str, block: str, heading: str | None = None) -> None:
    """Put ``block`` between the ``begin``/``end`` markers of ``doc`` (the markers are kept).

    Without the markers: append ``heading`` and a new marked block if a heading is given,
    else exit with an error naming the page.
    """
    text = doc.read_text(encoding="utf-8")
    if begin not in text or end not in text:
        if heading is None:
            sys.exit(f"{doc}: markers {begin} / {end} not found")
        text += f"\n{heading}\n\n{begin}\n{end}\n"
    text = re.sub(re.escape(begin) + ".*?" + re.escape(end), lambda _: f"{begin}\n{block}\n{end}",
                  text, flags=re.S)
    doc.write_text(text, encoding="utf-8")
    print(f"wrote {doc}")


def machine(packages: tuple[str, ...] = ()) -> str:
    """CPU model, cores, OS, Python and the installed versions of ``packages``."""
    model = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                  if ln.startswith("model name")), platform.processor() or "unknown CPU")
    versions = "".join(f", {p} {md.version(p)}" for p in packages)
    return (f"{model}, {os.cpu_count()} cores ({platform.system()} {platform.release()}), "
            f"Python {platform.python_version()}{versions}")
