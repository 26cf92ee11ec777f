"""Safety of the dashboard: token off localhost, Host check, path traversal, upload limit."""

from __future__ import annotations

import ipaddress
import re
import socket
import subprocess
import sys
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import PlainTextResponse
from starlette.routing import Route, WebSocketRoute
from web_helpers import LiveServer

from fielddiag.web.app import machine_address
from fielddiag.web.security import SecurityMiddleware, cookie_name, is_loopback, new_token

TOKEN = "s3cret-token-for-tests"


# ----------------------------------------------------------------------------- unit level
def _client(app, base_url: str) -> httpx.AsyncClient:
    return httpx.AsyncClient(transport=httpx.ASGITransport(app), base_url=base_url)


def _app(**kw) -> SecurityMiddleware:
    async def hello(request: Request) -> PlainTextResponse:
        body = await request.body()
        return PlainTextResponse(f"ok {len(body)}")

    async def ws(websocket) -> None:
        await websocket.accept()
        await websocket.send_text("hi")
        await websocket.close()

    inner = Starlette(routes=[Route("/{p:path}", hello, methods=["GET", "POST"]),
                              WebSocketRoute("/ws", ws)])
    return SecurityMiddleware(inner, **kw)


@pytest.mark.parametrize(
    ("host", "loopback"),
    [("127.0.0.1", True), ("localhost", True), ("::1", True), ("[::1]", True),
     ("127.0.0.2", True), ("0.0.0.0", False), ("192.168.1.20", False), ("::", False),
     ("myhost.example", False)],
)
def test_is_loopback(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_new_tokens_are_long_and_different() -> None:
    a, b = new_token(), new_token()
    assert a != b and len(a) >= 32 and re.fullmatch(r"[A-Za-z0-9_\-]+", a)


@pytest.mark.anyio
async def test_token_guards_every_http_route() -> None:
    app = _app(token=TOKEN, port=8080)
    async with _client(app, "http://10.0.0.5:8080") as c:
        for path in ("/", "/files/car-a/before.h5", "/_nicegui/3.18.0/static/nicegui.js",
                     "/_nicegui_ws/socket.io/?EIO=4&transport=polling"):
            r = await c.get(path)
            assert r.status_code == 401, path
            assert "access token required" in r.text
        assert (await c.get("/", params={"token": "wrong"})).status_code == 401
        assert (await c.get("/", headers={"Authorization": "Bearer wrong"})).status_code == 401
        assert (await c.get("/", headers={"Authorization": f"Bearer {TOKEN}"})).text == "ok 0"
        # the address with the token: redirect without it, cookie set
        r = await c.get("/session", params={"path": "a/b.h5", "token": TOKEN},
                        follow_redirects=False)
        assert r.status_code == 303
        assert r.headers["location"] == "/session?path=a%2Fb.h5"
        cookie = r.headers["set-cookie"]
        assert cookie.startswith(f"{cookie_name(8080)}={TOKEN};")
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
        # the cookie is enough from then on (the client kept it)
        assert (await c.get("/anything")).text == "ok 0"
        c.cookies.clear()
        assert (await c.get("/anything")).status_code == 401
        c.cookies.set(cookie_name(8080), "forged")
        assert (await c.get("/anything")).status_code == 401


@pytest.mark.anyio
async def test_loopback_without_token_accepts_only_local_host_headers() -> None:
    app = _app(token=None, check_host=True)
    async with _client(app, "http://127.0.0.1:8080") as c:
        assert (await c.get("/")).status_code == 200
        for host in ("localhost:8080", "[::1]:8080", "127.0.0.1"):
            assert (await c.get("/", headers={"Host": host})).status_code == 200, host
        for host in ("evil.example", "evil.example:8080", "127.0.0.1.evil.example"):
            r = await c.get("/", headers={"Host": host})
            assert r.status_code == 403, host


@pytest.mark.anyio
async def test_request_bodies_are_size_limited() -> None:
    app = _app(token=None, max_body_bytes=1000)
    async with _client(app, "http://127.0.0.1") as c:
        assert (await c.post("/up", content=b"x" * 1000)).text == "ok 1000"
        r = await c.post("/up", content=b"x" * 1001)
        assert r.status_code == 413 and "upload too large" in r.text

        async def chunks():  # no Content-Length: counted while streaming
            for _ in range(20):
                yield b"y" * 100

        r = await c.post("/up", content=chunks())
        assert r.status_code == 413


# ----------------------------------------------------------------------------- real server
def _ws_handshake(port: int, cookie: str | None = None) -> str:
    """Status line of a websocket upgrade to nicegui's socket.io endpoint."""
    req = (
        f"GET /_nicegui_ws/socket.io/?EIO=4&transport=websocket HTTP/1.1\r\n"
        f"Host: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
        + (f"Cookie: {cookie}\r\n" if cookie else "")
        + "\r\n"
    )
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(req.encode())
        return s.recv(4096).decode("latin-1").split("\r\n", 1)[0]


def test_server_off_localhost_requires_the_printed_token(sessions_root: Path) -> None:
    server = LiveServer(sessions_root, host="0.0.0.0")
    try:
        out = server.output()
        m = re.search(r"at (http://\S+/\?token=([A-Za-z0-9_\-]+))", out)
        assert m, out
        assert "access token required" in out
        token = m.group(2)
        # an address another machine can open, and the local one beside it
        assert urlsplit(m.group(1)).hostname == machine_address() not in ("0.0.0.0",
                                                                           "127.0.0.1")
        assert f"on this computer: http://127.0.0.1:{server.port}/?token={token}" in out
        with httpx.Client(base_url=server.url, timeout=10) as c:
            assert c.get("/").status_code == 401
            assert c.get("/files/car-a/before.h5").status_code == 401
            assert c.get("/_nicegui_ws/socket.io/?EIO=4&transport=polling").status_code == 401
            assert _ws_handshake(server.port).split(" ")[1] == "403"
            r = c.get(f"/?token={token}", follow_redirects=True)  # keeps the cookie
            assert r.status_code == 200 and "fielddiag" in r.text
            assert str(r.url) == f"{server.url}/"
            got = c.get("/files/car-a/before.h5")
            assert got.status_code == 200
            assert got.content == (sessions_root / "car-a" / "before.h5").read_bytes()
            cookie = f"{cookie_name(server.port)}={token}"
            assert _ws_handshake(server.port, cookie).split(" ")[1] == "101"
    finally:
        server.stop()


def test_address_of_a_wildcard_host_is_the_machines(tmp_path: Path, monkeypatch) -> None:
    from fielddiag.web import app

    for host in ("0.0.0.0", "::"):
        config = app.DashboardConfig(root=tmp_path, host=host, port=8123)
        url = app.address(config)
        shown = urlsplit(url).hostname
        assert shown == app.machine_address()
        assert url == f"http://{shown}:8123/?token={config.token}"
        try:
            assert not ipaddress.ip_address(shown).is_loopback
        except ValueError:  # no network: the host name, which resolves to no address
            assert shown == socket.gethostname()
    # a host given is shown as given; IPv6 in brackets
    assert app.address(app.DashboardConfig(root=tmp_path, host="192.168.1.20", port=80,
                                           token="t")) == "http://192.168.1.20:80/?token=t"
    assert app.address(app.DashboardConfig(root=tmp_path, host="fe80::1", port=80,
                                           token="t")) == "http://[fe80::1]:80/?token=t"
    assert app.address(app.DashboardConfig(root=tmp_path, port=80)) == "http://127.0.0.1:80/"

    # no route out and a host name that resolves to loopback (Debian's 127.0.1.1): the name
    class NoRoute:
        def __init__(self, *args) -> None:
            pass

        def __enter__(self):
            raise OSError("network is unreachable")

        def __exit__(self, *exc) -> None:
            pass

    monkeypatch.setattr(app.socket, "socket", NoRoute)
    monkeypatch.setattr(app.socket, "gethostname", lambda: "fieldlaptop")
    monkeypatch.setattr(app.socket, "gethostbyname", lambda name: "127.0.1.1")
    assert app.machine_address() == "fieldlaptop"


def test_given_token_is_honoured_on_localhost_too(sessions_root: Path) -> None:
    server = LiveServer(sessions_root, "--token", TOKEN)
    try:
        with httpx.Client(base_url=server.url, timeout=10) as c:
            assert c.get("/").status_code == 401
            assert c.get("/", headers={"Authorization": f"Bearer {TOKEN}"}).status_code == 200
    finally:
        server.stop()


def test_file_route_refuses_traversal_and_symlinks(live_server, sessions_root: Path,
                                                    tmp_path: Path) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text("top secret")
    (sessions_root / "escape").symlink_to(tmp_path)
    (sessions_root / "car-a" / "link.h5").symlink_to(secret)
    (sessions_root / "car-a" / "notes.txt").write_text("inside")
    with httpx.Client(base_url=live_server.url, timeout=10) as c:
        assert c.get("/files/car-a/notes.txt").text == "inside"
        for raw in ("/files/..%2Fsecret.txt", "/files/car-a%2F..%2F..%2Fsecret.txt",
                    "/files/%2E%2E/%2E%2E/secret.txt", "/files/%2Fetc%2Fpasswd",
                    "/files//etc/passwd", "/files/escape/secret.txt", "/files/car-a/link.h5"):
            r = c.get(raw)
            assert r.status_code == 403, (raw, r.status_code, r.text)
            assert "top secret" not in r.text and "root:" not in r.text
        assert c.get("/files/car-a/missing.h5").status_code == 404


def test_upload_over_the_limit_is_refused_by_the_server(sessions_root: Path) -> None:
    server = LiveServer(sessions_root, "--max-upload-mb", "0.01")
    try:
        with httpx.Client(base_url=server.url, timeout=10) as c:
            r = c.post("/_nicegui/client/x/upload/1", files={"f": ("a.csv", b"t,a,b\n" * 5000)})
            assert r.status_code == 413 and "upload too large" in r.text
    finally:
        server.stop()


def test_serve_command_errors_are_one_line(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "fielddiag.cli", "serve", "--root",
                        str(tmp_path / "missing")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.strip().startswith("fielddiag serve: error: sessions folder")
    assert "Traceback" not in r.stderr
