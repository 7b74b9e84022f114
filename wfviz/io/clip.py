"""Open a recorded clip (video file, image folder or .npy stack) as a streamed ``Clip``.

Video luma (measured on opencv-python-headless 5.0, FFmpeg backend). With
``CAP_PROP_CONVERT_RGB = 0`` the backend returns the decoder's first plane as an (H, W)
uint8 array; for 8-bit planar YUV and grey streams that is the Y plane. It logs
"Unknown/unsupported picture format ... treated as 8UC1" once per frame, so reads on that
path run with OpenCV logging at ERROR. OpenCV exposes neither the stream's colour range
nor yuv vs yuvj (both report ``I420``), so ``VideoClip`` measures it: on open it decodes
the first few frames both raw and as BGR, and picks one of these modes:

* ``"raw"``: the Y plane as stored. Used when OpenCV's BGR output equals Y (full-range
  streams: MJPG, FFV1 grey), or when a limited-range stream holds Y values well outside
  16-235. Such values mean the producer stored sensor values in Y directly, and the BGR
  conversion would stretch them and clip them to 0/255.
* ``"expand"``: Y mapped 16-235 -> 0-255 with a lookup table, the inverse of the
  compression OpenCV's own writer (and standard encoders) apply. Gives the same values as
  OpenCV's BGR output, without the colour conversion.
* ``"bgr"`` (fallback): BGR output reduced with ``cv2.cvtColor(BGR2GRAY)``. Used when the
  backend is not FFmpeg, the pixel format is not 8-bit planar YUV or grey, or the raw plane
  does not match the decoded picture. Values are stretched, and clipped outside 16-235 for
  limited-range streams.

Pass ``luma=`` to ``VideoClip`` to force a mode.
"""

from __future__ import annotations

import itertools
import math
import os
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from wfviz.io.frames import Clip, Frame

VIDEO_SUFFIXES = (".avi", ".mkv", ".mov", ".mp4")
IMAGE_SUFFIXES = (".bmp", ".png", ".tif", ".tiff")
DEFAULT_FPS = 20.0
#: Files wfviz itself writes beside image frames (``wfviz synth``, ``demo --save-clip``):
#: skipped without a warning.
COMPANION_FILES = frozenset({"truth.csv", "meta.json"})
FRAMES_SUBFOLDER = "frames"  # CLIP/frames/ beside CLIP/truth.csv: opened when CLIP itself holds no images
SUPPORTED = (f"a video ({' '.join(VIDEO_SUFFIXES)}), a folder of images "
             f"({' '.join(IMAGE_SUFFIXES)}), a .npy stack or synth:SCENARIO")
#: Clip sources named by a prefix (``synth:`` for the built-in scenarios), registered by the
#: packages that provide them (:func:`register_source`): ``prefix -> opener(spec, fps)``.
SOURCES: dict[str, Callable[[str, float | None], Clip]] = {}
#: Built-in prefixes and the module that registers each, imported when a spec first uses it.
PROVIDERS = {"synth:": "wfviz.synth.scenarios"}

LumaMode = Literal["auto", "raw", "expand", "bgr"]
#: Codec pixel-format tags (``CAP_PROP_CODEC_PIXEL_FORMAT``) whose first plane is 8-bit luma.
_PLANAR_LUMA_TAGS = frozenset({"I420", "IYUV", "YV12", "Y41B", "Y42B", "YV16", "444P", "YV24",
                               "440P", "YUV9", "YVU9", "NV12", "NV21", "Y800", "Y8  ", "GREY"})
_EXPAND = np.clip(np.round((np.arange(256) - 16) * 255 / 219), 0, 255).astype(np.uint8)
_PROBE_FRAMES = 5
_FIT_TOLERANCE = 3.0  # mean levels: a raw plane further than this from BGR is not luma
_RANGE_MARGIN = 8  # levels outside 16-235 that lossy coding of limited-range video can't reach
_RANGE_FRACTION = 1e-3  # share of probe pixels beyond that margin that proves raw sensor Y


