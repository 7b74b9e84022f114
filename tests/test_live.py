"""`wfviz record --connect | --serve | --spawn`: the run streamed live as well as written."""

from __future__ import annotations

import re
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from conftest import needs_vulkan, one_line_error, wfviz
from wfviz.record.live import Live


def _frames(rrd: Path, entity: str = "/camera/image") -> list[int]:
    out = []
    for c in RrdReader(rrd).stream():
        if c.entity_path == entity and not c.is_static:
            out += c.to_record_batch().column("frame").to_pylist()
    return sorted(set(out))  # a frame where the image kind switches has a row clearing the other


@needs_vulkan
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


def _nothing_written(folder: Path) -> None:
    assert not [p for p in folder.rglob("*") if p.is_file()], list(folder.rglob("*"))


@pytest.mark.parametrize("url, problem", [
    ("rerun+http://127.0.0.1:99999/proxy", "port out of range (1-65535)"),
    ("rerun://", "no host"),
    ("rerun+http://[::1/proxy", "invalid ipv6 url"),
    ("rerun+http://127.0.0.1/proxy", "no port"),
    ("rerun+http://127.0.0.1:9876/other", "path must be /proxy"),
])
def test_bad_connect_urls_are_one_line(tmp_path: Path, url: str, problem: str) -> None:
    """A --connect URL rerun cannot use: one line naming --connect and the problem, before any frame."""
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "2", "-o", "x.rrd",
                 "--connect", url, cwd=tmp_path, timeout=60)
    one_line_error(proc, f"--connect {url}", problem)
    _nothing_written(tmp_path)


@pytest.mark.parametrize("bind, problem", [("", "empty address"), ("999.1.1.1", "not an IP address"),
                                           ("no such host!", "not an IP address or host name")])
def test_bad_bind_addresses_are_one_line(tmp_path: Path, bind: str, problem: str) -> None:
    proc = wfviz("demo", "--frames", "2", "-o", "d.rrd", "--serve", "--bind", bind, cwd=tmp_path, timeout=60)
    one_line_error(proc, "--bind", problem)
    _nothing_written(tmp_path)


def test_serve_on_a_host_name_resolves_it(tmp_path: Path) -> None:
    """``--bind localhost`` serves on the address the name resolves to (loopback)."""
    from wfviz.record.screenshot import _free_port

    port = _free_port()
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "3", "-o", "s.rrd", "--serve",
                 "--bind", "localhost", "--port", str(port), cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert f"serving rerun+http://127.0.0.1:{port}/proxy" in proc.stderr
    assert _frames(tmp_path / "s.rrd") == list(range(3))


def _ipv6_loopback() -> bool:
    import socket

    try:
        with socket.socket(socket.AF_INET6) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback here")
def test_serve_on_ipv6_loopback(tmp_path: Path) -> None:
    from wfviz.record.screenshot import _free_port

    port = _free_port()
    proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "3", "-o", "s.rrd", "--serve",
                 "--bind", "::1", "--port", str(port), cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert f"serving rerun+http://[::1]:{port}/proxy" in proc.stderr
    assert _frames(tmp_path / "s.rrd") == list(range(3))


@pytest.mark.parametrize("bind", ["127.0.0.1", "::"])
def test_serve_port_in_use_is_one_line(tmp_path: Path, bind: str) -> None:
    """The gRPC port taken (here by a loopback listener): one line naming --port, nothing
    served or written (``::`` is accepted as every interface and also needs the port free)."""
    import socket

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "2", "-o", "x.rrd", "--serve",
                     "--bind", bind, "--port", str(port), cwd=tmp_path, timeout=60)
    one_line_error(proc, f"--port {port}: address already in use")
    _nothing_written(tmp_path)


def test_web_viewer_port_in_use_is_one_line(tmp_path: Path) -> None:
    """Served on every interface the web viewer needs port 9090: taken (here on loopback), one
    line naming it, before anything is served."""
    import socket

    from wfviz.record.live import WEB_PORT
    from wfviz.record.screenshot import _free_port

    with socket.socket() as held:
        try:
            held.bind(("127.0.0.1", WEB_PORT))
        except OSError:
            pytest.skip(f"port {WEB_PORT} is in use here already")
        held.listen()
        proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "2", "-o", "x.rrd", "--serve",
                     "--bind", "0.0.0.0", "--port", str(_free_port()), cwd=tmp_path, timeout=60)
    one_line_error(proc, f"web viewer port {WEB_PORT}", "already in use")
    _nothing_written(tmp_path)


@contextmanager
def _listener(mode: str, seconds: float = 120.0) -> Iterator[int]:
    """A loopback TCP port whose listener accepts every connection and then holds it without
    reading or writing (``hold``: a viewer that never answers) or closes it at once
    (``close``); the thread stops by itself after ``seconds`` or when the block ends."""
    import socket
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(16)
    server.settimeout(0.2)
    stop = threading.Event()
    held: list[socket.socket] = []

    def serve() -> None:
        end = time.monotonic() + seconds
        while not stop.is_set() and time.monotonic() < end:
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            if mode == "close":
                conn.close()
            else:
                held.append(conn)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        stop.set()
        thread.join(5)
        for conn in held:
            conn.close()
        server.close()


@pytest.mark.parametrize("mode", ["hold", "close"])
def test_a_viewer_that_never_answers_costs_at_most_the_bound(tmp_path: Path, mode: str) -> None:
    """Streaming to a listener that accepts and never answers (or closes at once): the run
    ends, waiting for the live side at most LIVE_WAIT_SECONDS, with the whole file under its
    name and one note."""
    from wfviz.record.live import LIVE_WAIT_SECONDS

    with _listener(mode) as port:
        proc = wfviz("record", "synth:lowsnr-tbd:0", "--tracker", "tbd", "--stop", "5", "-o", "bh.rrd",
                     "--connect", f"rerun+http://127.0.0.1:{port}/proxy", cwd=tmp_path,
                     timeout=LIVE_WAIT_SECONDS + 60)
    assert proc.returncode == 0, proc.stderr
    notes = [ln for ln in proc.stderr.splitlines() if ln.startswith("wfviz: note: live view:")]
    assert len(notes) == 1 and notes[0].endswith("the file is complete"), proc.stderr
    seconds = float(re.search(r"5 frames in ([0-9.]+) s", proc.stdout).group(1))  # the run, end included
    assert seconds < LIVE_WAIT_SECONDS + 5, proc.stdout
    assert _frames(tmp_path / "bh.rrd") == list(range(5))
    assert RrdReader(tmp_path / "bh.rrd").store() is not None  # the footer is written
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".wfviz-part")]
