"""The workbench's Bokeh server: one application at ``/``, bound to ``127.0.0.1`` unless the user exposes it on
purpose, its BokehJS served from the server itself (``resources="server"``: the page requests nothing outside the
machine)."""

from __future__ import annotations

import errno
import os
from collections.abc import Callable

from franka_vs_gym.errors import UserError
from franka_vs_gym.validation.app.state import App

LOCAL = ("127.0.0.1", "localhost", "::1")


def make_server(app: App, host: str = "127.0.0.1", port: int = 5006):
    """A started-but-not-running ``bokeh.server.server.Server`` serving the workbench at ``http://host:port/``."""
    os.environ["BOKEH_RESOURCES"] = "server"  # BokehJS from this server, never a CDN
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    from franka_vs_gym.validation.app.page import make_document

    origins = [f"{h}:{port}" for h in {host, "127.0.0.1", "localhost"}]
    try:
        server = Server({"/": Application(FunctionHandler(make_document(app)))}, address=host, port=port,
                        allow_websocket_origin=origins, num_procs=1, check_unused_sessions_milliseconds=5000,
                        unused_session_lifetime_milliseconds=30000)
    except OSError as e:
        if e.errno == errno.EADDRINUSE:
            raise UserError(f"port {port} on {host} is in use (another workbench?): choose another with --port") from e
        if e.errno in (errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT) or isinstance(e, OSError) and "address" in str(e):
            raise UserError(f"cannot listen on {host}:{port}: {e.strerror or e}") from e
        raise
    _only_needed_bundles(server)
    server.start()
    return server


#: the BokehJS bundles the page uses (no WebGL, no TeX: 1.9 MB less JavaScript for the browser to parse)
BUNDLES = ["bokeh", "bokeh-widgets", "bokeh-tables"]


def _only_needed_bundles(server) -> None:
    """Serve the page with :data:`BUNDLES` only (Bokeh's server page names every bundle). Left as Bokeh makes it
    where its server application object or its resources' signature is not the one this was written for."""
    from bokeh.resources import Resources

    tornado = getattr(server, "_tornado", None)
    make = getattr(tornado, "resources", None)
    if make is None:
        return

    def resources(absolute_url=None):
        r = make(absolute_url)
        if isinstance(r, Resources) and r.mode in ("server", "server-dev"):
            r.components = [c for c in r.components if c in BUNDLES]
        return r

    tornado.resources = resources


def url_of(host: str, port: int) -> str:
    shown = "127.0.0.1" if host in ("", "0.0.0.0") else host
    if ":" in shown:
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/"


def run(app: App, host: str, port: int, open_browser: bool, say: Callable[[str], None] | None = None) -> None:
    """Serve until interrupted (Ctrl-C or SIGTERM), opening the page in the default browser unless told not to."""
    server = make_server(app, host, port)
    url = url_of(host, port)
    (say or (lambda s: print(s, flush=True)))(  # one line on stdout when the server is ready
        f"franka-vs workbench: {url} (Ctrl-C stops it)" + (
            "" if host in LOCAL else f"; WARNING: listening on {host}, so other machines can read and write files "
                                     "on this one through the page"))
    if open_browser:
        import webbrowser

        server.io_loop.add_callback(lambda: webbrowser.open(url))
    try:
        server.io_loop.start()
    finally:
        server.stop()
        app.stop()


__all__ = ["LOCAL", "make_server", "run", "url_of"]
