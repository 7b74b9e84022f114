"""The clip folders wfviz writes (``wfviz synth``, ``wfviz demo --save-clip``), never over a
user's files.

A folder wfviz writes gets a manifest, ``.wfviz-synth.json``, listing the files it wrote (hidden,
so clip readers skip it). A later run may rewrite that folder: it replaces the listed files and
removes the listed ones it no longer writes (stale frames of a longer clip), and leaves every
other file alone. Any other non-empty folder is refused (:class:`OutputError`, nothing
touched). Files are rendered into a temporary folder beside the target first, which is renamed
into place when the target is new, or whose files are moved in, the manifest first (listing old
and new files, so a run killed half way leaves a folder the next run may still rewrite).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from wfviz.io.outputs import OutputError, remove_stale, temp_dir, write_atomically

MANIFEST = ".wfviz-synth.json"


def _plain_name(name: object) -> bool:
    return (isinstance(name, str) and name not in ("", ".", "..", MANIFEST)
            and not any(c in name for c in "/\\\0"))


def _listed(folder: Path) -> set[str] | None:
    """The file names ``folder``'s manifest lists, or None without a valid manifest."""
    try:
        data = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    files = data.get("files") if isinstance(data, dict) else None
    if not isinstance(files, list) or not all(_plain_name(n) for n in files):
        return None
    return set(files)


def check_folder(folder: Path, what: str = "the clip") -> set[str]:
    """May wfviz write ``what`` into ``folder``? Returns the files an earlier wfviz run wrote
    there (empty: a new or empty folder). :class:`OutputError` (one line, nothing touched) for
    a file, or a non-empty folder without wfviz's manifest."""
    folder = Path(folder)
    if not folder.exists() and not folder.is_symlink():
        for parent in folder.parents:
            if parent.exists() and not parent.is_dir():
                raise OutputError(f"{parent}: is a file, cannot hold the folder {folder.name}")
        return set()
    if not folder.is_dir():
        raise OutputError(f"{folder}: is a file, expected a folder to write {what} into")
    try:
        empty = next(folder.iterdir(), None) is None
    except OSError as exc:
        raise OutputError(f"{folder}: cannot read the folder ({exc.strerror or exc})") from None
    if empty:
        return set()
    listed = _listed(folder)
    if listed is None:
        raise OutputError(f"{folder}: folder is not empty and wfviz did not write it (no {MANIFEST}); "
                          f"nothing written: give a new or empty folder")
    return listed


def _write_manifest(folder: Path, names: set[str], by: str) -> None:
    write_atomically(folder / MANIFEST, json.dumps({"written_by": by, "files": sorted(names)}, indent=1) + "\n")


def write_folder(folder: Path, fill: Callable[[Path], None], *, by: str, what: str = "the clip") -> Path:
    """Write a clip folder: ``fill(tmp)`` writes the files (plain names, no sub-folders) into a
    temporary folder beside ``folder``, which then replaces the files an earlier wfviz run wrote
    in ``folder`` (see the module's description). ``by`` says which command wrote it (kept in
    the manifest). Returns ``folder``."""
    folder = Path(folder)
    check_folder(folder, what)
    place = Path(os.path.abspath(folder))  # "." too: the temporary folder goes beside it, not in it
    try:
        place.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{folder.parent}: cannot create the folder ({exc.strerror or exc})") from None
    remove_stale(place.parent)
    tmp = temp_dir(place)
    try:
        fill(tmp)
        new = {p.name for p in tmp.iterdir()}
        bad = [n for n in new if not _plain_name(n) or (tmp / n).is_dir()]
        if bad:  # a programming error, not bad input
            raise RuntimeError(f"cannot write {bad[0]!r} into a clip folder")
        _write_manifest(tmp, new, by)
        if not folder.exists() and not folder.is_symlink():
            try:
                os.replace(tmp, folder)
                return folder
            except OSError:  # created meanwhile: merge into it below
                pass
        _merge(tmp, folder, new, by, what)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def _merge(tmp: Path, folder: Path, new: set[str], by: str, what: str) -> None:
    """Move ``tmp``'s files into the existing ``folder`` (new or empty, or written by wfviz),
    then remove the files of the earlier run that this one did not write again."""
    old = check_folder(folder, what)
    taken = sorted(n for n in new if n not in old and (folder / n).exists())
    if taken:
        raise OutputError(f"{folder / taken[0]}: a file wfviz did not write has this name; "
                          f"nothing written: move it or give a new folder")
    _write_manifest(folder, old | new, by)  # a run killed from here on leaves a folder wfviz may rewrite
    for name in sorted(new):
        os.replace(tmp / name, folder / name)
    for name in sorted(old - new):
        if not (folder / name).is_dir():
            (folder / name).unlink(missing_ok=True)
    os.replace(tmp / MANIFEST, folder / MANIFEST)
