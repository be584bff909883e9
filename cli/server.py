"""The HTTP server of ``spcodec serve``: a local server for the streaming viewer and the scenes it opens.

A viewer streams an ``.spc`` with HTTP range requests: it reads the header block, learns from it
where each layer ends (spec section 3) and fetches the layers one range at a time. Python's
``http.server`` answers whole files only, so this module adds single-range support (RFC 9110
section 14): ``Range: bytes=a-b``, ``bytes=a-`` and ``bytes=-n`` get ``206 Partial Content`` with a
``Content-Range``; a range that lies outside the file, or a malformed ``bytes=`` range, gets ``416``
with ``Content-Range: bytes */size``; several ranges in one request, or another unit, are ignored
and the whole file is sent (both allowed by the RFC).

Odd requests get a status, never a traceback: a request target that names no file the OS could
open (a NUL byte, a name too long for it, a link loop, a component that is not a folder) is 404;
one that does not parse is 400; a client that hangs up mid-reply is let go quietly.

Text files (a tileset's JSON index and its external tilesets, the viewer's page and scripts) are
sent gzip-compressed to a client that accepts it (``Accept-Encoding: gzip``) and asks for no range:
a tileset's index is JSON of numbers and names, and compressed it is about a quarter of the bytes
a viewer waits for before its first request for a tile. Binary files, and every range, go as they
are.

``throttle`` paces the scene files (not the viewer's own code) to a given link speed, shared by
every connection as one link would be, so a viewer's progress can be watched and measured as on a
slow connection. The server binds the loopback interface unless told otherwise: it is a tool for
looking at one's own files, not a web server.

Layout of the URLs: ``/`` redirects to the viewer opening the first scene; ``/scenes/NAME`` are the
scene files; a scene that is a folder holding a ``tileset.json`` (``python -m spcodec.tiling``'s
output) is served whole under ``/scenes/NAME/`` (the index, its ``nodes/``), and ``/`` opens its
index, which the viewer streams by view; every other path is a file under the web folder
(``web/``: the viewer page in ``viewer/``, the decoder in ``src/``, their npm packages in
``node_modules/``).
"""

from __future__ import annotations

import errno
import gzip
import io
import json
import mimetypes
import os
import re
import shutil
import threading
import time
import urllib.parse
from dataclasses import dataclass
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import BinaryIO, Mapping

from spcodec.errors import UsageError

SCENE_PREFIX = "/scenes/"
VIEWER_PAGE = "/viewer/index.html"
TILESET_INDEX = "tileset.json"
"""The index a scene folder must hold (the name ``python -m spcodec.tiling`` writes)."""
_CHUNK = 16 * 1024
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript", ".mjs": "text/javascript",
          ".json": "application/json", ".wasm": "application/wasm", ".css": "text/css",
          ".spc": "application/octet-stream", ".ply": "application/octet-stream",
          ".glb": "model/gltf-binary", ".png": "image/png", ".map": "application/json"}
COMPRESSIBLE = frozenset({".json", ".js", ".mjs", ".html", ".css", ".map", ".txt"})
"""Suffixes of the text files sent gzip-compressed where the client accepts it."""
GZIP_LIMIT = 64 << 20
"""The largest text file compressed in memory; a larger one goes as it is."""
_RANGE = re.compile(r"^\s*([0-9]*)\s*-\s*([0-9]*)\s*$")  # ASCII digits only, as RFC 9110


def default_web_root() -> Path:
    """Where the viewer's files are: the ``web/`` folder beside this package's folder. In a source
    tree that is the repository's ``web/`` (cli/ and web/ side by side, the viewer beside the
    decoder's npm package); in an installed wheel, ``spcodec/web`` beside ``spcodec/cli``, the
    copy setup.py puts there."""
    return Path(__file__).resolve().parents[1] / "web"


class RangeNotSatisfiable(Exception):
    """The request's byte range cannot be served (answered with 416)."""


def _capped(digits: str, cap: int) -> int:
    """``min(int(digits), cap)`` for a string of ASCII digits of any length.

    A range's numbers come from the client and may have thousands of digits, past what ``int()``
    converts (Python's digit limit raises ValueError); any number longer than ``cap`` is at least
    ``cap``, and every use of it here (start past the end, end clipped to it) only needs that.
    """
    digits = digits.lstrip("0") or "0"
    if len(digits) > len(str(cap)):
        return cap
    return min(int(digits), cap)


