"""Defaults of a recording's images (:mod:`wfviz.record.images`), importable without rerun
(the command line's option defaults)."""

EXACT_EVERY = 10  # frames per exact (lossless, source dtype) image
PREVIEW_QUALITY = 85  # JPEG quality of the previews between
