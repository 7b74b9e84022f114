"""The study folder of ``wfviz tune``: which files the study owns there (a manifest), one study
process at a time (a lock), and the checks that keep every input of the command out of reach of
every file the study writes. All checks run before anything is written."""

from __future__ import annotations

import fcntl
import fnmatch
import json
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from wfviz.io.outputs import OutputError, remove_stale, temp_dir, write_atomically

MANIFEST = ".wfviz-study.json"
JOURNAL = "study.journal"
#: files at the top of the folder that a study writes (best-N.toml: one per Pareto point)
OWNED_NAMES = (JOURNAL, f"{JOURNAL}.lock", "trials.csv", "best.toml", "pareto.csv", "report.md",
               "study.rrd", "history.png", "pareto.png", "importance.png", "tune_vs_validation.png")
OWNED_PATTERNS = ("best-*.toml",)
#: sub-folders holding the study's files: the truth of synth: clips, --record-best's recordings
OWNED_FOLDERS = {"truth": "*.csv", "recordings": "trial-*.rrd"}


def _place(path: Path) -> Path:
    """Where ``path`` is written: its folder resolved, its own name kept (a symlink there is
    replaced, not followed)."""
    path = Path(path)
    return path.parent.resolve() / path.name


def _inside(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies inside it (both resolved)."""
    return path == folder or folder in path.parents


class StudyFolder:
    """The folder ``path`` of a study. :meth:`check_inputs` and :meth:`check_foreign` refuse
    (``OutputError``, one line) before anything is written; :meth:`lock` holds the folder for
    this process; :meth:`write` and :meth:`claim` record what the study wrote in its manifest,
    and :meth:`remove` deletes only such files."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._root = self.path.resolve()
        self._owned: set[str] = self._read_manifest()

    # -- what the study owns -------------------------------------------------------------
    def _read_manifest(self) -> set[str]:
        file = self.path / MANIFEST
        if not file.is_file():
            if (self.path / JOURNAL).is_file():  # a study written before the manifest existed
                return {rel for rel in self._owned_names_present()}
            return set()
        try:
            data = json.loads(file.read_text(encoding="utf-8"))
            return {str(f) for f in data["files"]}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise OutputError(f"{file}: not a readable study manifest ({exc})") from None

    def _owned_names_present(self) -> Iterator[str]:
        try:
            entries = list(self.path.iterdir())
        except OSError:
            return
        for e in entries:
            if e.is_file() and self.study_name(e.name):
                yield e.name
            elif e.is_dir() and e.name in OWNED_FOLDERS:
                for f in e.iterdir():
                    if f.is_file() and fnmatch.fnmatch(f.name, OWNED_FOLDERS[e.name]):
                        yield f"{e.name}/{f.name}"

    @staticmethod
    def study_name(name: str) -> bool:
        """``name`` (at the top of the folder) is one a study writes."""
        return name in OWNED_NAMES or any(fnmatch.fnmatch(name, p) for p in OWNED_PATTERNS)

    def owns_place(self, path: Path) -> bool:
        """``path`` (resolved) is where the study may write: an owned name at the top of the
        folder, anything in its owned sub-folders, or a temporary work folder of a trial."""
        if not _inside(path, self._root) or path == self._root:
            return False
        parts = path.relative_to(self._root).parts
        return (parts[0] in OWNED_FOLDERS or parts[0] == MANIFEST or parts[0].startswith(".work.")
                or (len(parts) == 1 and self.study_name(parts[0])))

    # -- checks (nothing written) --------------------------------------------------------
    def check_inputs(self, files: Iterable[tuple[Path, str]], clip_folders: Iterable[tuple[Path, str]]) -> None:
        """Refuse an input file in a place the study writes, and a clip folder that is the
        study folder, holds it or lies inside it."""
        for p, what in files:
            if self.owns_place(_place(p)) or self.owns_place(Path(p).resolve()):
                raise OutputError(f"{p}: {what} lies where the study in {self.path} writes its files; "
                                  "move it or choose another --out")
        for folder, what in clip_folders:
            f = Path(folder).resolve()
            if _inside(self._root, f):
                raise OutputError(f"--out {self.path}: is or lies inside {what} {folder}; "
                                  "the study's files would join its frames")
            if _inside(f, self._root):
                raise OutputError(f"--out {self.path}: holds {what} {folder}; choose a study folder apart from the clips")

    def check_foreign(self) -> None:
        """Refuse a folder holding files with the study's names that this study did not write
        (a user's ``report.md``, ``best-3.toml``, ``truth/x.csv`` would be replaced)."""
        for rel in self._owned_names_present():
            if rel not in self._owned and rel != f"{JOURNAL}.lock":
                raise OutputError(f"{self.path / rel}: exists and was not written by this study; "
                                  "move it or choose another --out")

    # -- the lock ------------------------------------------------------------------------
    @contextmanager
    def lock(self) -> Iterator[None]:
        """Create the folder if needed and hold it for this process (a second ``wfviz tune`` on
        it is refused). Nothing else is written: the checks run under the lock, then
        :meth:`clear_stale`. A refusal (any exception) removes again the folders created here,
        when nothing was written into them."""
        created = [f for f in (self.path, *self.path.parents) if not f.exists()]
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot create the study folder ({exc.strerror})") from None
        ok = False
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_DIRECTORY)
            try:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    raise OutputError(f"{self.path}: in use by another wfviz tune; wait for it to end "
                                      "or choose another --out") from None
                yield
                ok = True
            finally:
                os.close(fd)
        finally:
            if not ok:
                for folder in created:  # deepest first; only if still empty
                    try:
                        folder.rmdir()
                    except OSError:
                        break

    def clear_stale(self) -> None:
        """Remove the temporary files and work folders of killed runs (once the study is
        accepted: a refused command changes nothing)."""
        remove_stale(self.path)

    # -- writing -------------------------------------------------------------------------
    def claim(self, path: Path) -> Path:
        """Record ``path`` (in the folder) as the study's before it is written."""
        rel = _place(path).relative_to(self._root).as_posix()
        if rel not in self._owned:
            if Path(path).exists() or Path(path).is_symlink():
                raise OutputError(f"{path}: exists and was not written by this study")
            self._owned.add(rel)
            write_atomically(self.path / MANIFEST,
                             json.dumps({"files": sorted(self._owned)}, indent=1) + "\n")
        return Path(path)

    def write(self, path: Path, data: bytes | str) -> Path:
        """Write a study file whole to a temporary name, renamed into place (claimed first; its
        sub-folder made if needed); a file that already holds ``data`` is not touched."""
        self.claim(path)
        data = data.encode("utf-8", "surrogateescape") if isinstance(data, str) else data
        try:
            if Path(path).read_bytes() == data:
                return Path(path)  # the same: left as it is (its time too)
        except OSError:
            pass
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        write_atomically(Path(path), data)
        return Path(path)

    def remove(self, path: Path) -> None:
        """Delete ``path`` only if the study wrote it."""
        rel = _place(path).relative_to(self._root).as_posix()
        if rel in self._owned:
            Path(path).unlink(missing_ok=True)
            self._owned.discard(rel)
            write_atomically(self.path / MANIFEST,
                             json.dumps({"files": sorted(self._owned)}, indent=1) + "\n")

    def owned(self, pattern: str) -> list[Path]:
        """The study's files whose relative path matches ``pattern``."""
        return [self.path / rel for rel in sorted(self._owned) if fnmatch.fnmatch(rel, pattern)]

    def work_dir(self) -> Path:
        """A new temporary folder for the trials' tracks CSVs (``.work.PID.RANDOM.wfviz-part``,
        removed by the run, or as stale by the next one)."""
        return temp_dir(self.path / "work")
