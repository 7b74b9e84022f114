"""Watching a recording while it is written, for ``wfviz record --spawn | --connect URL |
--serve``: the .rrd file has a recording stream of its own, and :class:`LiveMirror` repeats
every call on a second stream, the live one, from a worker thread. The file never waits on the
network: a viewer closed, never reached or stalled (one that accepts and never reads applies
back-pressure to Rerun's gRPC client, which would otherwise hold up a shared stream, file sink
included) only loses the live view, and costs at most ``LIVE_WAIT_SECONDS`` at the end, after
the file is complete."""

from __future__ import annotations

import errno
import ipaddress
import queue
import re
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

import rerun as rr

MODES = ("spawn", "connect", "serve")
DEFAULT_PORT = 9876
WEB_PORT = 9090
SCHEMES = ("rerun", "rerun+http", "rerun+https")
LIVE_WAIT_SECONDS = 10.0  # at the end, after the file is complete: the live side's time, at most
LIVE_QUEUE = 4096  # calls the live stream may lag behind the file before the live view stops
_HOST_NAME = re.compile(r"(?=.{1,253}$)[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"
                        r"(?:\.[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?)*\.?")
_URL_HINT = "expected rerun+http://HOST:PORT/proxy"


@dataclass(frozen=True)
class Live:
    """Where to stream besides the file: ``spawn`` a viewer (or use the one on ``port``),
    ``connect`` to ``url`` (``rerun+http://HOST:PORT/proxy``), or ``serve`` a gRPC server on
    ``bind``:``port`` while the run lasts (with a web viewer on ``web_port`` when served on
    every interface). ``bind`` is an IP address (see :func:`live_view` for host names)."""

    mode: str
    url: str | None = None
    bind: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    web_port: int = WEB_PORT

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"live view: unknown mode '{self.mode}' (available: {', '.join(MODES)})")
        if self.mode == "connect":
            check_url(self.url or "")
        if self.mode == "serve" and _ip(self.bind) is None:
            raise ValueError(f"--bind {self.bind!r}: not an IP address")

    @property
    def grpc_url(self) -> str:
        """The URL a viewer reads the stream from."""
        if self.mode == "connect":
            return str(self.url)
        host = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(self.bind, self.bind)
        return f"rerun+http://{_url_host(host)}:{self.port}/proxy"

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


def live_view(mode: str, url: str | None = None, bind: str = "127.0.0.1", port: int = DEFAULT_PORT) -> Live:
    """The checked :class:`Live` for the command line: ``--connect`` URL parsed in full,
    ``--bind`` resolved to an address (a host name to its first IPv4 address, else IPv6) and,
    for ``serve``, the gRPC port (and the web viewer's when public) free. Any problem: one
    ValueError naming the option, before anything is started."""
    if mode != "serve":
        return Live(mode, url=url, port=port)
    live = Live(mode, bind=resolve_bind(bind), port=port)
    if live.public:
        _check_free("0.0.0.0", live.web_port, f"web viewer port {live.web_port}",
                    f"(hosted with --bind {bind}; free it or serve on 127.0.0.1)")
    _check_free(live.bind, port, f"--port {port}", f"(on {bind}; choose another --port)", bind=bind)
    return live


def check_url(url: str) -> None:
    """ValueError naming ``--connect`` unless ``url`` is ``SCHEME://HOST:PORT/proxy`` with a
    rerun scheme, a host name or IP address and a port 1-65535."""
    where = f"--connect {url}"
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        why = "port out of range (1-65535)" if "port" in str(exc).lower() else str(exc).lower()
        raise ValueError(f"{where}: {why} ({_URL_HINT})") from None
    if parts.scheme.lower() not in SCHEMES:
        raise ValueError(f"{where}: {_URL_HINT}")
    host = parts.hostname or ""
    if not host:
        raise ValueError(f"{where}: no host ({_URL_HINT})")
    if not (_ip(host) or _HOST_NAME.fullmatch(host)):
        raise ValueError(f"{where}: '{host}' is not a host name or IP address ({_URL_HINT})")
    if parts.username is not None or parts.query or parts.fragment:
        raise ValueError(f"{where}: unexpected user, query or fragment ({_URL_HINT})")
    if port is None or port == 0:
        raise ValueError(f"{where}: {'no port' if port is None else 'port 0'} ({_URL_HINT}, PORT 1-65535)")
    if parts.path != "/proxy":
        raise ValueError(f"{where}: path must be /proxy ({_URL_HINT})")


