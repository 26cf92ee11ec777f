"""The dashboard application: configuration, security, file serving, pages, ``serve``.

:func:`setup_app` registers everything on nicegui's app and returns the root page
function; :func:`serve` does that and runs the server until Ctrl-C. Pages live in
:mod:`fielddiag.web.pages` (one module per page) and are routed client-side with
``ui.sub_pages``, so moving between them keeps the connection.

Safety (see :mod:`fielddiag.web.security`): the server listens on 127.0.0.1 by default;
any other address requires an access token (given, or generated and printed). Files are
served only from under the sessions folder, addressed by a path relative to it, and
uploads are size-limited.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from fastapi import HTTPException
from fastapi.responses import FileResponse
from nicegui import app, ui

from fielddiag.catalog import Catalog, OutsideRootError, resolve_under_root
from fielddiag.downsample import DEFAULT_POINTS, PlotSourceCache
from fielddiag.errors import SessionError
from fielddiag.web.jobs import JobRunner
from fielddiag.web.security import (
    DEFAULT_MAX_BODY_BYTES,
    SecurityMiddleware,
    is_loopback,
    new_token,
)

__all__ = [
    "DashboardConfig",
    "DashboardState",
    "address",
    "machine_address",
    "serve",
    "setup_app",
]

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080


@dataclass
class DashboardConfig:
    """How the dashboard runs.

    Attributes
    ----------
    root : Path
        The sessions folder; nothing outside it is ever served.
    host, port : str, int
        Address to listen on.
    token : str or None
        Access token. Required (generated if None) when ``host`` is not loopback;
        honoured on loopback too when given.
    max_upload_bytes : int
        Largest upload accepted (bytes).
    plot_points : int
        Points per trace sent to the browser.
    """

    root: Path
    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    token: str | None = None
    max_upload_bytes: int = DEFAULT_MAX_BODY_BYTES
    plot_points: int = DEFAULT_POINTS

    def __post_init__(self) -> None:
        self.root = Path(self.root).resolve()
        if not is_loopback(self.host) and not self.token:
            self.token = new_token()


@dataclass
class DashboardState:
    """What the pages share: the catalog, open plot sources, background jobs, live recorder."""

    config: DashboardConfig
    catalog: Catalog
    plots: PlotSourceCache
    jobs: JobRunner
    live: dict = field(default_factory=dict)

    def resolve(self, relative: str) -> Path:
        return resolve_under_root(self.config.root, relative)


def machine_address() -> str:
    """This machine's address as other machines on its network reach it.

    The address of the interface that routes outwards (a UDP socket "connected" to a
    documentation address: nothing is sent), else what the host name resolves to, else
    the host name itself.
    """
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: routing only, no packet leaves
            ip = s.getsockname()[0]
        if ip and not ipaddress.ip_address(ip).is_loopback and ip != "0.0.0.0":
            return ip
    except OSError:
        pass
    name = socket.gethostname()
    try:
        ip = socket.gethostbyname(name)
        if not ipaddress.ip_address(ip).is_loopback:
            return ip
    except (OSError, ValueError):
        pass
    return name


def address(config: DashboardConfig) -> str:
    """The address to open in a browser (with the token when one is required).

    For a wildcard host (``0.0.0.0``, ``::``) that is this machine's network address
    (:func:`machine_address`), which a remote browser can open; otherwise the host given.
    """
    host = config.host.strip()
    shown = machine_address() if host in ("0.0.0.0", "", "::", "[::]") else host.strip("[]")
    if ":" in shown:
        shown = f"[{shown}]"
    url = f"http://{shown}:{config.port}/"
    return f"{url}?token={config.token}" if config.token else url


def _register_files_route(state: DashboardState) -> None:
    @app.get("/files/{relative:path}", include_in_schema=False)
    def _file(relative: str) -> FileResponse:
        try:
            path = state.resolve(relative)
        except OutsideRootError as exc:
            raise HTTPException(status_code=403, detail=str(exc)) from None
        if not path.is_file():
            raise HTTPException(
                status_code=404, detail=f"no file {relative!r} in the sessions folder"
            )
        return FileResponse(path, filename=path.name)


def setup_app(config: DashboardConfig) -> Callable[[], None]:
    """Register middleware, routes and shared state; return the root page function.

    Call once per server (or once per test inside nicegui's reset context).
    """
    from fielddiag.web.pages import diagnose, identify, live, session, sessions

    catalog = Catalog(config.root)
    state = DashboardState(
        config=config,
        catalog=catalog,
        plots=PlotSourceCache(max_open=4, n_out=config.plot_points),
        jobs=JobRunner(workers=1),
    )
    app.add_middleware(
        SecurityMiddleware,
        token=config.token,
        check_host=is_loopback(config.host) and not config.token,
        max_body_bytes=config.max_upload_bytes,
        port=config.port,
    )
    _register_files_route(state)
    app.on_startup(_freeze_startup_heap)
    app.on_shutdown(state.plots.close)
    app.on_shutdown(state.jobs.shutdown)
    app.on_shutdown(lambda: live.stop_all(state))

    from fielddiag.web.layout import header

    def root() -> None:
        ui.page_title("fielddiag")
        ui.query(".nicegui-content").classes("p-4 gap-3")
        header(str(config.root))
        ui.sub_pages(
            {
                "/": sessions.render,
                "/session": session.render,
                "/identify": identify.render,
                "/diagnose": diagnose.render,
                "/live": live.render,
            },
            data={"state": state},
        ).classes("w-full")

    root.state = state  # type: ignore[attr-defined]  # for tests and the benchmark
    return root


def _freeze_startup_heap() -> None:
    """Exclude the objects alive at start-up (the libraries: nicegui, numpy, scipy, numba,
    h5py ...) from the garbage collector's full passes. Without this each full pass walks
    them all: about 175 ms with the event loop stopped, several times a minute while the
    live view redraws, which showed as 200 ms stalls of the live plot."""
    import gc

    import fielddiag.diagnose.engine  # noqa: F401  (the heavy modules, before freezing)
    import fielddiag.identify  # noqa: F401

    gc.collect()
    gc.freeze()


def serve(
    root: Path,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    token: str | None = None,
    show: bool = False,
    *,
    max_upload_bytes: int = DEFAULT_MAX_BODY_BYTES,
    print_address: Callable[[str], None] | None = print,
) -> None:
    """Serve the dashboard for the sessions under ``root``; blocks until Ctrl-C.

    Parameters
    ----------
    root : Path
        Sessions folder.
    host, port : str, int
        Listen address. Anything but loopback requires an access token.
    token : str or None
        Access token; generated (and printed) when needed and not given.
    show : bool
        Open a browser tab.
    max_upload_bytes : int
        Largest upload accepted.
    print_address : callable or None
        Called with the address to open (``print`` by default).

    Raises
    ------
    SessionError
        ``root`` is not a folder.
    """
    root = Path(root)
    if not root.is_dir():
        raise SessionError(f"sessions folder {root} does not exist; create it or pick another")
    config = DashboardConfig(root=root, host=host, port=int(port), token=token,
                             max_upload_bytes=max_upload_bytes)
    root_fn = setup_app(config)
    if print_address is not None:
        where = "" if is_loopback(host) else " (access token required: keep this address private)"
        print_address(f"fielddiag dashboard for {config.root} at {address(config)}{where}")
        if host.strip("[] ") in ("0.0.0.0", "::", ""):
            local = DashboardConfig(root=config.root, host="127.0.0.1", port=config.port,
                                    token=config.token)
            print_address(f"  on this computer: {address(local)}")
    ui.run(
        root_fn,
        host=host,
        port=int(port),
        title="fielddiag",
        reload=False,
        show=show,
        show_welcome_message=False,
        favicon="🚗",
        uvicorn_logging_level="warning",
        # long numeric jobs run in worker threads; on a loaded 2-core machine the event
        # loop can wait seconds for the GIL, and nicegui's default 3 s would drop the page
        reconnect_timeout=30.0,
    )