#: Smallest frame side the pipeline accepts (the 5x5 suppression, 9 px centroid window and
#: horizon gradient/variance windows with their margins fit, with room to spare); checked by
#: ``wfviz.run`` with the tracker's configured windows, not when a clip is opened.
MIN_SIDE = 16
#: Most pixels a frame may have (8192x8192): the stages hold several float32 copies of a frame,
#: so larger frames would exhaust memory part way through. Checked when a clip is opened (for a
#: .npy from its header, before any pixel is read) and by ``wfviz.run``.
MAX_PIXELS = 1 << 26
#: Float frames whose spread (median absolute deviation of the first frame read) lies outside
#: 2**FLOAT_SPREAD[0] .. 2**FLOAT_SPREAD[1] are rescaled by a power of two that brings it to
#: 2**FLOAT_TARGET (see ``_ClipBase._rescale``); integer frames are never rescaled.
FLOAT_SPREAD = (-8, 32)
FLOAT_TARGET = 10
_MAX_SCALED = 2.0 ** 64  # largest rescaled value: squares stay within float32


class ClipError(ValueError):
    """Bad clip input; the message is one line: ``"<path>: <problem>"``."""


class ClipWarning(UserWarning):
    """Input that was read with a workaround (skipped file or frame, replaced NaN); one line."""


class ClipNote(ClipWarning):
    """Input that was converted as documented (colour to luma); one line."""


class BadFrameError(ClipError):
    """One frame cannot be decoded (``skip_bad_frames`` would skip it)."""


def open_clip(path: str | Path, fps: float | None = None, *, skip_bad_frames: bool = False,
              nan_as_zero: bool = False) -> Clip:
    """Open a video file, a folder of images, a .npy stack or ``synth:SCENARIO[:SEED]`` (a
    built-in scenario generated lazily); ``fps`` overrides the source's.

    ``skip_bad_frames``: an undecodable image or video frame is skipped with a
    :class:`ClipWarning` (its index is left out, listed in ``clip.skipped``) instead of
    raising. ``nan_as_zero``: NaN/inf pixels of float frames become 0 (warned once) instead
    of raising.
    """
    for prefix, module in PROVIDERS.items():
        if prefix not in SOURCES and str(path).startswith(prefix):
            import importlib

            importlib.import_module(module)
    for prefix, opener in SOURCES.items():
        if str(path).startswith(prefix):
            return opener(str(path), fps)
    p = Path(path)
    if not p.exists():
        raise ClipError(f"{p}: no such file or folder")
    if p.is_dir():
        folder, name = _frames_folder(p), None
        if folder != p:
            name = p.name or p.resolve().name
            warnings.warn(f"{p}: no images in the folder itself; reading {folder}", ClipNote, stacklevel=2)
        return ImageFolderClip(folder, fps, skip_bad_frames=skip_bad_frames, nan_as_zero=nan_as_zero,
                               name=name)
    suffix = p.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        return VideoClip(p, fps, skip_bad_frames=skip_bad_frames)
    if suffix == ".npy":
        return NpyClip(p, fps, nan_as_zero=nan_as_zero)
    raise ClipError(f"{p}: unsupported input; expected {SUPPORTED}")


def register_source(prefix: str, opener: Callable[[str, float | None], Clip]) -> None:
    """:func:`open_clip` opens a spec starting with ``prefix`` with ``opener(spec, fps)``
    (``wfviz.synth`` registers ``synth:SCENARIO[:SEED]`` when imported)."""
    SOURCES[prefix] = opener


def check_frame_size(shape: tuple[int, int], source: str | Path, minimum: int = MIN_SIDE) -> None:
    """Raise ClipError when frames of ``shape`` (rows, columns) are below ``minimum`` a side
    or have more than :data:`MAX_PIXELS` pixels."""
    if shape[0] * shape[1] > MAX_PIXELS:
        raise ClipError(f"{source}: frames are {shape[1]}x{shape[0]} ({shape[0] * shape[1]:,} pixels), "
                        f"larger than wfviz reads ({MAX_PIXELS:,} pixels a frame, e.g. 8192x8192)")
    if min(shape) < minimum:
        raise ClipError(f"{source}: frames are {shape[1]}x{shape[0]}, smaller than the "
                        f"processing windows need (at least {minimum}x{minimum})")


