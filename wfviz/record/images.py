"""Images in a recording: exact (lossless, source dtype) now and then, JPEG previews between.

A 640x512 16-bit frame is 0.66 MB raw and about 0.44 MB as lossless PNG (sensor noise does
not compress), so every frame exact would cost over 1 MB a frame with the residual. Instead
the first image frame of every ``exact_every`` frames carries the exact images (``rr.Image``:
hover reads the true values) and the frames between carry 8-bit JPEG previews (``rr.EncodedImage``)
stretched from the image's minimum to its maximum, which is how the viewer displays a
single-channel image that is not 8-bit, so scrubbing does not flicker between the two; 8-bit
images are encoded as they are. Each switch clears the other archetype on the entity, so one
image shows at any time (see docs/recording.md, "Images").
"""

from __future__ import annotations

import os
import queue
import threading
from functools import cache
from typing import Protocol

import cv2
import numpy as np
import pyarrow as pa
import rerun as rr

from wfviz.record_options import EXACT_EVERY, PREVIEW_QUALITY

IMAGE_DRAW_ORDER = -10.0  # exact images and previews alike (a tie would be drawn in any order)
MAP_DRAW_ORDER = -20.0  # value maps (the noise map) under the pictures


class _Stream(Protocol):
    def log(self, entity: str, *args: object, **kwargs: object) -> None: ...
    def set_time(self, timeline: str, **kwargs: object) -> None: ...
    def send_columns(self, entity: str, **kwargs: object) -> None: ...


def preview_jpeg(image: np.ndarray, quality: int = PREVIEW_QUALITY) -> bytes:
    """``image`` (one channel, any dtype) as an 8-bit JPEG: 8-bit as it is, anything else
    stretched linearly from its finite minimum (0) to its finite maximum (255). Never modifies
    ``image``."""
    if image.dtype == np.uint8:
        u8 = image
    elif image.dtype == np.float16:  # OpenCV has no half-precision arithmetic
        return preview_jpeg(image.astype(np.float32), quality)
    else:
        lo, hi, _, _ = cv2.minMaxLoc(image)
        if not (np.isfinite(lo) and np.isfinite(hi)):
            finite = image[np.isfinite(image)]
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
        scale = 255.0 / (hi - lo) if hi > lo else 0.0
        u8 = cv2.convertScaleAbs(image, alpha=scale, beta=-lo * scale)
    ok, data = cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return data.tobytes()


def time_columns(frames: list[int], times: list[float]) -> list[rr.TimeColumn]:
    """The ``frame`` and ``time`` index columns of rows sent with ``send_columns``. The times
    (s) go in as nanoseconds rounded as Rerun rounds one value (``round(1e9 · t)``, half to
    even), without its per-element Python conversion of a list."""
    nanos = np.rint(np.asarray(times, dtype=np.float64) * 1e9).astype("timedelta64[ns]")
    return [rr.TimeColumn("frame", sequence=frames), rr.TimeColumn("time", duration=nanos)]