def resolve_bind(bind: str) -> str:
    """The IP address ``bind`` names (an address as it is, ``[v6]`` unbracketed, a host name
    resolved); ValueError naming ``--bind`` if it is empty, malformed or unknown."""
    text = bind.strip()
    if text.startswith("[") and text.endswith("]"):
        text = text[1:-1]
    if not text:
        raise ValueError(f"--bind {bind!r}: empty address (give an IP address such as 127.0.0.1, or a host name)")
    ip = _ip(text)
    if ip is not None:
        return ip
    if re.fullmatch(r"[0-9.]+", text) or ":" in text or not _HOST_NAME.fullmatch(text):
        raise ValueError(f"--bind {bind}: not an IP address or host name")
    try:
        infos = socket.getaddrinfo(text, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        why = exc.strerror if isinstance(exc, socket.gaierror) else str(exc)
        raise ValueError(f"--bind {bind}: cannot resolve this host name ({why})") from None
    addrs = [str(info[4][0]) for info in infos if info[0] in (socket.AF_INET, socket.AF_INET6)]
    addrs = [a for a in addrs if "%" not in a]
    if not addrs:
        raise ValueError(f"--bind {bind}: this host name has no IP address")
    return next((a for a in addrs if ":" not in a), addrs[0])


def _ip(text: str) -> str | None:
    """``text`` as a normalised IPv4 or IPv6 address (no zone), or None."""
    try:
        return str(ipaddress.ip_address(text)) if "%" not in text else None
    except ValueError:
        return None


def _url_host(ip: str) -> str:
    """``ip`` as the host part of a URL or of Rerun's ``"{ip}:{port}"`` (IPv6 in brackets)."""
    return f"[{ip}]" if ":" in ip else ip


def _check_free(addr: str, port: int, what: str, hint: str, bind: str | None = None) -> None:
    """ValueError unless a server could listen on ``addr``:``port`` now (a probe socket, closed
    again at once; address reuse as Rerun's servers set it)."""
    family = socket.AF_INET6 if ":" in addr else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((addr, port))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise ValueError(f"{what}: address already in use {hint}") from None
        if exc.errno == errno.EADDRNOTAVAIL and bind is not None:
            raise ValueError(f"--bind {bind}: {addr} is not an address of this machine") from None
        raise ValueError(f"{what}: cannot listen on {addr} ({exc.strerror or exc})") from None


def live_sink(live: Live) -> Any:
    """The live sink (starting a viewer or a server first when asked); Rerun refusing it:
    ValueError naming the option."""
    try:
        if live.mode == "spawn":
            rr.spawn(port=live.port, connect=False, hide_welcome_screen=True)
            return rr.GrpcSink(live.grpc_url)
        if live.mode == "connect":
            return rr.GrpcSink(live.grpc_url)
        sink = rr.GrpcServerSink(bind_ip=_url_host(live.bind), port=live.port)  # Rerun parses "{ip}:{port}"
        if live.public:
            rr.serve_web_viewer(web_port=live.web_port, open_browser=False, connect_to=live.grpc_url)
        return sink
    except (RuntimeError, OSError) as exc:
        option = {"spawn": "--spawn", "connect": f"--connect {live.url}"}.get(live.mode, f"--serve on {live.bind}")
        raise ValueError(f"{option}: {' '.join(str(exc).split())}") from None


class LiveMirror:
    """A recording stream (``file``) whose calls (``log``, ``send_columns``, ``set_time``,
    ``send_blueprint``) are repeated in order on ``live`` by a worker thread, each caller
    thread's time context kept apart. Falling ``LIVE_QUEUE`` calls behind, or a live call
    failing, stops the live view (:attr:`problem` says why); the file goes on."""

    def __init__(self, file: rr.RecordingStream, live: rr.RecordingStream) -> None:
        self.file, self.live = file, live
        self.problem: str | None = None
        self._flush_seconds = LIVE_WAIT_SECONDS
        self._queue: queue.Queue[tuple[int, str, tuple, dict] | None] = queue.Queue(LIVE_QUEUE)
        self._done = threading.Event()
        self._worker = threading.Thread(target=self._replay, name="wfviz-live", daemon=True)
        self._worker.start()

    def log(self, *args: Any, **kwargs: Any) -> None:
        self.file.log(*args, **kwargs)
        self._mirror("log", args, kwargs)

    def send_columns(self, *args: Any, **kwargs: Any) -> None:
        self.file.send_columns(*args, **kwargs)
        self._mirror("send_columns", args, kwargs)

    def set_time(self, *args: Any, **kwargs: Any) -> None:
        self.file.set_time(*args, **kwargs)
        self._mirror("set_time", args, kwargs)

    def send_blueprint(self, *args: Any, **kwargs: Any) -> None:
        self.file.send_blueprint(*args, **kwargs)
        self._mirror("send_blueprint", args, kwargs)

    def _mirror(self, name: str, args: tuple, kwargs: dict) -> None:
        if self.problem is not None:
            return
        try:
            self._queue.put_nowait((threading.get_ident(), name, args, kwargs))
        except queue.Full:
            self.problem = f"the viewer fell {LIVE_QUEUE} calls behind, stopped streaming to it"

    def _replay(self) -> None:
        """The worker: every queued call on ``live``, then (at the end) flush and disconnect."""
        times: dict[int, dict[str, dict]] = {}
        current: int | None = None
        while (item := self._queue.get()) is not None:
            if self.problem is not None:
                continue
            tid, name, args, kwargs = item
            try:
                if name == "set_time":
                    times.setdefault(tid, {})[args[0]] = kwargs
                    if tid != current:
                        continue  # applied when this thread's next call is replayed
                elif tid != current:  # another caller thread: its own time context
                    self.live.reset_time()
                    for timeline, when in times.get(tid, {}).items():
                        self.live.set_time(timeline, **when)
                    current = tid
                getattr(self.live, name)(*args, **kwargs)
            except Exception as exc:  # noqa: BLE001 - the live side only
                self.problem = " ".join(str(exc).split()) or type(exc).__name__
        try:
            self.live.flush(timeout_sec=self._flush_seconds)
        except Exception as exc:  # noqa: BLE001 - e.g. "Flush timed out"
            self.problem = self.problem or " ".join(str(exc).split())
        self.live.disconnect()
        self._done.set()

    def end(self) -> str | None:
        """Let the live side take what is queued, flush and close, within
        ``LIVE_WAIT_SECONDS`` in all. Returns its problem (one line), or None. If it is still
        stuck then (a viewer that accepts and never reads holds Rerun's gRPC client), it is
        left to its daemon thread and Rerun's exit hook, which would wait for it with no time
        limit, is dropped."""
        end = time.monotonic() + LIVE_WAIT_SECONDS
        self._flush_seconds = max(0.5, LIVE_WAIT_SECONDS - 2.0)
        try:
            self._queue.put(None, timeout=LIVE_WAIT_SECONDS)
            self._done.wait(max(0.0, end - time.monotonic()))
        except queue.Full:
            pass
        if self._done.is_set():
            return self.problem
        rr.unregister_shutdown()
        return self.problem or f"the viewer took nothing for {LIVE_WAIT_SECONDS:g} s, left it"