class _ClipBase:
    """Read-only ``Clip`` properties shared by the readers."""

    files: Sequence[Path] = ()  # an image folder's, one per frame

    def __init__(self, path: Path, name: str, fps: float, n_frames: int | None,
                 shape: tuple[int, int], nan_as_zero: bool = False) -> None:
        check_frame_size(shape, path, minimum=1)  # too large: refused before any frame is read
        self.path = path
        self._name, self._fps, self._n_frames, self._shape = name, fps, n_frames, shape
        self.nan_as_zero = nan_as_zero
        self._nan_warned = False
        #: float frames are multiplied by 2**gain_exponent (None: not set yet; see ``_rescale``)
        self.gain_exponent: int | None = None
        #: frames left out with ``skip_bad_frames``: index -> problem
        self.skipped: dict[int, str] = {}

    @property
    def name(self) -> str:
        """Short name: the file stem or folder name."""
        return self._name

    @property
    def fps(self) -> float:
        """Frames per second used for timestamps."""
        return self._fps

    @property
    def n_frames(self) -> int | None:
        """Number of frames if known in advance, else None."""
        return self._n_frames

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of every frame."""
        return self._shape

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({str(self.path)!r}, fps={self.fps:g}, "
                f"n_frames={self.n_frames}, shape={self.shape})")

    def _frame(self, index: int, image: np.ndarray, source: str) -> Frame:
        """Wrap ``image`` as frame ``index``, checking it matches the clip's shape."""
        if image.shape != self._shape:
            raise ClipError(f"{source}: frame {index} is {image.shape[1]}x{image.shape[0]}, "
                            f"expected {self._shape[1]}x{self._shape[0]}")
        if image.dtype.kind == "f":
            image = self._rescale(index, self._finite(index, image, source), source)
        return Frame(index, index / self._fps, np.ascontiguousarray(image))

    def _rescale(self, index: int, image: np.ndarray, source: str) -> np.ndarray:
        """Float ``image`` times 2**k, k fixed by the first frame read (a note when k != 0).

        Float clips come in any unit (1e-40 to 1e30 a grey level). The stages' arithmetic is
        float32 (squares in variances underflow to 0 near 1e-20 and overflow near 1e19) and has
        floors in grey levels (1e-6 for a noise sigma, ...), so frames whose spread lies outside
        2**-8 .. 2**32 are brought to a spread of about 2**10, like integer data. A power of two
        changes only the exponent: the values are exact, just in other units, and the tracks
        (pixel positions) do not depend on it. Frames within the range are returned as read."""
        if self.gain_exponent is None:
            self.gain_exponent = _gain_exponent(image)
            if self.gain_exponent:
                warnings.warn(f"{source}: float frames rescaled by 2**{self.gain_exponent} (frame {index}'s "
                              f"spread, {_spread(image):.3g}, is outside 2**{FLOAT_SPREAD[0]}..2**"
                              f"{FLOAT_SPREAD[1]}); tracks are unaffected, recorded values are in the new "
                              f"units", ClipNote, stacklevel=4)
        if not self.gain_exponent:
            return image
        with np.errstate(over="ignore"):
            scaled = np.ldexp(image, self.gain_exponent, dtype=image.dtype)
        if not float(np.abs(scaled).max()) <= _MAX_SCALED:
            raise ClipError(f"{source}: frame {index} holds values up to {float(np.abs(image).max()):.3g}, "
                            f"too large at the clip's scale (x2**{self.gain_exponent}, set by the first "
                            f"frame read; values must stay within 2**64 after it)")
        return scaled

    def _finite(self, index: int, image: np.ndarray, source: str) -> np.ndarray:
        """``image`` with NaN/inf set to 0 if ``nan_as_zero`` (warned once), else ClipError."""
        finite = np.isfinite(image)
        if finite.all():
            return image
        bad = int(finite.size - np.count_nonzero(finite))
        if not self.nan_as_zero:
            raise ClipError(f"{source}: frame {index} has {bad} NaN or infinite pixels "
                            f"(--nan-as-zero replaces them with 0)")
        if not self._nan_warned:
            self._nan_warned = True
            warnings.warn(f"{source}: frame {index} has {bad} NaN or infinite pixels, replaced by 0 "
                          f"(later frames are not reported)", ClipWarning, stacklevel=2)
        return np.where(finite, image, image.dtype.type(0))

    def _skip(self, indices: list[int], problem: str) -> None:
        """Record and warn (once) that frames ``indices`` are left out."""
        self.skipped.update((i, problem) for i in indices)
        warnings.warn(f"{problem}; skipped (--skip-bad-frames)", ClipWarning, stacklevel=3)