def parse_range(header: str | None, size: int) -> tuple[int, int] | None:
    """The inclusive byte range ``(first, last)`` a ``Range`` header asks of a ``size``-byte file.

    ``None`` means "send the whole file": no header, a unit other than bytes, or several ranges.
    :class:`RangeNotSatisfiable` for a malformed bytes range or one that starts past the end.
    """
    if not header:
        return None
    unit, _, spec = header.partition("=")
    if unit.strip().lower() != "bytes":
        return None
    if "," in spec:
        return None
    match = _RANGE.match(spec)
    if not match or not (match.group(1) or match.group(2)):
        raise RangeNotSatisfiable(f"malformed range {header!r}")
    first_text, last_text = match.groups()
    # numbers are capped at size: a start that large is past the end (416), an end or a suffix
    # that large means "to the end" / "the whole file"
    if not first_text:  # suffix range: the last n bytes
        length = _capped(last_text, size)
        if length == 0 or size == 0:
            raise RangeNotSatisfiable(f"empty suffix range {header!r}")
        return max(0, size - length), size - 1
    first = _capped(first_text, size)
    last = _capped(last_text, size) if last_text else size - 1
    if last < first:
        raise RangeNotSatisfiable(f"range {header!r} ends before it starts")
    if first >= size:
        raise RangeNotSatisfiable(f"range {header!r} starts past the end ({size} bytes)")
    return first, min(last, size - 1)


class Link:
    """A shared, paced link: every scene byte sent through it waits for its turn at ``rate``
    bytes per second, as on one connection of that speed (no pacing when ``rate`` is None)."""

    def __init__(self, bytes_per_second: float | None) -> None:
        self.rate = bytes_per_second
        self._lock = threading.Lock()
        self._free_at = 0.0

    def wait_for(self, nbytes: int) -> None:
        """Block until ``nbytes`` more bytes would have crossed the link."""
        if not self.rate:
            return
        with self._lock:
            start = max(time.monotonic(), self._free_at)
            self._free_at = start + nbytes / self.rate
            done = self._free_at
        delay = done - time.monotonic()
        if delay > 0:
            time.sleep(delay)


@dataclass
class ServerConfig:
    """What a server serves: scene files by URL name, the web folder, and the link speed."""

    scenes: Mapping[str, Path]
    web_root: Path
    link: Link
    log: bool = False
    up: str | None = None
    """The scene's up axis for files that do not store one (the page's ``up`` parameter)."""


