"""What keeps a local web app local: allowed hosts, same-origin WebSockets, response headers, URL size.

A page on any other site the user visits can send requests to 127.0.0.1 (and, through DNS
rebinding, read the answers) and open WebSockets to it. So every request must name one of the
hosts this server was started for (Starlette's ``TrustedHostMiddleware``), and a WebSocket
handshake that a browser makes from another origin is refused. Every answer carries a Content
Security Policy that allows only this server's own scripts and styles, and no framing.

These are plain ASGI middlewares (not ``BaseHTTPMiddleware``): they add nothing measurable to a
play step's round trip.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any
from urllib.parse import urlsplit

from starlette.datastructures import Headers
from starlette.responses import PlainTextResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from starlette.websockets import WebSocketClose

LOCAL_HOSTS = ("127.0.0.1", "localhost", "[::1]")
"""Hosts every server answers to: this machine under its usual names."""

WILDCARD_ADDRESSES = ("0.0.0.0", "::")
"""Addresses that mean "every interface": no request names them; name hosts with --allow-host."""

MAX_URL_BYTES = 16 * 1024
"""Longest path plus query string answered; longer ones get 414 (the longest episode query with a
nudge before each of 500 steps is about 13 KB)."""

MAX_HEADER_BYTES = 1024 * 1024
"""What uvicorn buffers of a request head, so that a long URL reaches the app and gets its 414
instead of a reset connection (h11's default is 16 KB)."""

MAX_WS_MESSAGE_BYTES = 64 * 1024
"""Largest WebSocket message uvicorn accepts; the app's own limit per message is smaller."""

SERVER_OPTIONS: dict[str, Any] = {
    "h11_max_incomplete_event_size": MAX_HEADER_BYTES,
    "ws_max_size": MAX_WS_MESSAGE_BYTES,
}
"""uvicorn options for the app (``uvicorn.run(app, host, port, **SERVER_OPTIONS)``)."""

CONTENT_SECURITY_POLICY = "; ".join(
    [
        "default-src 'self'",
        "script-src 'self'",
        "style-src 'self'",
        "img-src 'self' data:",
        "connect-src 'self'",
        "object-src 'none'",
        "base-uri 'none'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    ]
)

SECURITY_HEADERS = [
    (b"content-security-policy", CONTENT_SECURITY_POLICY.encode()),
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
    (b"cross-origin-resource-policy", b"same-origin"),
]


def host_name(host: str) -> str:
    """``host`` as it appears in a Host header without the port: IPv6 addresses in brackets."""
    host = host.strip().lower()
    if ":" in host and not host.startswith("["):
        return f"[{host}]"
    return host


def allowed_hosts(extra: Iterable[str] = ()) -> list[str]:
    """The local names plus ``extra`` (the address bound and any ``--allow-host``), without repeats."""
    hosts = dict.fromkeys(LOCAL_HOSTS)
    named = [h for h in extra if h.strip() and h.strip() not in WILDCARD_ADDRESSES]
    hosts.update(dict.fromkeys(host_name(h) for h in named))
    return list(hosts)


class SameOriginWebSockets:
    """Refuse a WebSocket handshake whose ``Origin`` is not this server's own (scheme-less compare of
    host and port with the ``Host`` header). Browsers always send ``Origin`` on a WebSocket; a
    handshake without one comes from a program, not from a page on another site, and is let in."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            headers = Headers(scope=scope)
            origin = headers.get("origin")
            if origin is not None and not _same_origin(origin, headers.get("host", "")):
                await WebSocketClose(code=1008, reason="cross-origin WebSocket refused")(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _same_origin(origin: str, host: str) -> bool:
    try:
        parts = urlsplit(origin)
    except ValueError:
        return False
    return parts.scheme in ("http", "https") and bool(host) and parts.netloc.lower() == host.lower()


class URLLengthLimit:
    """Answer 414 to a request whose path and query string together exceed ``MAX_URL_BYTES``."""

    def __init__(self, app: ASGIApp, max_bytes: int = MAX_URL_BYTES) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            size = len(scope.get("raw_path") or scope["path"].encode()) + len(scope.get("query_string", b""))
            if size > self.max_bytes:
                if scope["type"] == "websocket":
                    await WebSocketClose(code=1009, reason="URL too long")(scope, receive, send)
                else:
                    text = f"URL too long: at most {self.max_bytes} bytes of path and query"
                    await PlainTextResponse(text, status_code=414)(scope, receive, send)
                return
        await self.app(scope, receive, send)


class SecurityHeaders:
    """Add ``SECURITY_HEADERS`` to every HTTP answer (error answers included)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *SECURITY_HEADERS]
            await send(message)

        await self.app(scope, receive, send_with_headers)