def _frames_folder(folder: Path) -> Path:
    """``folder``, or its ``frames`` sub-folder when only that holds the images (the layout
    ``CLIP/frames/``, ``CLIP/truth.csv``, ``CLIP/meta.json`` of scene generators)."""
    sub = folder / FRAMES_SUBFOLDER
    if not sub.is_dir() or any(_is_image(e) for e in folder.iterdir()):
        return folder
    return sub if any(_is_image(e) for e in sub.iterdir()) else folder


def _is_image(p: Path) -> bool:
    return not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()


class ImageFolderClip(_ClipBase):
    """A folder of PNG/TIFF/BMP images in file-name order; hidden files, ``truth.csv`` and
    ``meta.json`` are skipped, other entries too with a :class:`ClipWarning`."""

    def __init__(self, folder: Path, fps: float | None = None, *, skip_bad_frames: bool = False,
                 nan_as_zero: bool = False, name: str | None = None) -> None:
        visible = sorted((p for p in folder.iterdir() if not p.name.startswith(".")),
                         key=lambda p: p.name)
        files = [p for p in visible if _is_image(p)]
        if not files:
            raise ClipError(f"{folder}: no images ({' '.join(IMAGE_SUFFIXES)}) in folder")
        others = [p.name for p in visible if p not in files and p.name not in COMPANION_FILES]
        if others:
            listed = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
            warnings.warn(f"{folder}: skipping {len(others)} non-image "
                          f"{'entry' if len(others) == 1 else 'entries'} ({listed})", ClipWarning,
                          stacklevel=3)
        self.files = files
        self.skip_bad_frames = skip_bad_frames
        self._colour_noted = False
        self._pages_noted = False
        first = None
        for index, path in enumerate(files):  # the first decodable image sets size and type
            try:
                first, _ = _read_image(path, index)
                break
            except ClipError:
                if not skip_bad_frames or index == len(files) - 1:
                    raise
        assert first is not None
        self.dtype = first.dtype
        name = name or folder.name or folder.resolve().name
        super().__init__(folder, name, _fps(folder, fps, None), len(files), first.shape[:2],
                         nan_as_zero)

    def _read(self, path: Path, index: int) -> np.ndarray:
        """Decode image ``index``; note the first colour image converted to luma."""
        image, colour = _read_image(path, index)
        if colour and not self._colour_noted:
            self._colour_noted = True
            warnings.warn(f"{path}: colour image converted to luma (0.299 R + 0.587 G + 0.114 B); "
                          f"later colour images too", ClipNote, stacklevel=3)
        if not self._pages_noted and path.suffix.lower() in (".tif", ".tiff"):
            pages = _page_count(path)
            if pages > 1:
                self._pages_noted = True
                warnings.warn(f"{path}: multi-page TIFF ({pages} pages): only the first page is read, "
                              f"as frame {index} (one image per frame is expected); later ones too",
                              ClipWarning, stacklevel=3)
        return image

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``, reading one image at a time.

        With ``skip_bad_frames`` an undecodable image is skipped (index left out) with a
        warning.
        """
        for index in _indices(start, stop, len(self.files)):
            path = self.files[index]
            try:
                image = self._read(path, index)
            except BadFrameError as exc:
                if not self.skip_bad_frames:
                    raise
                self._skip([index], str(exc))
                continue
            if image.shape != self.shape or image.dtype != self.dtype:
                raise ClipError(f"{path}: image {index} is {_describe(image.shape, image.dtype)}, "
                                f"but {self.files[0].name} is {_describe(self.shape, self.dtype)}")
            yield self._frame(index, image, str(path))


class NpyClip(_ClipBase):
    """A (T, H, W) or (H, W) .npy array, memory-mapped and copied out one frame at a time.

    uint8, uint16 and float32 are kept; bool becomes uint8; every other integer or float
    type becomes float32 (exact for integers up to 2**24 in magnitude, so signed data keeps
    its sign). Object, string, complex and structured arrays raise ``ClipError``. Float frames
    far from the usual scale are rescaled by a power of two (``_ClipBase._rescale``).
    """

    def __init__(self, path: Path, fps: float | None = None, *, nan_as_zero: bool = False) -> None:
        array = self._load(path)
        if array.ndim not in (2, 3):
            raise ClipError(f"{path}: expected a (T, H, W) or (H, W) array, got {array.shape}")
        if 0 in array.shape:
            problem = "no frames" if array.ndim == 3 and array.shape[0] == 0 else "empty frames"
            raise ClipError(f"{path}: {problem}; expected a (T, H, W) or (H, W) array with no zero "
                            f"dimension, got {array.shape}")
        self.dtype = _frame_dtype(array.dtype, path)
        n_frames = 1 if array.ndim == 2 else array.shape[0]
        super().__init__(path, path.stem, _fps(path, fps, None), n_frames, array.shape[-2:],
                         nan_as_zero)

    @staticmethod
    def _load(path: Path) -> np.ndarray:
        """Memory-map ``path`` read-only, turning numpy's load errors into ``ClipError``."""
        try:
            return np.load(path, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            if _npy_dtype(path).hasobject:
                raise ClipError(f"{path}: cannot load .npy array: it holds Python objects "
                                f"(dtype object), not pixels, and is read with allow_pickle=False") from None
            problem = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ClipError(f"{path}: cannot load .npy array ({problem})") from None

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` as independent C-contiguous copies."""
        array = self._load(self.path)
        stack = array[np.newaxis] if array.ndim == 2 else array
        for index in _indices(start, stop, stack.shape[0]):
            image = np.array(stack[index], dtype=self.dtype, order="C", copy=True)
            yield self._frame(index, image, str(self.path))


class VideoClip(_ClipBase):
    """A video file read with ``cv2.VideoCapture``, as luma (see the module docstring)."""

    def __init__(self, path: Path, fps: float | None = None, luma: LumaMode = "auto", *,
                 skip_bad_frames: bool = False) -> None:
        if luma not in ("auto", "raw", "expand", "bgr"):
            raise ValueError(f"luma must be auto, raw, expand or bgr, got {luma!r}")
        cap = _capture(path)
        try:
            native_fps = cap.get(cv2.CAP_PROP_FPS)
            count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
            raw_ok = (cap.getBackendName() == "FFMPEG"
                      and _fourcc(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)) in _PLANAR_LUMA_TAGS)
        finally:
            cap.release()
        bgr = _read_some(path, "bgr", _PROBE_FRAMES)
        raw = _read_some(path, "raw", len(bgr)) if raw_ok else []
        self.luma: LumaMode = _choose_luma(raw, bgr) if luma == "auto" else luma
        shape = bgr[0].shape[:2]
        n_frames = int(count) if math.isfinite(count) and count > 0 else None
        self.skip_bad_frames = skip_bad_frames
        super().__init__(path, path.stem, _fps(path, fps, native_fps), n_frames, shape)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` from a fresh capture, seeking to ``start``.

        Reads until ``stop`` or the end of the stream: ``n_frames`` is the container's
        estimate, so it does not cut the pass short. A read that fails well before that
        estimate is a bad frame: ``BadFrameError``, or with ``skip_bad_frames`` a warning and
        the index left out (reading goes on to the estimate, so a truncated file ends there).
        """
        indices = _indices(start, stop, None)
        if isinstance(indices, range) and not indices:
            return
        cap = _capture(self.path, self.luma)
        failed: list[int] = []
        try:
            cap = _seek(cap, self.path, self.luma, start)
            for index in indices:
                image = _decode(cap, self.luma)
                if image is None:
                    if not self._expects_more(index):
                        break
                    if not self.skip_bad_frames:
                        raise BadFrameError(f"{self.path}: cannot decode frame {index} of "
                                            f"{self.n_frames}, truncated or corrupt video")
                    failed.append(index)
                    continue
                if failed:
                    self._skip(failed, f"{self.path}: cannot decode {_span(failed)}")
                    failed = []
                yield self._frame(index, image, str(self.path))
            if failed:
                self._skip(failed, f"{self.path}: cannot decode {_span(failed)} of {self.n_frames} "
                                   f"(truncated video?)")
        finally:
            cap.release()

    def _expects_more(self, index: int) -> bool:
        """Whether the container says the stream goes on past ``index`` (beyond estimate slack)."""
        n = self.n_frames
        return n is not None and index < n - max(1, n // 200)


def _spread(image: np.ndarray) -> float:
    """A float frame's spread: its median absolute deviation, else (mostly constant) its largest
    deviation from the median, else (constant) the magnitude of its value."""
    x = image.astype(np.float64, copy=False).ravel()
    med = float(np.median(x))
    dev = np.abs(x - med)
    return float(np.median(dev)) or float(dev.max()) or abs(med)


def _gain_exponent(image: np.ndarray) -> int:
    """k so that 2**k brings the spread of float ``image`` into range (0: already in range or
    all zero); never so large that the frame's largest value passes 2**64."""
    spread = _spread(image)
    if spread == 0.0 or FLOAT_SPREAD[0] <= math.log2(spread) <= FLOAT_SPREAD[1]:
        return 0
    k = FLOAT_TARGET - math.frexp(spread)[1]
    peak = float(np.abs(image.astype(np.float64, copy=False)).max())
    return min(k, 64 - math.frexp(peak)[1])  # peak * 2**k < 2**64 (_MAX_SCALED)


def _indices(start: int, stop: int | None, n: int | None) -> Iterable[int]:
    """Frame indices ``start <= index < stop``, clamped to ``n`` when it is known."""
    if start < 0 or (stop is not None and stop < 0):
        raise ValueError(f"start and stop must be >= 0, got start={start}, stop={stop}")
    if n is not None:
        stop = n if stop is None else min(stop, n)
    return itertools.count(start) if stop is None else range(start, stop)


def _fps(path: Path, override: float | None, native: float | None) -> float:
    """``override`` if given (must be positive), else a usable ``native`` fps, else 20."""
    if override is not None:
        if not (math.isfinite(override) and override > 0):
            raise ClipError(f"{path}: fps must be a positive number, got {override}")
        return float(override)
    if native is not None and math.isfinite(native) and native > 0:
        return float(native)
    return DEFAULT_FPS


def _frame_dtype(dtype: np.dtype, path: Path) -> np.dtype:
    """The frame dtype for source ``dtype`` (see ``NpyClip``); ClipError if unsupported."""
    if dtype in (np.uint8, np.uint16, np.float32):
        return np.dtype(dtype)
    if dtype == np.bool_:
        return np.dtype(np.uint8)
    if dtype.kind in "iuf" and dtype.fields is None:
        return np.dtype(np.float32)
    raise ClipError(f"{path}: unsupported pixel type {dtype}")


def display(text: object) -> str:
    """``text`` (a path, a message) printable as UTF-8: bytes of a non-UTF-8 file name (held by
    Python as lone surrogates, which cannot be encoded for output) shown as ``\\xff``."""
    s = os.fspath(text) if isinstance(text, os.PathLike) else str(text)
    try:
        s.encode("utf-8")
        return s
    except UnicodeEncodeError:
        try:
            return s.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        except UnicodeEncodeError:
            return s.encode("utf-8", "backslashreplace").decode("utf-8")


def _cv2_safe(path: Path) -> bool:
    """Whether OpenCV can be given ``str(path)``: its bindings cannot convert a name that is not
    valid UTF-8 (a crash, not an error), so such files are read by bytes or descriptor."""
    try:
        str(path).encode("utf-8")
        return True
    except UnicodeEncodeError:
        return False


def write_image(path: Path, image: np.ndarray) -> bool:
    """``cv2.imwrite`` for any file name: encoded in memory (format from the suffix), written
    by bytes. False if OpenCV cannot encode ``image``."""
    ok, data = cv2.imencode(Path(path).suffix or ".png", image)
    if not ok:
        return False
    data.tofile(path)
    return True


@contextmanager
def opencv_name(path: Path) -> Iterator[str]:
    """A name of ``path`` OpenCV can be given while the block runs (for writers, which pick the
    container from the suffix): ``str(path)``, or for a name that is not valid UTF-8 a symlink
    with a plain name in a private temporary folder, removed on exit. The file is created first
    so that the link is not dangling."""
    if _cv2_safe(path):
        yield str(path)
        return
    import tempfile

    target = os.path.abspath(path)
    os.close(os.open(target, os.O_WRONLY | os.O_CREAT, 0o666))
    with tempfile.TemporaryDirectory(prefix="wfviz-name-") as folder:
        link = os.path.join(folder, "file" + (Path(path).suffix if _cv2_safe(Path(path).suffix) else ""))
        os.symlink(target, link)
        yield link


def _page_count(path: Path) -> int:
    """Pages of a (TIFF) image file (1 if OpenCV cannot tell)."""
    try:
        with _quiet(cv2.utils.logging.LOG_LEVEL_SILENT):
            if _cv2_safe(path):
                return int(cv2.imcount(str(path)))
            ok, pages = cv2.imdecodemulti(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)
            return len(pages) if ok else 1
    except (cv2.error, AttributeError, OSError, ValueError):
        return 1


def _read_image(path: Path, index: int) -> tuple[np.ndarray, bool]:
    """Decode one image at full range and reduce it to 2-D luma; True if it was colour.

    The file is read by bytes and decoded in memory, so any file name works (OpenCV cannot be
    given a name that is not valid UTF-8)."""
    try:
        data = np.fromfile(path, np.uint8)
    except OSError as exc:
        raise BadFrameError(f"{path}: cannot read image {index} ({exc.strerror or exc})") from None
    try:
        with _quiet(cv2.utils.logging.LOG_LEVEL_SILENT):  # the error below says it in one line
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    except cv2.error:
        image = None
    if image is None or image.size == 0:
        raise BadFrameError(f"{path}: cannot decode image {index}")
    colour = image.ndim == 3 and image.shape[2] in (3, 4)
    if colour:
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim != 2:
        raise ClipError(f"{path}: image {index} has unsupported shape {image.shape}")
    return image.astype(_frame_dtype(image.dtype, path), copy=False), colour


def _npy_dtype(path: Path) -> np.dtype:
    """The dtype in a .npy header (uint8 if the header is unreadable)."""
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            reader = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                      else np.lib.format.read_array_header_2_0)
            return np.dtype(reader(fh)[2])
    except (ValueError, OSError, EOFError, TypeError):
        return np.dtype(np.uint8)