class ImageLog:
    """Which frames carry images and of which kind, and the logging of them.

    ``image_every``: an image on every N-th frame logged (0: never); ``exact_every``: the first
    image frame of every N frames is exact (1: every image exact, 0: previews only);
    ``quality``: the previews' JPEG quality. Images are sent past the batcher (which is slower
    with megabytes, and whose 16 MB batches made the process grow by about 75 KB a frame with
    previews), in chunks of up to ``ROWS`` images or ``CHUNK_BYTES`` per entity and kind (the
    file writer keeps about 8 KB per image chunk until it closes: a chunk per image grew a
    20 000-frame recording by over 200 MB); a live viewer therefore gets them in those batches.
    With ``threaded`` (default: when this process may use more than one CPU) the encoding and
    sending run on a worker thread, at most ``QUEUE`` images behind; the images must then not
    be modified after they are logged (the trackers make new arrays each frame).
    A worker's error is raised by the next :meth:`log` or by :meth:`close`."""

    QUEUE = 4
    ROWS = 64  # images per chunk, at most ...
    CHUNK_BYTES = 8 * 2**20  # ... or about this many bytes (each chunk costs the writer ~8 KB until the end)

    def __init__(self, rec: _Stream, image_every: int = 1, exact_every: int = EXACT_EVERY,
                 quality: int = PREVIEW_QUALITY, threaded: bool | None = None) -> None:
        if image_every < 0 or exact_every < 0 or not 1 <= quality <= 100:
            raise ValueError(f"image_every {image_every}, exact_every {exact_every}, quality {quality}")
        self.rec, self.image_every, self.exact_every, self.quality = rec, image_every, exact_every, quality
        self.exact = False  # whether the current frame's images are exact
        self._block = -1  # the exact_every block whose exact images were logged
        self._kind: dict[str, bool] = {}  # entity -> last logged exact (True) or preview (False)
        self._now = (0, 0.0)
        self._pending: dict[tuple[str, bool], _Rows] = {}  # (path, exact) -> rows not sent
        if threaded is None:
            threaded = image_every > 0 and len(os.sched_getaffinity(0)) > 1
        self._jobs: queue.Queue | None = queue.Queue(self.QUEUE) if threaded else None
        self._error: BaseException | None = None
        self._worker: threading.Thread | None = None
        if self._jobs is not None:
            self._worker = threading.Thread(target=self._work, name="wfviz-images", daemon=True)
            self._worker.start()

    def begin_frame(self, n_logged: int, frame: int, time: float) -> bool:
        """Decide the ``n_logged``-th frame logged (``frame`` at ``time``); True if it carries images."""
        self._now = (frame, time)
        images = self.image_every > 0 and n_logged % self.image_every == 0
        self.exact = False
        if images and self.exact_every > 0 and n_logged // self.exact_every != self._block:
            self.exact, self._block = True, n_logged // self.exact_every
        return images

    def log(self, path: str, image: np.ndarray, value_map: bool = False) -> None:
        """``image`` at ``path``: exact on exact frames, else a JPEG preview; a ``value_map`` (a
        map of measured values, of no use as a picture) always exact and drawn under the pictures
        of its view."""
        if self._error is not None:
            self._raise()
        exact = value_map or self.exact
        clear = self._kind.get(path, exact) != exact  # the other kind showed until now: clear it
        self._kind[path] = exact
        job = (path, image, exact, MAP_DRAW_ORDER if value_map else IMAGE_DRAW_ORDER, clear, *self._now)
        if self._jobs is None:
            self._send(*job)
        else:
            self._jobs.put(job)

    def close(self) -> None:
        """Wait until every image is sent (the worker stops); raise a worker's error."""
        if self._jobs is not None and self._worker is not None:
            self._jobs.put(None)  # the worker sends the previews it holds, then stops
            self._worker.join()
            self._jobs = None
        elif self._error is None:
            try:
                self._send_rows()
            except BaseException as exc:  # noqa: BLE001 - raised below
                self._error = exc
        if self._error is not None:
            self._raise()

    def _raise(self) -> None:
        error, self._error = self._error, None
        raise RuntimeError(f"recording an image failed: {error}") from error

    def _work(self) -> None:
        assert self._jobs is not None
        while (job := self._jobs.get()) is not None:
            if self._error is None:  # after an error: drain, so that log() never blocks
                try:
                    self._send(*job)
                except BaseException as exc:  # noqa: BLE001 - handed to the main thread
                    self._error = exc
        if self._error is None:
            try:
                self._send_rows()
            except BaseException as exc:  # noqa: BLE001 - handed to the main thread
                self._error = exc

    def _send(self, path: str, image: np.ndarray, exact: bool, order: float, clear: bool, frame: int,
              time: float) -> None:
        if clear:
            self.rec.set_time("frame", sequence=frame)  # this thread's time (the worker's own, or the caller's)
            self.rec.set_time("time", duration=time)
            self.rec.log(path, _cleared(rr.EncodedImage if exact else rr.Image))
        if exact:
            data, template = image_row(image, order)
        else:
            data = preview_jpeg(image, self.quality)
            template = _preview_template(order)
        key = (path, exact)
        rows = self._pending.get(key)
        if rows is not None and rows.template.names != template.names:
            self._send_rows(key)  # another set of components (cannot happen with Rerun 0.41's two archetypes)
            rows = None
        if rows is None:
            rows = self._pending[key] = _Rows(template)
        rows.add(frame, time, data, template)
        if len(rows.frames) >= self.ROWS or rows.nbytes >= self.CHUNK_BYTES:
            self._send_rows(key)

    def _send_rows(self, only: tuple[str, bool] | None = None) -> None:
        """The rows held (of ``only``, or all), one chunk per entity and kind."""
        for key in [only] if only is not None else list(self._pending):
            rows = self._pending.pop(key, None)
            if rows is not None and rows.frames:
                self.rec.send_columns(key[0], indexes=time_columns(rows.frames, rows.times), columns=rows.columns())


@cache
def _cleared(archetype: type) -> rr.AsComponents:
    """``archetype.cleared()``, built once (the same empty components every time)."""
    return archetype.cleared()  # type: ignore[attr-defined, no-any-return]


