"""Output files written atomically: to a unique temporary file beside the target, renamed
into place only when complete, and never over an input of the command."""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Iterable
from pathlib import Path

from wfviz.io.clip import IMAGE_SUFFIXES

TEMP_SUFFIX = ".wfviz-part"
#: ``.NAME.PID.RANDOM.wfviz-part``: a temporary output of process PID (see :func:`temp_path`)
_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[^.]+" + re.escape(TEMP_SUFFIX) + "$")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()
MIN_FREE = 1 << 20  # bytes: below this an output folder counts as full (Rerun's writer hangs on a full disk)


class OutputError(OSError):
    """An output path cannot be written (one-line message naming it)."""


def temp_path(path: Path) -> Path:
    """A new empty file beside ``path``, unique to this call (``.NAME.PID.RANDOM.wfviz-part``):
    two runs writing the same output never share a temporary file, and a run killed before
    renaming leaves a name :func:`remove_stale` recognises."""
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=TEMP_SUFFIX, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp's 0600 would make the output private
    finally:
        os.close(fd)
    return Path(name)


def temp_dir(path: Path) -> Path:
    """A new empty folder beside ``path``, named as :func:`temp_path` names files."""
    return Path(tempfile.mkdtemp(prefix=f".{path.name}.{os.getpid()}.", suffix=TEMP_SUFFIX, dir=path.parent))


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale(folder: Path) -> list[Path]:
    """Remove the temporary outputs in ``folder`` left by wfviz processes that no longer run
    (killed before they could clean up); returns what was removed."""
    removed = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = _TEMP_NAME.match(entry.name)
        if m is None or _alive(int(m["pid"])):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed.append(entry)
        except OSError:
            pass
    return removed


def same_file(a: Path, b: Path) -> bool:
    """``a`` and ``b`` name the same file (symlinks and hard links resolved)."""
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_not_inputs(outputs: Iterable[Path | None], inputs: Iterable[tuple[Path, str]],
                     input_folders: Iterable[Path] = ()) -> None:
    """Refuse (``OutputError``) an output that would replace an input of the command (``inputs``:
    (path, what it is), e.g. a clip frame, the truth, config or recording file; symlinks and hard
    links resolved), or any file already in an input image folder, or an image file there (it
    would join the clip), or that names the same file as another output, or a folder. Nothing is
    written.

    Cost: a few system calls per output, plus one per input only for an output that resolves
    into an input folder or replaces an existing file."""
    ins = [(Path(p), what) for p, what in inputs]
    folders = {Path(f).resolve() for f in input_folders}
    parents: dict[Path, Path] = {}
    for p, _ in ins:
        if p.parent not in parents:
            parents[p.parent] = p.parent.resolve()
    loose = [(p, what) for p, what in ins if parents[p.parent] not in folders]  # truth, config, ...
    seen: list[Path] = []
    for out in outputs:
        if out is None:
            continue
        out = Path(out)
        target = out.resolve()
        if target.is_dir():  # refused here, before an output folder is touched
            raise OutputError(f"{out}: is a folder, expected a file name")
        for p, what in loose:
            if same_file(out, p):
                raise OutputError(f"{out}: output would overwrite {what}")
        if target.parent in folders:
            for p, what in ins:  # name the input it would replace, if it is one
                if p.resolve() == target:
                    raise OutputError(f"{out}: output would overwrite {what}")
            if target.exists() or target.suffix.lower() in IMAGE_SUFFIXES:
                raise OutputError(f"{out}: output would overwrite or join the frames of the input folder "
                                  f"{target.parent}")
        elif target.is_file():  # replacing a file: is it an input under another name (a frame
            # that is a symlink to it, a hard link)? one stat per input, only in this case
            key = (target.stat().st_dev, target.stat().st_ino)
            for p, what in ins:
                try:
                    st = p.stat()
                except OSError:
                    continue
                if (st.st_dev, st.st_ino) == key:
                    raise OutputError(f"{out}: output would overwrite {what}")
        for other in seen:
            if same_file(out, other) or target == other.resolve():
                raise OutputError(f"{out}: two outputs of this command have the same name")
        seen.append(out)


def replace_into(temp: Path, path: Path) -> None:
    """Rename the finished temporary file ``temp`` to ``path`` (atomic, replacing an older
    file); an OSError becomes a one-line OutputError naming ``path``."""
    try:
        os.replace(temp, path)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None


def write_atomically(path: Path, data: bytes | str) -> None:
    """Write ``data`` to ``path`` through a unique temporary file (removed on any error)."""
    tmp = temp_path(path)
    try:
        try:
            # text naming a file whose name is not UTF-8 keeps that name's own bytes
            tmp.write_bytes(data.encode("utf-8", "surrogateescape") if isinstance(data, str) else data)
        except OSError as exc:
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None
        replace_into(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def check_writable(path: Path) -> None:
    """Create the parent folder if needed and check a file can be written there."""
    parent = path.parent
    for folder in (parent, *parent.parents):
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{folder}: is a file, cannot hold the output {path.name}")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{parent}: cannot create output folder ({exc.strerror})") from None
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, expected a file name")
    try:
        free = shutil.disk_usage(parent).free
    except OSError:
        free = MIN_FREE
    if free < MIN_FREE:
        raise OutputError(f"{parent}: output folder is full ({free // 1024} kB free)")
    probe = parent / f".wfviz-probe-{os.getpid()}"
    try:  # a real write: os.access says yes to root even on read-only mounts
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputError(f"{parent}: output folder is not writable ({exc.strerror})") from None


class TextOutput:
    """A text file written to a unique temporary name beside ``path`` (:func:`temp_path`) and
    renamed into place by :meth:`close` (:meth:`abort`: removed). ``header``: its first line.
    Write errors are :class:`OutputError` naming ``path``."""

    def __init__(self, path: Path, header: str = "", newline: str = "\r\n") -> None:
        self.path = path
        self.temp = temp_path(path)
        self.newline = newline
        try:
            self._fh = open(self.temp, "w", newline="", encoding="utf-8")
            if header:
                self._fh.write(header + newline)
        except OSError as exc:
            self.temp.unlink(missing_ok=True)
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc})") from None

    def write(self, text: str) -> None:
        """Append ``text`` as it is."""
        try:
            self._fh.write(text)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write ({exc.strerror or exc})") from None

    def close(self) -> None:
        """Flush, close and rename into place."""
        try:
            self._fh.close()
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write ({exc.strerror or exc})") from None
        replace_into(self.temp, self.path)

    def abort(self) -> None:
        """Close and remove the partial file."""
        try:
            self._fh.close()
        except OSError:  # e.g. the disk is full: the buffered rows cannot be flushed
            pass
        self.temp.unlink(missing_ok=True)
