"""Watching a recording while it is written: the .rrd file sink plus a live one, for ``wfviz
record --spawn | --connect URL | --serve``. The file is written whatever happens to the live
side (a viewer closed or never reached only loses the live view)."""

from __future__ import annotations

import errno
import ipaddress
import re
import socket
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import rerun as rr

MODES = ("spawn", "connect", "serve")
DEFAULT_PORT = 9876
WEB_PORT = 9090
SCHEMES = ("rerun", "rerun+http", "rerun+https")
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


def sinks(path: Path, live: Live | None) -> list[object]:
    """The file sink for ``path`` and, with ``live``, the live one (starting a viewer or a
    server first when asked). Rerun refusing the live side: ValueError naming the option."""
    out: list[object] = [rr.FileSink(str(path))]
    if live is None:
        return out
    try:
        if live.mode == "spawn":
            rr.spawn(port=live.port, connect=False, hide_welcome_screen=True)
            out.append(rr.GrpcSink(live.grpc_url))
        elif live.mode == "connect":
            out.append(rr.GrpcSink(live.grpc_url))
        else:  # Rerun parses "{bind_ip}:{port}": an IPv6 address needs its brackets
            out.append(rr.GrpcServerSink(bind_ip=_url_host(live.bind), port=live.port))
            if live.public:
                rr.serve_web_viewer(web_port=live.web_port, open_browser=False, connect_to=live.grpc_url)
    except (RuntimeError, OSError) as exc:
        option = {"spawn": "--spawn", "connect": f"--connect {live.url}"}.get(live.mode, f"--serve on {live.bind}")
        raise ValueError(f"{option}: {' '.join(str(exc).split())}") from None
    return out

