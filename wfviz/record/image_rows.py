"""Images as Rerun rows without an archetype a frame: an image's bytes, plus its other
components' one-row Arrow arrays taken from a template of its kind. A chunk's bytes become one
``list<uint8>`` column (:class:`ImageRows`).

``rr.Image`` and ``rr.EncodedImage`` convert each component in Python on every image, which the
recorder paid on every frame. Here Rerun's conversion runs once per kind of image (its shape,
dtype and draw order, or a preview's draw order). Where Rerun stores an image's buffer as the
image's bytes in C order, the next images of the kind are taken as bytes. This is checked on the
kind's first image, and any other kind is converted by Rerun every time. The rows hold what the
archetypes would (``tests/test_images.py``).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pyarrow as pa
import rerun as rr

BLOB_TYPE = pa.list_(pa.field("item", pa.uint8(), nullable=False))  # Image:buffer, EncodedImage:blob
MAX_BLOB_BYTES = 2**31 - 1  # list<uint8> has 32-bit offsets


class ImageTemplate:
    """An image archetype's components as Arrow: ``names`` and ``descriptors`` of its
    components, the index ``blob`` of the one holding the image's bytes (``list<uint8>``), and
    the others' one-row arrays ``constants`` (format, media type, draw order; None at ``blob``)."""

    def __init__(self, archetype: rr.AsComponents) -> None:
        batches = list(archetype.as_component_batches())
        self.descriptors = [b.component_descriptor() for b in batches]
        self.names = tuple(str(d) for d in self.descriptors)  # "Image:buffer", ...
        arrays = [b.as_arrow_array() for b in batches]
        blobs = [i for i, a in enumerate(arrays) if a.type == BLOB_TYPE]
        if len(blobs) != 1:
            raise ValueError(f"expected one {BLOB_TYPE} component in {self.names}, "
                             f"got {[str(a.type) for a in arrays]}")
        self.blob = blobs[0]
        self.constants: list[pa.Array | None] = [None if i == self.blob else a for i, a in enumerate(arrays)]
        self.blob_of = arrays[self.blob]  # the archetype's own blob (one row)

    def blob_bytes(self) -> bytes:
        """The bytes the archetype this template was made from holds in its blob component."""
        return self.blob_of.flatten().to_numpy(zero_copy_only=False).tobytes()


@cache
def preview_template(order: float) -> ImageTemplate:
    """The components of a JPEG preview (``rr.EncodedImage``) but its bytes, at draw ``order``."""
    return ImageTemplate(rr.EncodedImage(contents=b"\xff", media_type="image/jpeg", draw_order=order))


# (shape, dtype, draw order) -> the kind's template, and whether Rerun's buffer is the image's bytes
_image_kinds: dict[tuple[tuple[int, ...], str, float], tuple[ImageTemplate, bool]] = {}


def image_row(image: np.ndarray, order: float) -> tuple[bytes, ImageTemplate]:
    """``rr.Image(image, draw_order=order)`` as its buffer's bytes and the template of its other
    components; Rerun converts only the first image of a kind whose buffer is the image's bytes."""
    key = (image.shape, image.dtype.str, order)
    known = _image_kinds.get(key)
    if known is not None and known[1]:
        return image.tobytes(), known[0]
    template = ImageTemplate(rr.Image(image, draw_order=order))
    data = template.blob_bytes()
    if known is None:  # two threads may both get here: they store the same
        _image_kinds[key] = (template, data == image.tobytes())
    return data, template


class ImageRows:
    """One entity's images of one kind not sent yet: each row's bytes and its template's
    constants; :meth:`columns` makes them one chunk's columns."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names
        self.frames: list[int] = []
        self.times: list[float] = []
        self.blobs: list[bytes] = []
        self.rows: list[ImageTemplate] = []
        self.nbytes = 0

    def add(self, frame: int, time: float, data: bytes, template: ImageTemplate) -> None:
        """A row: the image's ``data`` at ``frame`` and ``time`` with ``template``'s other
        components (a converted kind brings its own template each row)."""
        if template.names != self.names:
            raise ValueError(f"components {template.names} among rows of {self.names}")
        self.blobs.append(data)
        self.rows.append(template)
        self.nbytes += len(data) + sum(a.nbytes for a in template.constants if a is not None)
        self.frames.append(frame)
        self.times.append(time)

    def columns(self) -> list[tuple[object, pa.Array]]:
        """(descriptor, Arrow array) of each component, a row per image: the bytes as one
        ``list<uint8>`` array, the others' one-row arrays concatenated."""
        offsets = np.zeros(len(self.blobs) + 1, dtype=np.int64)
        np.cumsum([len(b) for b in self.blobs], out=offsets[1:])
        if offsets[-1] > MAX_BLOB_BYTES:
            raise ValueError(f"{offsets[-1]} bytes of images in one chunk (at most {MAX_BLOB_BYTES})")
        values = pa.py_buffer(b"".join(self.blobs))
        blob = pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)),
                                        pa.Array.from_buffers(pa.uint8(), len(values), [None, values]),
                                        type=BLOB_TYPE)
        first = self.rows[0]
        return [(d, blob if i == first.blob else pa.concat_arrays([t.constants[i] for t in self.rows]))
                for i, d in enumerate(first.descriptors)]
