"""Who may talk to the dashboard: access token, Host check, request size limit.

One pure ASGI middleware guards every route of the server: pages, static files, file
downloads, uploads and the websocket (socket.io is mounted inside the same app, so its
HTTP long-polling and websocket requests pass through here too).

* **Access token** (required whenever the server listens on anything but loopback): a
  request is let in if it carries the token as ``Authorization: Bearer <token>``, as the
  cookie set below, or as ``?token=<token>`` in the address. The address form is what a
  person opens (the one ``fielddiag serve`` prints); the server answers it with a
  redirect to the same address without the token and sets an HttpOnly, SameSite=Strict
  cookie, so the token does not stay in the address bar or the history. Anything else
  gets 401 (HTTP) or a refused handshake (websocket).
* **Host check** on loopback without a token: only ``localhost``/``127.0.0.1``/``[::1]``
  Host headers are accepted, so a web page on the internet cannot reach the dashboard
  through DNS rebinding.
* **Size limit** on request bodies (uploads): a declared ``Content-Length`` over the
  limit is refused at once with 413; a chunked body is counted and cut off at the limit.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from collections.abc import Awaitable, Callable, MutableMapping
from http.cookies import SimpleCookie
from typing import Any
from urllib.parse import parse_qsl, urlencode

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

TOKEN_QUERY = "token"
LOOPBACK_HOST_NAMES = ("localhost", "127.0.0.1", "::1")
DEFAULT_MAX_BODY_BYTES = 200_000_000

__all__ = ["SecurityMiddleware", "cookie_name", "is_loopback", "new_token"]


def is_loopback(host: str) -> bool:
    """True if ``host`` (an address or name the server binds to) is reachable only locally."""
    h = host.strip().strip("[]").lower()
    if h == "localhost":
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    """A fresh random access token (32 URL-safe characters, 192 bits)."""
    return secrets.token_urlsafe(24)


def cookie_name(port: int | None) -> str:
    """Name of the token cookie (per port: cookies are shared between ports of a host)."""
    return f"fielddiag_token_{port}" if port else "fielddiag_token"


def _headers(scope: Scope) -> dict[str, str]:
    out: dict[str, str] = {}
    for k, v in scope.get("headers", []):
        key = k.decode("latin-1").lower()
        val = v.decode("latin-1")
        out[key] = f"{out[key]}; {val}" if key == "cookie" and key in out else val
    return out


def _host_name(host_header: str) -> str:
    """The name part of a Host header (``[::1]:8080`` -> ``::1``)."""
    h = host_header.strip().lower()
    if h.startswith("["):
        return h[1 : h.find("]")] if "]" in h else h[1:]
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


async def _send_text(send: Send, status: int, text: str, headers: list | None = None) -> None:
    body = text.encode("utf-8")
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"text/plain; charset=utf-8"),
                (b"content-length", str(len(body)).encode()),
                (b"cache-control", b"no-store"),
                *(headers or []),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class _BodyTooLarge(Exception):
    pass


class SecurityMiddleware:
    """ASGI middleware: token, Host check and body size limit (see the module docstring).

    Parameters
    ----------
    app : ASGI app
    token : str or None
        Required access token; None lets every request in (loopback only).
    check_host : bool
        Accept only loopback Host headers (use when listening on loopback without a token).
    max_body_bytes : int
        Largest request body (an upload) accepted.
    port : int or None
        Server port, for the cookie name.
    """

    def __init__(
        self,
        app: ASGIApp,
        *,
        token: str | None = None,
        check_host: bool = False,
        max_body_bytes: int = DEFAULT_MAX_BODY_BYTES,
        port: int | None = None,
    ) -> None:
        self.app = app
        self.token = token
        self.check_host = check_host
        self.max_body_bytes = int(max_body_bytes)
        self.cookie = cookie_name(port)

    def _token_ok(self, supplied: str | None) -> bool:
        return bool(supplied) and hmac.compare_digest(
            str(supplied).encode("utf-8"), str(self.token).encode("utf-8")
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope.get("type")
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _headers(scope)
        if self.check_host and _host_name(headers.get("host", "")) not in LOOPBACK_HOST_NAMES:
            await self._refuse(scope, send, 403, "this dashboard answers only on localhost")
            return
        if self.token is not None:
            query = parse_qsl(scope.get("query_string", b"").decode("latin-1"), True)
            from_query = next((v for k, v in query if k == TOKEN_QUERY), None)
            auth = headers.get("authorization", "")
            bearer = auth[7:].strip() if auth.lower().startswith("bearer ") else None
            cookies = SimpleCookie()
            try:
                cookies.load(headers.get("cookie", ""))
            except Exception:  # a malformed cookie header is just no cookie
                cookies = SimpleCookie()
            from_cookie = cookies[self.cookie].value if self.cookie in cookies else None
            if kind == "http" and from_query is not None and self._token_ok(from_query):
                await self._redirect_setting_cookie(scope, send, query)
                return
            if not (self._token_ok(bearer) or self._token_ok(from_cookie)
                    or self._token_ok(from_query)):
                await self._refuse(
                    scope,
                    send,
                    401,
                    "access token required: open the address printed by `fielddiag serve` "
                    "(it ends with ?token=...)",
                )
                return
        if kind == "http" and scope.get("method", "GET") not in ("GET", "HEAD", "OPTIONS"):
            await self._limited(scope, receive, send, headers)
            return
        await self.app(scope, receive, send)

    async def _refuse(self, scope: Scope, send: Send, status: int, text: str) -> None:
        if scope["type"] == "websocket":
            # Closing before accepting makes the server answer the handshake with 403.
            await send({"type": "websocket.close", "code": 1008, "reason": text[:120]})
        else:
            await _send_text(send, status, text + "\n", [(b"www-authenticate", b"Bearer")]
                             if status == 401 else None)

    async def _redirect_setting_cookie(
        self, scope: Scope, send: Send, query: list[tuple[str, str]]
    ) -> None:
        rest = urlencode([(k, v) for k, v in query if k != TOKEN_QUERY])
        location = (scope.get("root_path", "") + scope.get("path", "/")) + (
            f"?{rest}" if rest else ""
        )
        cookie = (
            f"{self.cookie}={self.token}; Path=/; HttpOnly; SameSite=Strict; Max-Age=2592000"
        )
        await send(
            {
                "type": "http.response.start",
                "status": 303,
                "headers": [
                    (b"location", location.encode("latin-1")),
                    (b"set-cookie", cookie.encode("latin-1")),
                    (b"cache-control", b"no-store"),
                    (b"content-length", b"0"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": b""})

    async def _limited(self, scope: Scope, receive: Receive, send: Send, headers: dict) -> None:
        limit = self.max_body_bytes
        declared = headers.get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await _send_text(
                send, 413, f"upload too large: the limit is {limit / 1e6:g} MB\n"
            )
            return
        seen = 0
        started = False
        too_large = False

        async def counting_receive() -> Message:
            nonlocal seen, too_large
            message = await receive()
            if message.get("type") == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    too_large = True
                    raise _BodyTooLarge
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if too_large:
                return  # whatever the app answers to a body cut off, the answer is 413
            if message.get("type") == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, guarded_send)
        except Exception:
            if not too_large:
                raise
        if too_large and not started:
            await _send_text(send, 413, f"upload too large: the limit is {limit / 1e6:g} MB\n")