def _span(indices: list[int]) -> str:
    """``"frame 4"`` or ``"frames 4-9"`` (consecutive indices)."""
    return f"frame {indices[0]}" if len(indices) == 1 else f"frames {indices[0]}-{indices[-1]}"


def _describe(shape: tuple[int, ...], dtype: np.dtype) -> str:
    """``"640x512 uint16"``."""
    return f"{shape[1]}x{shape[0]} {dtype}"


def _fourcc(code: float) -> str:
    """The four characters of a FOURCC stored in a float (``""`` if none)."""
    value = int(code)
    return value.to_bytes(4, "little").decode("latin-1") if value > 0 else ""


def _capture(path: Path, luma: LumaMode = "bgr") -> cv2.VideoCapture:
    """An open capture of ``path``, returning the raw first plane unless ``luma`` is "bgr".

    A path that is not valid UTF-8 (which OpenCV cannot be given) is opened by bytes and handed
    over as ``/proc/self/fd/N``, closed once the capture has opened its own; where there is no
    /proc, ClipError."""
    if _cv2_safe(path):
        cap = cv2.VideoCapture(str(path))
    else:
        if not os.path.isdir("/proc/self/fd"):
            raise ClipError(f"{path}: cannot open a video whose name is not valid UTF-8 on this "
                            f"system; rename it")
        fd = os.open(path, os.O_RDONLY)
        try:
            cap = cv2.VideoCapture(f"/proc/self/fd/{fd}")
        finally:
            os.close(fd)
    if not cap.isOpened():
        cap.release()
        raise ClipError(f"{path}: cannot decode video (truncated or unsupported codec)")
    if luma != "bgr":
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    return cap


