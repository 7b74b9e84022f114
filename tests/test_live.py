"""`wfviz record --connect | --serve | --spawn`: the run streamed live as well as written."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from wfviz.record.live import Live


def wfviz(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "wfviz", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)


def _frames(rrd: Path, entity: str = "/camera/image") -> list[int]:
    out = []
    for c in RrdReader(rrd).stream():
        if c.entity_path == entity and not c.is_static:
            out += c.to_record_batch().column("frame").to_pylist()
    return sorted(set(out))  # a frame where the image kind switches has a row clearing the other


def _vulkan_ready() -> bool:
    from test_screenshot import _vulkan_missing

    return _vulkan_missing() is None


@pytest.mark.skipif(not _vulkan_ready(), reason="no Vulkan software driver (see tests/test_screenshot.py)")
def test_connect_streams_to_a_headless_viewer_and_writes_the_file(tmp_path: Path) -> None:
    """A headless viewer on loopback receives every frame of the run; the file has them too."""
    from wfviz.record.screenshot import _connect, _find_viewer, _free_port, _kill_group

    port = _free_port()
    cmd = [_find_viewer(), "--headless", "--renderer", "vulkan", "--bind", "127.0.0.1", "--port", str(port),
           "--hide-welcome-screen"]
    with tempfile.TemporaryFile() as log:
        viewer = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True)
        try:
            client = _connect(viewer, port, time.monotonic() + 120, log)
            proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "15", "-o", "live.rrd",
                         "--connect", f"rerun+http://127.0.0.1:{port}/proxy", cwd=tmp_path)
            assert proc.returncode == 0, proc.stderr
            assert "streaming to" in proc.stderr
            deadline = time.monotonic() + 60
            while True:
                state = client.get_state()
                ends = [t.end for r in state.recordings for t in r.timelines if t.name == "frame"]
                if ends and max(e or 0 for e in ends) >= 14 or time.monotonic() > deadline:
                    break
                time.sleep(0.2)
            assert ends and max(e or 0 for e in ends) == 14, ends
        finally:
            _kill_group(viewer)
    assert _frames(tmp_path / "live.rrd") == list(range(15))


def test_a_lost_connection_keeps_the_file(tmp_path: Path) -> None:
    """Nothing listens at the URL: the run still ends, says so in one note, and the file is whole."""
    from wfviz.record.screenshot import _free_port

    port = _free_port()
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "8", "-o", "lost.rrd",
                 "--connect", f"rerun+http://127.0.0.1:{port}/proxy", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "the file is complete" in proc.stderr
    assert _frames(tmp_path / "lost.rrd") == list(range(8))
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".wfviz-part")]


def test_serve_binds_loopback_by_default_and_writes_the_file(tmp_path: Path) -> None:
    from wfviz.record.screenshot import _free_port

    port = _free_port()
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "8", "-o", "s.rrd", "--serve",
                 "--port", str(port), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert f"serving rerun+http://127.0.0.1:{port}/proxy" in proc.stderr
    assert _frames(tmp_path / "s.rrd") == list(range(8))


def test_live_options_are_checked(tmp_path: Path) -> None:
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--spawn", "--serve", cwd=tmp_path)
    assert proc.returncode == 2 and "--spawn and --serve: choose one live view" in proc.stderr
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--connect", "http://x:1", cwd=tmp_path)
    assert proc.returncode == 2 and "expected rerun+http://HOST:PORT/proxy" in proc.stderr
    assert not (tmp_path / "recordings").exists() or not any((tmp_path / "recordings").iterdir())
    assert Live("serve", bind="0.0.0.0", port=5).grpc_url == "rerun+http://127.0.0.1:5/proxy"
