"""Helpers shared by the test modules (``from conftest import wfviz, digest, ...``): running the
command line, small input clips, the state of output folders, and the Vulkan check of the tests
that render in the real viewer."""

from __future__ import annotations

import csv
import ctypes.util
import hashlib
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from wfviz.io.outputs import TEMP_SUFFIX

# -- the command line ---------------------------------------------------------------------------

#: ``wfviz`` as a subprocess (the interpreter running the tests)
WFVIZ = [sys.executable, "-m", "wfviz"]
#: the rerun CLI installed beside it
RERUN = Path(sys.executable).with_name("rerun")


def wfviz(*args: str, cwd: Path | None = None, timeout: float = 300, **kw: Any) -> subprocess.CompletedProcess:
    """Run ``wfviz ARGS`` in a subprocess (output captured as text)."""
    return subprocess.run([*WFVIZ, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, **kw)


def invoke(*args: str) -> Any:
    """Run ``wfviz ARGS`` in this process (typer's CliRunner; its ``Result``)."""
    from typer.testing import CliRunner

    from wfviz.cli import app

    return CliRunner().invoke(app, list(args))


def one_line_error(proc: subprocess.CompletedProcess, *words: str) -> None:
    """The command failed with exit code 2 and one ``wfviz: error:`` line holding ``words``."""
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wfviz: error: "), proc.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


# -- outputs --------------------------------------------------------------------------------------

def digest(folder: Path) -> dict[str, str]:
    """Name -> SHA-1 of every file under ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def temporaries(folder: Path) -> list[Path]:
    """Temporary outputs (``*.wfviz-part``, ``*.part``) anywhere under ``folder``."""
    return [p for p in folder.rglob("*") if p.name.endswith(TEMP_SUFFIX) or p.name.endswith(".part")]


def rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file (tracks, trials) as dicts."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def verify(path: Path) -> None:
    """``rerun rrd verify`` passes (skipped when this rerun has no such subcommand)."""
    if not RERUN.exists():
        pytest.skip(f"no rerun CLI beside {sys.executable}")
    if "verify" not in subprocess.run([str(RERUN), "rrd", "--help"], capture_output=True, text=True).stdout:
        pytest.skip("this rerun has no `rerun rrd verify`")
    proc = subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr


# -- inputs ---------------------------------------------------------------------------------------

H, W = 32, 40  # noise(): above the 16x16 minimum, small enough to be quick
RNG = np.random.default_rng(7)


def noise(dtype: type = np.uint16, shape: tuple[int, ...] = (H, W)) -> np.ndarray:
    """Noise of frames (..., rows, columns), each with a bright pixel at a random place (a
    detection in every frame: frames without any make the recorder warn about empty values)."""
    image = RNG.integers(100, 120, shape).astype(dtype)
    frames = image.reshape(-1, *shape[-2:])
    for f in frames:
        f[RNG.integers(2, shape[-2] - 2), RNG.integers(2, shape[-1] - 2)] = 250
    return frames.reshape(shape)


def write_folder(folder: Path, images: dict[str, np.ndarray]) -> Path:
    """Write ``images`` (file name -> array) into ``folder``."""
    folder.mkdir(exist_ok=True)
    for name, image in images.items():
        assert cv2.imwrite(str(folder / name), image)
    return folder


# -- the real viewer ------------------------------------------------------------------------------

_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/usr/local/share/vulkan/icd.d", "/etc/vulkan/icd.d")


def vulkan_missing() -> str | None:
    """Why the Vulkan software driver is unusable here, or None if it looks installed."""
    if ctypes.util.find_library("vulkan") is None:
        return "Vulkan loader (libvulkan1) not installed"
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return None
    if not any(Path(d).glob("lvp_icd*.json") for d in _ICD_DIRS):
        return "Vulkan software driver lavapipe (mesa-vulkan-drivers) not installed"
    return None


#: the test renders in the headless viewer (skipped without a Vulkan software driver)
needs_vulkan = pytest.mark.skipif(vulkan_missing() is not None,
                                  reason=f"no Vulkan software driver: {vulkan_missing()} (see tests/test_screenshot.py)")
