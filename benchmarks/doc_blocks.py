"""Replace a generated block between two HTML-comment markers in a docs page."""

from __future__ import annotations

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
