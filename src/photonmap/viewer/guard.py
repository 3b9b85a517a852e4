"""Who may drive the viewer: its own page only (docs/viewer.md, Security).

An ASGI middleware in front of the application (:func:`guarded`) answers every request and
WebSocket handshake before the application sees it:

- ``Host`` must name this server (``127.0.0.1``, ``localhost``, ``::1`` or the ``--host`` it is
  bound to): a page on another site that rebinds its own name to 127.0.0.1 (DNS rebinding) is
  refused (421);
- ``Origin``, when a browser sends one, must be the server's own (scheme, host and port): a
  cross-site request or WebSocket is refused (403);
- every request but the page's static files carries the server's random token (made per server,
  as Jupyter does): in the URL the server prints and opens (``/?token=…``, which also sets a
  ``SameSite=Strict`` cookie for the page's own requests), as an ``X-Photonmap-Token`` header
  or ``Authorization: token …``; without it 403;
- a POST body must be JSON (``Content-Type: application/json``; 415; an empty body, as
  ``/api/reset`` takes, has nothing to declare) of at most :data:`MAX_BODY` bytes (413), so that
  no form or ``text/plain`` request of another page is a "simple request" the browser sends
  without asking.

Refusals are one short JSON ``{"detail": ...}`` that never repeats what was sent.
"""

from __future__ import annotations

import hmac
import json
import secrets
import socket
from http.cookies import SimpleCookie
from urllib.parse import parse_qs, urlsplit

MAX_BODY = 1 << 20  # bytes of a request body
COOKIE = "photonmap_token"
LOOPBACK = ("127.0.0.1", "localhost", "::1")
PUBLIC = ("/static/", "/favicon.ico")  # the page's own files: no state, no token


def new_token() -> str:
    """A random token for one server (URL-safe, 192 bits)."""
    return secrets.token_urlsafe(24)


def allowed_hosts(bound: str) -> set[str]:
    """The host names a request may give for a server bound to ``bound``: the loopback names,
    ``bound`` itself, and for a wildcard address (``0.0.0.0``, ``::``) this machine's names and
    addresses."""
    hosts = {*LOOPBACK, bound.strip("[]").lower()}
    if bound in ("0.0.0.0", "::", ""):
        try:
            name = socket.gethostname()
            hosts |= {name.lower(), socket.getfqdn().lower()}
            hosts |= {info[4][0] for info in socket.getaddrinfo(name, None)}
        except OSError:
            pass
    return hosts


def _split_host(value: str) -> tuple[str, int | None]:
    """``"127.0.0.1:8000"`` → ("127.0.0.1", 8000); ``"[::1]:80"`` → ("::1", 80)."""
    try:
        parts = urlsplit(f"//{value}")
        return (parts.hostname or "").lower(), parts.port
    except ValueError:
        return "", None


class Guard:
    """The ASGI middleware of the module docstring."""

    def __init__(self, app, token: str, hosts: set[str], port: int | None = None):
        self.app = app
        self.token = token
        self.hosts = hosts
        self.port = port

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        why = self._refusal(scope, headers)
        if why is not None:
            return await _refuse(scope, receive, send, *why)
        if scope["type"] == "http" and scope["method"] == "POST":
            body = await _read_body(headers, receive)
            if body is None:
                return await _refuse(scope, receive, send, 413,
                                     f"the request body exceeds {MAX_BODY} bytes")  # fmt: skip
            receive = _replay(body)
        started = []

        async def tracked(message):
            if message["type"] in ("http.response.start", "websocket.accept"):
                started.append(True)
            await send(message)

        try:
            await self.app(scope, receive, tracked)
        except Exception as exc:  # noqa: BLE001 - one line in the log, never a traceback
            first = (str(exc).strip().splitlines() or [""])[0][:120]
            print(f"photonmap view: {scope.get('path', '')} failed: {type(exc).__name__}: "
                  f"{first}", flush=True)  # fmt: skip
            if not started and scope["type"] == "http":
                await _refuse(scope, receive, send, 500,
                              f"internal error ({type(exc).__name__})")  # fmt: skip

    def _refusal(self, scope, headers) -> tuple[int, str] | None:
        host, port = _split_host(headers.get("host", ""))
        if host not in self.hosts or (self.port and port not in (None, self.port)):
            return 421, "this server answers only to its own address (check the Host header)"
        origin = headers.get("origin")
        if origin is not None and not self._own_origin(origin):
            return 403, "requests from other sites are refused (Origin)"
        path = scope.get("path", "")
        if scope["type"] == "http" and scope["method"] in ("GET", "HEAD"):
            if any(path.startswith(p) for p in PUBLIC):
                return None
        if not self._authorised(scope, headers):
            return 403, (
                "a token is required: open the URL that 'photonmap view' printed (…/?token=…), "
                "or send the X-Photonmap-Token header"
            )
        if scope["type"] == "http" and scope["method"] == "POST":
            kind = headers.get("content-type", "").split(";")[0].strip().lower()
            empty = headers.get("content-length", "0") == "0" and "transfer-encoding" not in headers
            if kind != "application/json" and not empty:
                return 415, "POST bodies must be JSON (Content-Type: application/json)"
        return None

    def _own_origin(self, origin: str) -> bool:
        try:
            parts = urlsplit(origin)
            port = parts.port or {"http": 80, "https": 443}.get(parts.scheme)
        except ValueError:
            return False
        host = (parts.hostname or "").lower()
        return parts.scheme == "http" and host in self.hosts and (
            not self.port or port == self.port
        )

    def _authorised(self, scope, headers) -> bool:
        given = []
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        given += query.get("token", [])
        given.append(headers.get("x-photonmap-token", ""))
        auth = headers.get("authorization", "").split(None, 1)
        if len(auth) == 2 and auth[0].lower() in ("token", "bearer"):
            given.append(auth[1].strip())
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:  # noqa: BLE001 - a malformed cookie header counts as none
            pass
        if COOKIE in cookie:
            given.append(cookie[COOKIE].value)
        return any(hmac.compare_digest(g.encode(), self.token.encode()) for g in given if g)


async def _read_body(headers, receive) -> bytes | None:
    """The whole request body, or None once it passes :data:`MAX_BODY` bytes."""
    length = headers.get("content-length", "")
    if length.isdigit() and int(length) > MAX_BODY:
        return None
    chunks, size = [], 0
    while True:
        message = await receive()
        if message["type"] == "http.disconnect":
            break
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > MAX_BODY:
            return None
        chunks.append(chunk)
        if not message.get("more_body", False):
            break
    return b"".join(chunks)


def _replay(body: bytes):
    sent = False

    async def receive():
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return {"type": "http.disconnect"}

    return receive


async def _refuse(scope, receive, send, status: int, detail: str) -> None:
    if scope["type"] == "websocket":
        await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
        return
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode())]})  # fmt: skip
    await send({"type": "http.response.body", "body": body})