@contextmanager
def _quiet(level: int = cv2.utils.logging.LOG_LEVEL_ERROR) -> Iterator[None]:
    """Raise OpenCV's process-wide log level (default ERROR: silences the 8UC1 warning) for one read."""
    old = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(level)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(old)


def _decode(cap: cv2.VideoCapture, luma: LumaMode) -> np.ndarray | None:
    """The next frame as luma in mode ``luma``, or None at the end of the stream."""
    with _quiet():
        ok, image = cap.read()
    if not ok or image is None:
        return None
    if luma == "bgr":
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.LUT(image, _EXPAND) if luma == "expand" else image


def _read_some(path: Path, mode: Literal["raw", "bgr"], n: int) -> list[np.ndarray]:
    """Up to ``n`` frames from the start: Y planes (``"raw"``) or BGR-derived grey."""
    cap = _capture(path, mode)
    try:
        images = [im for im in (_decode(cap, mode) for _ in range(n)) if im is not None]
    finally:
        cap.release()
    if mode == "bgr" and not images:
        raise ClipError(f"{path}: cannot decode video (truncated or unsupported codec)")
    return images


def _choose_luma(raw: list[np.ndarray], grey: list[np.ndarray]) -> LumaMode:
    """Pick "raw", "expand" or "bgr" by comparing Y planes with OpenCV's BGR-derived grey."""
    if len(raw) != len(grey) or any(r.shape != g.shape or r.dtype != np.uint8
                                    for r, g in zip(raw, grey)):
        return "bgr"
    y, g = np.stack(raw).astype(np.int16), np.stack(grey).astype(np.int16)
    expanded = _EXPAND[y].astype(np.int16)
    decisive = np.abs(expanded - y) >= 3  # pixels where the two range models differ
    mask = decisive if decisive.any() else np.ones_like(decisive)
    err_raw = float(np.abs(g - y)[mask].mean())
    err_expand = float(np.abs(g - expanded)[mask].mean())
    if min(err_raw, err_expand) > _FIT_TOLERANCE:
        return "bgr"
    outside = (y < 16 - _RANGE_MARGIN) | (y > 235 + _RANGE_MARGIN)
    if err_expand < err_raw and outside.mean() <= _RANGE_FRACTION:
        return "expand"
    return "raw"


def _seek(cap: cv2.VideoCapture, path: Path, luma: LumaMode, start: int) -> cv2.VideoCapture:
    """Position ``cap`` at frame ``start``: seek, or re-open and skip if seeking misreports."""
    if start == 0:
        return cap
    cap.set(cv2.CAP_PROP_POS_FRAMES, start)
    if int(cap.get(cv2.CAP_PROP_POS_FRAMES)) == start:
        return cap
    cap.release()
    cap = _capture(path, luma)
    for _ in range(start):
        if not cap.grab():
            break
    return cap
