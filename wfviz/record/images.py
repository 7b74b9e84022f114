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

from wfviz.record.image_rows import ImageRows, image_row, preview_template
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
        self._pending: dict[tuple[str, bool], ImageRows] = {}  # (path, exact) -> rows not sent
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
            data, template = preview_jpeg(image, self.quality), preview_template(order)
        key = (path, exact)
        rows = self._pending.get(key)
        if rows is None:
            rows = self._pending[key] = ImageRows(template.names)
        rows.add(frame, time, data, template)
        if len(rows.frames) >= self.ROWS or rows.nbytes >= self.CHUNK_BYTES:
            self._send_rows(key)

    def _send_rows(self, only: tuple[str, bool] | None = None) -> None:
        """The rows held (of ``only``, or all), one chunk per entity and kind."""
        for key in [only] if only is not None else list(self._pending):
            rows = self._pending.pop(key, None)
            if rows is not None and rows.frames:
                columns = [rr.ComponentColumn(d, ArrowBatch(a)) for d, a in rows.columns()]
                self.rec.send_columns(key[0], indexes=time_columns(rows.frames, rows.times), columns=columns)


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
