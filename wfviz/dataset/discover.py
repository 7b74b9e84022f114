"""The clips of a dataset: a folder searched recursively, or a list file of ``CLIP[=TRUTH]`` lines.

In a folder, a folder holding at least two images is one clip (its subfolders are not searched),
and every video file and ``.npy`` stack is one; hidden entries are skipped. A clip's truth is
found by :func:`wfviz.tune.clips.find_truth`'s rules (``truth.csv`` in the clip folder, or beside
the clip: ``X/frames`` → ``X/truth.csv``); a clip without truth is tracked only. A list file
(``.txt`` or ``.list``) names one clip a line, ``CLIP`` or ``CLIP=TRUTH`` (``#`` starts a comment;
relative paths are relative to the list file; ``synth:SCENARIO[:SEED]`` clips bring their own
truth). Labels (the names of a clip's output files) are unique: the folder's name (``frames``
takes its parent's) or the file's stem, with the parent folder's name put in front of
colliding ones."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from wfviz.io.clip import IMAGE_SUFFIXES, VIDEO_SUFFIXES
from wfviz.synth.scenarios import SYNTH_PREFIX
from wfviz.tune.clips import find_truth, split_spec

LIST_SUFFIXES = (".txt", ".list")
CLIP_FILE_SUFFIXES = (*VIDEO_SUFFIXES, ".npy")
_COMMENT = re.compile(r"(^|\s)#.*$")  # a comment: from a # at the start or after a space
MIN_IMAGES = 2  # a folder with fewer images is not a clip (a preview, a mask, ...)


@dataclass(frozen=True)
class DatasetClip:
    """A clip of a dataset: ``spec`` as :func:`wfviz.io.clip.open_clip` takes it, its truth CSV
    ("" none; a ``synth:`` clip has its own) and a ``label`` unique in the dataset."""

    label: str
    spec: str
    truth: str = ""

    @property
    def synthetic(self) -> bool:
        return self.spec.startswith(SYNTH_PREFIX)


def discover(dataset: Path, exclude: Path | None = None) -> list[DatasetClip]:
    """The clips of ``dataset`` (a folder, a list file or one clip), in a stable order; ``exclude``:
    a folder not searched (the run's output folder). Nothing found, or a list naming a missing
    clip or truth file: ValueError, one line."""
    if dataset.is_file() and dataset.suffix.lower() in LIST_SUFFIXES:
        found = _from_list(dataset)
    elif dataset.is_file() and dataset.suffix.lower() in CLIP_FILE_SUFFIXES:
        found = [(str(dataset), _truth(dataset))]
    elif dataset.is_dir():
        found = [(str(p), _truth(p)) for p in _search(dataset, exclude.resolve() if exclude else None)]
    elif dataset.exists():
        raise ValueError(f"{dataset}: not a dataset (give a folder of clips, a list file "
                         f"({'/'.join(LIST_SUFFIXES)}), a video or a .npy stack)")
    else:
        raise ValueError(f"{dataset}: no such folder or list file")
    if not found:
        raise ValueError(f"{dataset}: no clips found (folders of {MIN_IMAGES} or more images "
                         f"({' '.join(IMAGE_SUFFIXES)}), videos ({' '.join(VIDEO_SUFFIXES)}) or .npy stacks)")
    return [DatasetClip(label, spec, truth) for label, (spec, truth) in zip(labels([s for s, _ in found]), found)]


def _hidden(p: Path) -> bool:
    return p.name.startswith(".")


def _images(folder: Path, names: list[str]) -> int:
    return sum(1 for n in names if not n.startswith(".") and Path(n).suffix.lower() in IMAGE_SUFFIXES
               and (folder / n).is_file())


def _search(root: Path, exclude: Path | None) -> list[Path]:
    """The clips under ``root`` (``root`` itself when it is an image folder), sorted by path."""
    out: list[Path] = []
    for folder, dirs, files in os.walk(root, followlinks=False):
        here = Path(folder)
        if exclude is not None and here.resolve() == exclude:
            dirs[:] = []
            continue
        if _images(here, files) >= MIN_IMAGES:
            out.append(here)
            dirs[:] = []  # a clip folder's subfolders are no clips of their own
            continue
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        out.extend(here / f for f in sorted(files)
                   if not f.startswith(".") and Path(f).suffix.lower() in CLIP_FILE_SUFFIXES)
    return sorted(out, key=lambda p: p.parts)


def _truth(clip: Path) -> str:
    """The truth CSV found for ``clip`` by :func:`find_truth`'s rules, or ""."""
    try:
        found = find_truth(str(clip), None)
    except ValueError:
        return ""
    return str(found) if found is not None else ""


def _from_list(path: Path) -> list[tuple[str, str]]:
    """The ``(clip, truth)`` lines of a list file, relative paths resolved against its folder."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason})") from None
    base = path.parent
    out: list[tuple[str, str]] = []
    seen: dict[str, int] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = _COMMENT.sub("", line).strip()
        if not line:
            continue
        where = f"{path}:{n}"
        spec, truth = split_spec(line)
        if not spec.startswith(SYNTH_PREFIX):
            clip = base / spec
            if not clip.exists():
                raise ValueError(f"{where}: {spec}: no such clip")
            spec = str(clip)
        if spec in seen:
            raise ValueError(f"{where}: {line}: listed twice (first on line {seen[spec]})")
        seen[spec] = n
        if truth is not None:
            t = base / truth
            if not t.is_file():
                raise ValueError(f"{where}: {truth}: no such truth file")
            truth = str(t)
        elif not spec.startswith(SYNTH_PREFIX):
            truth = _truth(Path(spec))
        out.append((spec, truth or ""))
    return out


def _name(spec: str) -> list[str]:
    """The name parts of a clip, innermost first: (name, parent, grandparent, ...)."""
    if spec.startswith(SYNTH_PREFIX):
        return [spec[len(SYNTH_PREFIX):].replace(":", "-")]
    p = Path(os.path.abspath(spec))
    if p.name == "frames" and p.is_dir():
        p = p.parent
    first = p.name if p.is_dir() else p.stem
    return [first or "clip", *(q.name for q in p.parents if q.name)]


def labels(specs: list[str]) -> list[str]:
    """A unique, file-name-safe label per clip: its name, with parent folders' names put in
    front (``set-name``) while it collides with another's, then a counter."""
    parts = [_name(s) for s in specs]
    depth = [1] * len(specs)

    def label(i: int) -> str:
        return "-".join(reversed(parts[i][:depth[i]]))

    while True:
        taken: dict[str, list[int]] = {}
        for i in range(len(specs)):
            taken.setdefault(label(i).lower(), []).append(i)
        grow = [i for same in taken.values() if len(same) > 1 for i in same if depth[i] < len(parts[i])]
        if not grow:
            break
        for i in grow:
            depth[i] += 1
    out: list[str] = []
    used: set[str] = set()
    for i in range(len(specs)):
        base = name = _safe(label(i))
        k = 1
        while name.lower() in used:  # also apart on case-insensitive file systems
            k += 1
            name = f"{base}-{k}"
        used.add(name.lower())
        out.append(name)
    return out


def _safe(label: str) -> str:
    """``label`` usable as a file name: no path separators, control characters or leading dot."""
    cleaned = "".join("_" if c in "/\\\0" or ord(c) < 32 else c for c in label).lstrip(".")
    return cleaned or "clip"