class ArrowBatch:
    """A ready Arrow array as a Rerun component batch."""

    def __init__(self, array: pa.Array) -> None:
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


class _Template:
    """An image archetype's components as Arrow: the one that holds the image's bytes
    (``list<uint8>``: ``Image:buffer``, ``EncodedImage:blob``) at ``blob``, the others' one-row
    arrays, the same for every image of a kind (format, media type, draw order)."""

    def __init__(self, archetype: rr.AsComponents) -> None:
        batches = list(archetype.as_component_batches())
        self.descriptors = [b.component_descriptor() for b in batches]
        self.names = tuple(str(d) for d in self.descriptors)  # "Image:buffer", ...
        arrays = [b.as_arrow_array() for b in batches]
        blobs = [i for i, a in enumerate(arrays) if a.type == BLOB_TYPE]
        if len(blobs) != 1:
            raise ValueError(f"expected one {BLOB_TYPE} component, got {[str(a.type) for a in arrays]}")
        self.blob = blobs[0]
        self.constants: list[pa.Array | None] = [None if i == self.blob else a for i, a in enumerate(arrays)]
        self.nbytes = sum(a.nbytes for a in arrays if a is not arrays[self.blob])

    def blob_bytes(self, archetype: rr.AsComponents) -> bytes:
        """The bytes ``archetype`` (of this template's kind) holds in its blob component."""
        array = list(archetype.as_component_batches())[self.blob].as_arrow_array()
        return array.values.to_numpy(zero_copy_only=False).tobytes()


BLOB_TYPE = pa.list_(pa.field("item", pa.uint8(), nullable=False))


@cache
def _preview_template(order: float) -> _Template:
    return _Template(rr.EncodedImage(contents=b"\xff", media_type="image/jpeg", draw_order=order))


_image_kinds: dict[tuple, tuple[_Template, bool]] = {}  # (shape, dtype, order) -> template, raw bytes


def image_row(image: np.ndarray, order: float) -> tuple[bytes, _Template]:
    """``rr.Image(image, draw_order=order)`` as the bytes of its buffer and the template of its
    other components. Rerun's own conversion (about 0.3 ms for a 640x512 image, in Python) runs
    once per shape, dtype and draw order: where its buffer is the image's bytes in C order
    (checked on that first image), the next images of the kind are taken as bytes; any other
    kind is converted by Rerun every time."""
    key = (image.shape, image.dtype.str, order)
    known = _image_kinds.get(key)
    if known is not None and known[1]:
        return image.tobytes(), known[0]
    archetype = rr.Image(image, draw_order=order)
    template = _Template(archetype)
    data = template.blob_bytes(archetype)
    if known is None:
        _image_kinds[key] = (template, data == image.tobytes())
    return data, template


class _Rows:
    """One entity's images of one kind not sent yet: each row's image bytes and the one-row
    arrays of its other components; sent as one chunk, the bytes as one ``list<uint8>`` column
    (no Arrow array a row, and no concatenation of megabytes of them)."""

    def __init__(self, template: _Template) -> None:
        self.template = template
        self.frames: list[int] = []
        self.times: list[float] = []
        self.blobs: list[bytes] = []
        self.constants: list[list[pa.Array]] = [[] for _ in template.descriptors]
        self.nbytes = 0

    def add(self, frame: int, time: float, data: bytes, template: _Template) -> None:
        self.blobs.append(data)
        for column, array in zip(self.constants, template.constants):
            if array is not None:
                column.append(array)
        self.nbytes += len(data) + 8 + template.nbytes  # as the Arrow arrays of a row would count
        self.frames.append(frame)
        self.times.append(time)

    def columns(self) -> list[rr.ComponentColumn]:
        offsets = np.zeros(len(self.blobs) + 1, dtype=np.int64)
        np.cumsum([len(b) for b in self.blobs], out=offsets[1:])
        if offsets[-1] >= 2**31:  # list<uint8> has 32-bit offsets; a chunk holds about CHUNK_BYTES
            raise ValueError(f"{offsets[-1]} bytes of images in one chunk (at most 2 GiB)")
        values = pa.py_buffer(b"".join(self.blobs))
        blob = pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)),
                                        pa.Array.from_buffers(pa.uint8(), len(values), [None, values]),
                                        type=BLOB_TYPE)
        out = []
        for i, d in enumerate(self.template.descriptors):
            array = blob if i == self.template.blob else pa.concat_arrays(self.constants[i])
            out.append(rr.ComponentColumn(d, ArrowBatch(array)))
        return out
