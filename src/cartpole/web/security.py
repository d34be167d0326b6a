"""What keeps a local web app local: allowed hosts, same-origin WebSockets, response headers, URL size,
and the server's token, without which nothing is changed (:class:`TokenGate`).

A page on any other site the user visits can send requests to 127.0.0.1 (and, through DNS
rebinding, read the answers) and open WebSockets to it. So every request must name one of the
hosts this server was started for (Starlette's ``TrustedHostMiddleware``), and a WebSocket
handshake that a browser makes from another origin is refused. Every answer carries a Content
Security Policy that allows only this server's own scripts and styles, and no framing.

These are plain ASGI middlewares (not ``BaseHTTPMiddleware``): they add nothing measurable to a
play step's round trip. Their refusals have the app's one shape (``{"detail", "field"}``,
:func:`~cartpole.web.answers.refusal`); a refused WebSocket is closed with code 1008 and a reason.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterable
from typing import Any
from urllib.parse import parse_qs, urlencode, urlsplit

from starlette.datastructures import Headers
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.responses import PlainTextResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from starlette.websockets import WebSocketClose

from cartpole.web import answers

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
        "img-src 'self' data: blob:",
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


HOST_CHECKED = "cartpole.host_checked"
"""The scope key :class:`OwnHosts` sets on a request whose host it let through."""


class OwnHosts(TrustedHostMiddleware):
    """Starlette's ``TrustedHostMiddleware`` (its check of the ``Host`` header, unchanged, and no
    ``www.`` redirect), its 400 refusal in the app's one shape."""

    def __init__(self, app: ASGIApp, allowed_hosts: Iterable[str]) -> None:
        async def checked(scope: Scope, receive: Receive, send: Send) -> None:
            scope[HOST_CHECKED] = True
            await app(scope, receive, send)

        super().__init__(checked, allowed_hosts=list(allowed_hosts), www_redirect=False)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await super().__call__(scope, receive, send)
            return
        refused = False

        async def send_or_refuse(message: Message) -> None:
            nonlocal refused
            if message["type"] == "http.response.start" and not scope.get(HOST_CHECKED):
                refused = True  # Starlette's own refusal: answered in the app's shape instead
                text = "this server does not answer requests for that host (see cartpole serve --allow-host)"
                await answers.refusal(400, text)(scope, receive, send)
            elif not refused:
                await send(message)

        await super().__call__(scope, receive, send_or_refuse)


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
                    await answers.refusal(414, text)(scope, receive, send)
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


# ---------------------------------------------------------------------------------------------------
# The server's token: what starting, stopping and resuming trainings need
# ---------------------------------------------------------------------------------------------------

TOKEN_COOKIE = "cartpole_token"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
"""Methods that change nothing; every other one is a change."""


def new_token() -> str:
    """A token no page can guess (as Jupyter's): 256 random bits, in hex, so that it never starts with '-'
    and `--token TOKEN` takes it as it is printed."""
    return secrets.token_hex(32)


class TokenGate:
    """What a request must carry to be answered.

    A change (any method but GET, HEAD and OPTIONS) needs the server's token, in the ``cartpole_token``
    cookie or as ``Authorization: Bearer TOKEN`` (401 without it or with a wrong one), and, when it
    comes from a browser, the server's own origin (``Origin``, ``Sec-Fetch-Site``: 403 from another
    site); on a read-only server every change gets 403. With ``reads_need_token`` (a server bound to
    more than this machine) every request needs the token, WebSockets too.

    Opening any page with ``?token=TOKEN`` (the address ``cartpole serve`` prints) sets the cookie,
    HttpOnly and SameSite=Strict, and redirects to the same address without the token.
    """

    def __init__(self, app: ASGIApp, token: str, read_only: bool = False, reads_need_token: bool = False):
        self.app = app
        self.token = token.encode()
        self.read_only = read_only
        self.reads_need_token = reads_need_token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        if scope["type"] == "websocket":
            if self.reads_need_token and not self.carries_token(headers):
                await WebSocketClose(code=1008, reason="this server needs its token")(scope, receive, send)
                return
            await self.app(scope, receive, send)
            return
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        if scope["method"] == "GET" and "token" in query:
            await self.token_in_address(scope, query, receive, send)
            return
        change = scope["method"] not in SAFE_METHODS
        refusal = self.refusal(headers, change)
        if refusal is not None:
            status, text = refusal
            await answers.refusal(status, text)(scope, receive, send)
            return
        await self.app(scope, receive, send)

    def refusal(self, headers: Headers, change: bool) -> tuple[int, str] | None:
        """(status, one line) for a request that may not be answered; None for one that may."""
        if change and self.read_only:
            return 403, "this server is read-only (cartpole serve --read-only): it changes nothing"
        if change and not from_own_origin(headers):
            return 403, "a change must come from this app's own pages (cross-origin request refused)"
        if (change or self.reads_need_token) and not self.carries_token(headers):
            return 401, (
                "this needs the server's token: open the address `cartpole serve` printed (with ?token=), "
                "or send Authorization: Bearer TOKEN"
            )
        return None

    def carries_token(self, headers: Headers) -> bool:
        scheme, _, given = headers.get("authorization", "").partition(" ")
        if scheme.lower() == "bearer" and self.matches(given.strip()):
            return True
        cookie = cookie_value(headers.get("cookie", ""), TOKEN_COOKIE)
        return cookie is not None and self.matches(cookie)

    def matches(self, given: str) -> bool:
        return secrets.compare_digest(given.encode("utf-8", "replace"), self.token)

    async def token_in_address(
        self, scope: Scope, query: dict[str, list[str]], receive: Receive, send: Send
    ) -> None:
        """``?token=``: a right one sets the cookie and redirects to the address without it; 401 otherwise."""
        if not self.matches(query["token"][-1]):
            text = "wrong token: open the address `cartpole serve` printed"
            await answers.refusal(401, text)(scope, receive, send)
            return
        rest = urlencode([(k, v) for k, values in query.items() if k != "token" for v in values])
        location = scope.get("root_path", "") + scope["path"] + (f"?{rest}" if rest else "")
        cookie = f"{TOKEN_COOKIE}={self.token.decode()}; Path=/; HttpOnly; SameSite=Strict"
        headers = {"location": location, "set-cookie": cookie, "cache-control": "no-store"}
        await PlainTextResponse("", status_code=303, headers=headers)(scope, receive, send)


def from_own_origin(headers: Headers) -> bool:
    """Whether a request comes from this server's own pages or from a program (no ``Origin``): a
    browser names the page's origin on every change and says ``Sec-Fetch-Site`` where it knows it."""
    if headers.get("sec-fetch-site", "same-origin") not in ("same-origin", "none"):
        return False
    origin = headers.get("origin")
    return origin is None or _same_origin(origin, headers.get("host", ""))


def cookie_value(header: str, name: str) -> str | None:
    for part in header.split(";"):
        key, sep, value = part.strip().partition("=")
        if sep and key == name:
            return value
    return None
