"""``gspc view``: the web viewer (web/viewer) and one .gspc file served on 127.0.0.1, for a browser.

The viewer's ES modules are served as they are (no build step): web/viewer, web/src and web/node_modules,
which ``npm ci --prefix web`` installs, plus the scene at /scene/NAME. Every file answers HTTP range
requests, so the viewer can read a file's head and tile index first and then any tile (spec 10.14).
"""

from __future__ import annotations

import mimetypes
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import quote, unquote, urlsplit

from gspc.errors import InputError
from gspc.options import check_int

WEB = Path(__file__).resolve().parents[1] / "web"
SERVED = ("viewer", "src", "node_modules")  # the folders of web/ the viewer loads
NEEDED_MODULES = ("fzstd", "three", "@sparkjsdev/spark")
HOST = "127.0.0.1"
TYPES = {".mjs": "text/javascript", ".js": "text/javascript", ".gspc": "application/octet-stream"}
_RANGE = re.compile(r"bytes=(\d*)-(\d*)")


@dataclass(frozen=True)
class ViewSite:
    """What one ``gspc view`` serves: the web folder and the scene."""

    web: Path
    scene: Path

    @property
    def scene_url(self) -> str:
        return f"/scene/{quote(self.scene.name)}"

    @property
    def viewer_url(self) -> str:
        return f"/viewer/?file={quote(self.scene_url)}"


def view_site(scene: str | Path, web: Path = WEB) -> ViewSite:
    """The site for ``scene``; InputError naming what is missing (the scene, the viewer, its npm modules)."""
    path = Path(scene)
    if not path.is_file():
        raise InputError(f"{scene}: no such file")
    if not (web / "viewer" / "index.html").is_file():
        raise InputError(f"gspc view needs the repository's web/ folder, not at {web}: run it in a checkout")
    missing = [m for m in NEEDED_MODULES if not (web / "node_modules" / m / "package.json").is_file()]
    if missing:
        npm = "npm" if shutil.which("npm") else "npm (Node.js 20 or later)"
        raise InputError(
            f"the viewer's modules ({', '.join(missing)}) are not installed: run `npm ci --prefix {web}` "
            f"with {npm}"
        )
    return ViewSite(web.resolve(), path.resolve())


def byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """The bytes ``start .. end`` (inclusive) a Range header asks of a ``size``-byte file; None for the whole
    file (no header, or one this server does not read: several ranges); ValueError where no byte of the file
    is asked for (416)."""
    if header is None:
        return None
    m = _RANGE.fullmatch(header.strip())
    if m is None or not (m[1] or m[2]):
        return None
    if m[1]:
        start = int(m[1])
        end = min(int(m[2]), size - 1) if m[2] else size - 1
    else:  # the last N bytes
        start, end = max(size - int(m[2]), 0), size - 1
    if start >= size or start > end:
        raise ValueError(f"bytes {header} of a {size}-byte file")
    return start, end


class ViewHandler(BaseHTTPRequestHandler):
    """GET and HEAD of the viewer's files and the scene, with single byte ranges."""

    site: ViewSite
    server_version = "gspc-view"

    def log_message(self, format: str, *args) -> None:  # noqa: A002 (the base class's name)
        pass  # a page load is dozens of module requests; the address printed at start is what matters

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        self._answer(body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._answer(body=False)

    def _path(self) -> Path | None:
        """The file a request names, or None (outside what is served)."""
        path = unquote(urlsplit(self.path).path)
        if path == unquote(self.site.scene_url):
            return self.site.scene
        parts = [p for p in path.split("/") if p]
        if not parts or parts[0] not in SERVED or any(p in (".", "..") for p in parts):
            return None
        target = self.site.web.joinpath(*parts)
        if target.is_dir():
            target = target / "index.html"
        return target if target.is_file() else None

    def _answer(self, body: bool) -> None:
        if urlsplit(self.path).path == "/":
            self.send_response(HTTPStatus.FOUND)
            self.send_header("Location", self.site.viewer_url)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        path = self._path()
        if path is None:
            self.send_error(HTTPStatus.NOT_FOUND)
            return
        size = path.stat().st_size
        try:
            span = byte_range(self.headers.get("Range"), size)
        except ValueError:
            self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        start, end = span if span is not None else (0, size - 1)
        self.send_response(HTTPStatus.PARTIAL_CONTENT if span is not None else HTTPStatus.OK)
        kind = TYPES.get(path.suffix) or mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(end - start + 1))
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Cache-Control", "no-cache")
        if span is not None:
            self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.end_headers()
        if body:
            self._send_file(path, start, end - start + 1)

    def _send_file(self, path: Path, start: int, length: int) -> None:
        with open(path, "rb") as f:
            f.seek(start)
            while length > 0:
                block = f.read(min(length, 1 << 20))
                if not block:
                    break
                try:
                    self.wfile.write(block)
                except (BrokenPipeError, ConnectionResetError):
                    return  # the browser went away (a cancelled stream)
                length -= len(block)


def make_server(site: ViewSite, port: int) -> ThreadingHTTPServer:
    """A server for ``site`` on 127.0.0.1:``port`` (0: a free port), not yet serving."""
    check_int("--port", port, 0, 65535)
    handler = type("SiteHandler", (ViewHandler,), {"site": site})
    try:
        server = ThreadingHTTPServer((HOST, port), handler)
    except OSError as e:
        raise InputError(f"cannot serve on {HOST}:{port}: {e.strerror or e}") from None
    server.daemon_threads = True
    return server


def serve(scene: str | Path, port: int, say: Callable[[str], None] = partial(print, flush=True)) -> None:
    """Serve the viewer and ``scene`` until interrupted, after ``say``-ing the address to open."""
    site = view_site(scene)
    server = make_server(site, port)
    try:
        address = f"http://{HOST}:{server.server_address[1]}{site.viewer_url}"
        say(f"gspc view: {site.scene.name} at {address} (Ctrl-C stops)")
        server.serve_forever()
    finally:
        server.server_close()
