"""Watching a recording while it is written: the .rrd file sink plus a live one, for ``wfviz
record --spawn | --connect URL | --serve``. The file is written whatever happens to the live
side (a viewer closed or never reached only loses the live view)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import rerun as rr

MODES = ("spawn", "connect", "serve")
DEFAULT_PORT = 9876
WEB_PORT = 9090


@dataclass(frozen=True)
class Live:
    """Where to stream besides the file: ``spawn`` a viewer (or use the one on ``port``),
    ``connect`` to ``url`` (``rerun+http://HOST:PORT/proxy``), or ``serve`` a gRPC server on
    ``bind``:``port`` while the run lasts (with a web viewer on ``web_port`` when served on
    every interface)."""

    mode: str
    url: str | None = None
    bind: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    web_port: int = WEB_PORT

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"live view: unknown mode '{self.mode}' (available: {', '.join(MODES)})")
        if self.mode == "connect" and not (self.url or "").startswith(("rerun://", "rerun+http://", "rerun+https://")):
            raise ValueError(f"--connect {self.url}: expected rerun+http://HOST:PORT/proxy")

    @property
    def grpc_url(self) -> str:
        """The URL a viewer reads the stream from."""
        if self.mode == "connect":
            return str(self.url)
        host = "127.0.0.1" if self.bind in ("0.0.0.0", "") else self.bind
        return f"rerun+http://{host}:{self.port}/proxy"

    @property
    def public(self) -> bool:
        """Served on every interface: then a web viewer is hosted too (its HTTP server always
        binds every interface, so not on the loopback default)."""
        return self.mode == "serve" and self.bind in ("0.0.0.0", "::")

    def describe(self) -> str:
        """One line for the terminal: where the run can be watched."""
        if self.mode == "serve":
            if self.public:
                return f"serving {self.grpc_url} on every interface, with a web viewer on port {self.web_port}"
            return f"serving {self.grpc_url} while the run lasts (watch: rerun {self.grpc_url}, or rerun --web-viewer {self.grpc_url})"
        return f"streaming to {self.grpc_url}"


def sinks(path: Path, live: Live | None) -> list[object]:
    """The file sink for ``path`` and, with ``live``, the live one (starting a viewer or a
    server first when asked)."""
    out: list[object] = [rr.FileSink(str(path))]
    if live is None:
        return out
    if live.mode == "spawn":
        rr.spawn(port=live.port, connect=False, hide_welcome_screen=True)
        out.append(rr.GrpcSink(live.grpc_url))
    elif live.mode == "connect":
        out.append(rr.GrpcSink(live.grpc_url))
    else:
        out.append(rr.GrpcServerSink(bind_ip=live.bind, port=live.port))
        if live.public:
            rr.serve_web_viewer(web_port=live.web_port, open_browser=False, connect_to=live.grpc_url)
    return out
