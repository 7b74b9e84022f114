"""pyarrow without pandas in a process that only writes a recording (start-up time)."""

from __future__ import annotations

import sys


class _NoPandas:
    """A meta-path finder under which ``import pandas`` fails (see :func:`arrow_without_pandas`)."""

    @staticmethod
    def find_spec(name: str, path: object = None, target: object = None) -> None:
        if name == "pandas" or name.startswith("pandas."):
            raise ModuleNotFoundError("pandas withheld from pyarrow's probe", name=name)


def arrow_without_pandas() -> None:
    """Keep pyarrow from importing pandas (0.3-0.45 s, most of a recording's start-up after
    Rerun itself) at its first conversion of a Python value, which Rerun does for nearly every
    component: pyarrow asks once, softly, whether pandas can be imported, to tell pandas arrays
    from sequences (we pass none). That probe is answered "no" here while pandas is not loaded;
    pyarrow retries the import whenever something does need pandas (``to_pandas``), and code
    that imports pandas itself (the scores' motmetrics) is unaffected. A change in pyarrow's
    probe only brings the import back.

    For a process that writes a recording and ends (the console commands ``record`` and
    ``demo``: :func:`wfviz.entry.main` calls it), never on import: pyarrow then believes pandas
    absent for the rest of the process, and converting a nanosecond timestamp that microseconds
    cannot hold to Python (``as_py``, ``to_pylist``), which needs pandas, raises instead."""
    if "pandas" in sys.modules:
        return
    import pyarrow as pa

    finder = _NoPandas()
    sys.meta_path.insert(0, finder)  # type: ignore[arg-type]
    try:
        pa.array([True])  # a Python list: pyarrow's soft pandas probe, made once
    finally:
        sys.meta_path.remove(finder)  # type: ignore[arg-type]