class ViewerRequestHandler(BaseHTTPRequestHandler):
    """GET and HEAD for the viewer's files and the scenes, with single byte ranges."""

    server_version = "spcodec-serve"
    protocol_version = "HTTP/1.1"
    config: ServerConfig  # set on the subclass made by make_server

    def do_GET(self) -> None:  # noqa: N802 - the name http.server dispatches to
        self._respond(send_body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._respond(send_body=False)

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - the base class's name
        if self.config.log:
            super().log_message(format, *args)

    def handle(self) -> None:
        """Serve the connection; a client that hangs up (a viewer cancelling a fetch, a closed
        tab) is no error of the server's, so it ends the connection without a traceback."""
        try:
            super().handle()
        except ConnectionError:
            self.close_connection = True

    # ----------------------------------------------------------------------------- routing
    def _respond(self, send_body: bool) -> None:
        try:
            path = urllib.parse.unquote(urllib.parse.urlsplit(self.path).path)
        except ValueError:  # e.g. "http://[x/": urlsplit reads a malformed IPv6 host in it
            self._refuse(HTTPStatus.BAD_REQUEST, send_body)
            return
        if path == "/":
            first = next(iter(self.config.scenes))
            tiled = self.config.scenes[first].is_dir()
            query = {"src": SCENE_PREFIX + first + (f"/{TILESET_INDEX}" if tiled else "")}
            if self.config.up:
                query["up"] = self.config.up
            query = urllib.parse.urlencode(query)
            self._redirect(f"{VIEWER_PAGE}?{query}")
            return
        if path.startswith(SCENE_PREFIX):
            name, slash, rest = path[len(SCENE_PREFIX):].partition("/")
            scene = self.config.scenes.get(name)
            if scene is not None and (scene.is_dir() or not slash):
                found = _file_under(scene, rest) if scene.is_dir() else scene
                if found is None:
                    self._refuse(HTTPStatus.NOT_FOUND, send_body)
                else:
                    self._send_file(found, send_body, paced=True)
                return
        local = self._web_file(path)
        if local is None:
            self._refuse(HTTPStatus.NOT_FOUND, send_body)
            return
        self._send_file(local, send_body, paced=False)

    def _web_file(self, path: str) -> Path | None:
        """The file under the web root that ``path`` names, or None."""
        if path.endswith("/"):
            path += "index.html"
        return _file_under(self.config.web_root, path)

    def _refuse(self, status: HTTPStatus, send_body: bool) -> None:
        """A short plain-text error answer that keeps the connection usable. Unlike
        ``send_error`` it logs one line (the request's, with its status), not two."""
        body = f"{status.value} {status.phrase}\n".encode()
        self.send_response(status)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        if send_body:
            self.wfile.write(body)

    def _redirect(self, location: str) -> None:
        self.send_response(HTTPStatus.FOUND)
        self.send_header("Location", location)
        self.send_header("Content-Length", "0")
        self.end_headers()

    # ----------------------------------------------------------------------------- files
    def _send_file(self, path: Path, send_body: bool, paced: bool) -> None:
        try:
            handle = open(path, "rb")
        except OSError:
            self._refuse(HTTPStatus.NOT_FOUND, send_body)
            return
        with handle:
            size = os.fstat(handle.fileno()).st_size
            try:
                span = parse_range(self.headers.get("Range"), size)
            except RangeNotSatisfiable:
                self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
                self.send_header("Content-Range", f"bytes */{size}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            if span is None and self._gzip_wanted(path, size):
                self._send_gzipped(handle, path, send_body, paced)
                return
            first, last = span if span else (0, size - 1)
            length = last - first + 1 if size else 0
            self.send_response(HTTPStatus.PARTIAL_CONTENT if span else HTTPStatus.OK)
            self.send_header("Content-Type", _content_type(path))
            self.send_header("Content-Length", str(length))
            self.send_header("Accept-Ranges", "bytes")
            self.send_header("Cache-Control", "no-store")
            if span:
                self.send_header("Content-Range", f"bytes {first}-{last}/{size}")
            self.end_headers()
            if send_body:
                handle.seek(first)
                self._copy(handle, length, self.config.link if paced else None)

    def _gzip_wanted(self, path: Path, size: int) -> bool:
        return (path.suffix.lower() in COMPRESSIBLE and size <= GZIP_LIMIT
                and accepts_gzip(self.headers.get("Accept-Encoding")))

    def _send_gzipped(self, handle: BinaryIO, path: Path, send_body: bool, paced: bool) -> None:
        """The whole file compressed, for a client that accepts gzip and asked for no range."""
        body = gzip.compress(handle.read(), compresslevel=6, mtime=0)
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", _content_type(path))
        self.send_header("Content-Encoding", "gzip")
        self.send_header("Vary", "Accept-Encoding")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if send_body:
            self._copy(io.BytesIO(body), len(body), self.config.link if paced else None)

    def _copy(self, handle: BinaryIO, length: int, link: Link | None) -> None:
        if link is None or not link.rate:
            shutil.copyfileobj(_Limited(handle, length), self.wfile, _CHUNK)
            return
        remaining = length
        while remaining > 0:
            block = handle.read(min(_CHUNK, remaining))
            if not block:
                break
            link.wait_for(len(block))
            self.wfile.write(block)
            remaining -= len(block)


def _file_under(root: Path, path: str) -> Path | None:
    """The file under ``root`` that the URL path ``path`` names, or None: never outside the root,
    never a hidden file, never a name the OS refuses to look up."""
    parts = [p for p in path.split("/") if p]
    if any(p.startswith(".") for p in parts) or "\0" in path:
        return None
    try:
        base = root.resolve()
        candidate = base.joinpath(*parts).resolve() if parts else base
        if candidate != base and base not in candidate.parents:
            return None
        return candidate if candidate.is_file() else None
    except (OSError, ValueError, RuntimeError):
        # ENAMETOOLONG, EACCES, ...; ValueError: a NUL byte; RuntimeError: pathlib's "Symlink loop"
        return None


class _Limited:
    """A reader that stops after ``length`` bytes (the end of a range)."""

    def __init__(self, handle: BinaryIO, length: int) -> None:
        self.handle, self.remaining = handle, length

    def read(self, size: int = -1) -> bytes:
        if self.remaining <= 0:
            return b""
        block = self.handle.read(self.remaining if size < 0 else min(size, self.remaining))
        self.remaining -= len(block)
        return block


def accepts_gzip(header: str | None) -> bool:
    """Whether an ``Accept-Encoding`` header names gzip with a weight above 0 (RFC 9110 12.5.3)."""
    for part in (header or "").split(","):
        coding, *params = [item.strip() for item in part.split(";")]
        if coding.lower() != "gzip":
            continue
        for param in params:
            key, _, value = param.partition("=")
            if key.strip().lower() == "q":
                try:
                    return float(value) > 0
                except ValueError:
                    return False
        return True
    return False


def _content_type(path: Path) -> str:
    suffix = path.suffix.lower()
    return _TYPES.get(suffix) or mimetypes.guess_type(path.name)[0] or "application/octet-stream"


def scene_names(paths: list[str | os.PathLike]) -> dict[str, Path]:
    """URL names for scenes (their file or folder names; a clash is a usage error). A folder must
    be a tileset: hold a ``tileset.json`` that is a JSON object with a root tile."""
    scenes: dict[str, Path] = {}
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            check_tileset_folder(path)
        elif not path.is_file():
            raise UsageError(f"{path}: no such file or folder")
        if path.name in scenes:
            raise UsageError(f"two scenes are named {path.name}: serve them from separate servers")
        scenes[path.name] = path.resolve()
    return scenes


def check_tileset_folder(folder: Path) -> None:
    """A one-line UsageError unless ``folder`` holds a tileset index the viewer can open (the
    viewer checks each tile; this catches the wrong folder before a page is opened)."""
    index = folder / TILESET_INDEX
    if not index.is_file():
        raise UsageError(f"{folder}: a folder to serve must hold a {TILESET_INDEX} (python -m "
                         "spcodec.tiling writes one)")
    try:
        document = json.loads(index.read_bytes())
    except (OSError, ValueError) as exc:
        raise UsageError(f"{index}: not a JSON document ({str(exc).splitlines()[0]})") from None
    if not isinstance(document, dict) or not isinstance(document.get("root"), dict):
        raise UsageError(f"{index}: not a 3D Tiles tileset (no root tile)")


def make_server(scenes: list[str | os.PathLike], host: str = "127.0.0.1", port: int = 0,
                throttle_kbps: float | None = None, web_root: Path | None = None,
                log: bool = False, up: str | None = None) -> ThreadingHTTPServer:
    """A threaded server for ``scenes`` (the first is the one ``/`` opens); ``port=0`` picks a free
    port (read it from ``server.server_address``). ``throttle_kbps`` is in kilobits per second."""
    if not scenes:
        raise UsageError("give at least one scene file to serve")
    if throttle_kbps is not None and not throttle_kbps > 0:
        raise UsageError(f"--throttle must be a positive speed in kbit/s, got {throttle_kbps}")
    if not 0 <= port <= 65535:
        raise UsageError(f"--port must be 0..65535, got {port}")
    config = ServerConfig(
        scenes=scene_names(scenes), web_root=Path(web_root or default_web_root()),
        link=Link(throttle_kbps * 1000 / 8 if throttle_kbps else None), log=log, up=up)
    handler = type("Handler", (ViewerRequestHandler,), {"config": config})
    try:
        server = ThreadingHTTPServer((host, port), handler)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise UsageError(f"port {port} on {host} is in use: pass another --port") from None
        raise UsageError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    server.daemon_threads = True
    return server


def viewer_missing(web_root: Path | None = None) -> str | None:
    """Why the viewer page cannot run from ``web_root`` (None when it can)."""
    root = Path(web_root or default_web_root())
    if not (root / "viewer" / "index.html").is_file():
        return (f"the viewer page is not in {root / 'viewer'} (this spcodec was built without "
                "its web folder: install it from a source checkout)")
    if not (root / "viewer" / "node_modules" / "playcanvas").is_dir():
        return f"the viewer's npm packages are not installed: run 'npm ci' in {root / 'viewer'}"
    if not (root / "node_modules" / "draco3d").is_dir():
        return f"the decoder's npm packages are not installed: run 'npm ci' in {root}"
    return None
