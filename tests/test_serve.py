"""`spcodec serve`: byte ranges (206, Content-Range, 416), routing, confinement and pacing, and
odd requests (huge numbers, NUL bytes, overlong names, hang-ups) answered without a traceback."""

from __future__ import annotations

import ast
import fnmatch
import gzip
import http.client
import json
import shutil
import socket
import struct
import sys
import threading
import time
import urllib.parse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from spcodec.cli import main
from spcodec.cli.server import RangeNotSatisfiable, accepts_gzip, make_server, parse_range
from spcodec.errors import UsageError

from conftest import REPO

SCENE = bytes(range(256)) * 40  # 10,240 distinct-looking bytes
HUGE = "9" * 5000  # past Python's int() digit limit (4,300)


@pytest.fixture(scope="module")
def server_errors() -> list[BaseException]:
    """What requests to the module's server raised (socketserver prints each as a traceback)."""
    return []


@pytest.fixture(scope="module")
def server(tmp_path_factory, server_errors):
    """A running server for one scene with a small web folder; yields (host, port)."""
    tmp_path = tmp_path_factory.mktemp("serve")
    scene = tmp_path / "scene.spc"
    scene.write_bytes(SCENE)
    web = tmp_path / "web"
    (web / "viewer").mkdir(parents=True)
    (web / "viewer" / "index.html").write_text("<!doctype html><title>viewer</title>")
    (web / "src").mkdir()
    (web / "src" / "index.js").write_text("export const x = 1;\n")
    (web / ".secret").write_text("hidden")
    (tmp_path / "outside.txt").write_text("outside the web root")
    (web / "link-out.txt").symlink_to(tmp_path / "outside.txt")
    (web / "loop").symlink_to(web / "loop")
    srv = make_server([scene], port=0, web_root=web)
    srv.handle_error = lambda request, address: server_errors.append(sys.exc_info()[1])
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield srv.server_address[:2]
    srv.shutdown()
    srv.server_close()


def request(address, path, headers=None, method="GET"):
    conn = http.client.HTTPConnection(*address, timeout=10)
    conn.request(method, path, headers=headers or {})
    response = conn.getresponse()
    body = response.read()
    conn.close()
    return response, body


def raw_request(address, target: str, headers: str = "") -> tuple[str, bytes]:
    """Send a GET as raw bytes (http.client refuses some of these targets) and read the answer
    to its end: (status line, rest). An empty status line: the server hung up without one."""
    with socket.create_connection(address, timeout=10) as sock:
        sock.sendall(f"GET {target} HTTP/1.1\r\nHost: x\r\n{headers}Connection: close\r\n\r\n"
                     .encode("latin-1"))
        reply = b""
        while block := sock.recv(65536):
            reply += block
    status, _, rest = reply.partition(b"\r\n")
    return status.decode("latin-1"), rest


def test_whole_file_advertises_ranges(server):
    response, body = request(server, "/scenes/scene.spc")
    assert response.status == 200 and body == SCENE
    assert response.getheader("Accept-Ranges") == "bytes"
    assert int(response.getheader("Content-Length")) == len(SCENE)
    assert response.getheader("Content-Range") is None


@pytest.mark.parametrize("spec, first, last", [
    ("bytes=0-47", 0, 47),                      # a header
    ("bytes=100-199", 100, 199),
    ("bytes=10000-", 10000, len(SCENE) - 1),    # open-ended
    ("bytes=-40", len(SCENE) - 40, len(SCENE) - 1),  # suffix
    ("bytes=10200-99999", 10200, len(SCENE) - 1),    # clipped to the end
    ("bytes=-99999", 0, len(SCENE) - 1),        # suffix longer than the file
    ("bytes=5-5", 5, 5),
])
def test_single_range_gets_206_with_content_range(server, spec, first, last):
    response, body = request(server, "/scenes/scene.spc", {"Range": spec})
    assert response.status == 206
    assert response.getheader("Content-Range") == f"bytes {first}-{last}/{len(SCENE)}"
    assert int(response.getheader("Content-Length")) == last - first + 1
    assert body == SCENE[first:last + 1]


@pytest.mark.parametrize("spec", [f"bytes={len(SCENE)}-", f"bytes={len(SCENE) + 5}-{len(SCENE) + 9}",
                                  "bytes=-0", "bytes=9-3", "bytes=abc", "bytes=-", "bytes=1-2-3"])
def test_bad_or_unsatisfiable_range_gets_416(server, spec):
    response, body = request(server, "/scenes/scene.spc", {"Range": spec})
    assert response.status == 416 and body == b""
    assert response.getheader("Content-Range") == f"bytes */{len(SCENE)}"


@pytest.mark.parametrize("spec, status, span", [
    (f"bytes={HUGE}-", 416, None),                         # starts past the end
    (f"bytes={HUGE}-{HUGE}9", 416, None),
    (f"bytes=0-{HUGE}", 206, (0, len(SCENE) - 1)),         # ends past it: the rest of the file
    (f"bytes=10200-{HUGE}", 206, (10200, len(SCENE) - 1)),
    (f"bytes=-{HUGE}", 206, (0, len(SCENE) - 1)),          # a suffix longer than the file
    (f"bytes={'0' * 5000}7-{'0' * 5000}9", 206, (7, 9)),   # leading zeros are still numbers
])
def test_range_numbers_of_any_length_are_answered(server, server_errors, spec, status, span):
    """A 5,000-digit number raised ValueError in int() and the connection closed unanswered."""
    server_errors.clear()
    response, body = request(server, "/scenes/scene.spc", {"Range": spec})
    assert response.status == status and not server_errors
    if span is None:
        assert body == b"" and response.getheader("Content-Range") == f"bytes */{len(SCENE)}"
    else:
        first, last = span
        assert response.getheader("Content-Range") == f"bytes {first}-{last}/{len(SCENE)}"
        assert body == SCENE[first:last + 1]


def test_parse_range_caps_huge_numbers_at_the_file():
    assert parse_range(f"bytes=3-{HUGE}", 10) == (3, 9)
    assert parse_range(f"bytes=-{HUGE}", 10) == (0, 9)
    for spec in [f"bytes={HUGE}-", f"bytes={HUGE}-5", f"bytes=-{HUGE}", "bytes=\u0661-"]:
        with pytest.raises(RangeNotSatisfiable):
            parse_range(spec, 0 if spec == f"bytes=-{HUGE}" else 10)


@pytest.mark.parametrize("target, status", [
    ("/a%00b", 404),                     # ValueError: embedded null byte
    ("/viewer/index.html%00", 404),
    ("/scenes/scene.spc%00", 404),
    ("/" + "a" * 5000, 404),             # OSError ENAMETOOLONG: one name too long
    ("/" + "a/" * 2500, 404),            # the whole path too long
    ("/src/index.js/x", 404),            # ENOTDIR
    ("/loop", 404), ("/loop/x", 404),    # a link to itself (pathlib: RuntimeError)
    ("http://[x/", 400),                 # urlsplit's ValueError: an unclosed IPv6 host
])
def test_targets_no_file_can_have_get_a_status_not_a_traceback(server, server_errors, target,
                                                               status):
    server_errors.clear()
    line, rest = raw_request(server, target)
    assert line.split(" ", 2)[:2] == ["HTTP/1.1", str(status)], (line, server_errors)
    assert not server_errors and b"outside the web root" not in rest


def test_an_odd_request_logs_one_line(tmp_path, capsys):
    """With --log, one line per request (send_error wrote two), and no traceback."""
    scene = tmp_path / "scene.spc"
    scene.write_bytes(SCENE)
    srv = make_server([scene], port=0, web_root=tmp_path, log=True)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        for target in ["/a%00b", "/" + "a" * 5000, "/missing.html"]:
            assert raw_request(srv.server_address[:2], target)[0].startswith("HTTP/1.1 404")
        assert raw_request(srv.server_address[:2], "/scenes/scene.spc",
                           f"Range: bytes={HUGE}-\r\n")[0].startswith("HTTP/1.1 416")
    finally:
        srv.shutdown()
        srv.server_close()
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 4 and "Traceback" not in err, err
    assert [line.split()[-2] for line in err.splitlines()] == ["404", "404", "404", "416"]


def test_a_client_that_hangs_up_mid_reply_is_no_error(tmp_path):
    """A viewer cancelling a fetch resets the connection while the server writes: that raised
    ConnectionResetError/BrokenPipeError out of the handler, printed as a traceback."""
    scene = tmp_path / "scene.spc"
    scene.write_bytes(SCENE)
    srv = make_server([scene], port=0, throttle_kbps=400, web_root=tmp_path)  # 0.2 s for SCENE
    errors: list[BaseException] = []
    done = threading.Event()
    srv.handle_error = lambda request, address: errors.append(sys.exc_info()[1])
    close = srv.shutdown_request
    srv.shutdown_request = lambda request: (close(request), done.set())
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        sock = socket.create_connection(srv.server_address[:2], timeout=10)
        sock.sendall(b"GET /scenes/scene.spc HTTP/1.1\r\nHost: x\r\n\r\n")
        head = b""
        while b"\r\n\r\n" not in head:  # the headers come at once, the paced body later
            head += sock.recv(1024)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        sock.close()  # a reset, not a clean close
        assert done.wait(10)
    finally:
        srv.shutdown()
        srv.server_close()
    assert head.startswith(b"HTTP/1.1 200") and errors == []


@pytest.mark.parametrize("spec", ["bytes=0-1,5-6", "items=0-3"])
def test_multiple_ranges_or_other_units_send_the_whole_file(server, spec):
    response, body = request(server, "/scenes/scene.spc", {"Range": spec})
    assert response.status == 200 and body == SCENE


def test_head_sends_headers_only(server):
    response, body = request(server, "/scenes/scene.spc", {"Range": "bytes=0-9"}, method="HEAD")
    assert response.status == 206 and body == b""
    assert response.getheader("Content-Length") == "10"


def test_root_redirects_to_the_viewer_with_the_scene(server):
    response, _ = request(server, "/")
    assert response.status == 302
    location = urllib.parse.urlsplit(response.getheader("Location"))
    assert location.path == "/viewer/index.html"
    assert urllib.parse.parse_qs(location.query) == {"src": ["/scenes/scene.spc"]}
    response, body = request(server, location.path)
    assert response.status == 200 and b"viewer" in body
    assert response.getheader("Content-Type").startswith("text/html")
    assert request(server, "/viewer/")[1] == body  # a folder serves its index.html
    response, _ = request(server, "/src/index.js")
    assert response.status == 200 and response.getheader("Content-Type") == "text/javascript"


@pytest.mark.parametrize("path", ["/../outside.txt", "/viewer/../../outside.txt",
                                  "/%2e%2e/outside.txt", "/.secret", "/scenes/other.spc",
                                  "/nothing.html", "/src/", "/link-out.txt", "/%00/../outside.txt"])
def test_nothing_outside_the_web_root_or_hidden_is_served(server, path):
    response, body = request(server, path)
    assert response.status == 404 and b"outside the web root" not in body and b"hidden" not in body


def test_keep_alive_connection_serves_successive_ranges(server):
    """A viewer fetches layer after layer, usually on one connection."""
    conn = http.client.HTTPConnection(*server, timeout=10)
    for first, last in [(0, 47), (48, 1000), (1001, len(SCENE) - 1)]:
        conn.request("GET", "/scenes/scene.spc", headers={"Range": f"bytes={first}-{last}"})
        response = conn.getresponse()
        assert response.status == 206 and response.read() == SCENE[first:last + 1]
    conn.close()


def test_throttle_paces_the_scene(tmp_path):
    """At 400 kbit/s (50,000 bytes/s) the 10,240-byte scene cannot arrive in under 0.2 s."""
    scene = tmp_path / "scene.spc"
    scene.write_bytes(SCENE)
    srv = make_server([scene], port=0, throttle_kbps=400, web_root=tmp_path)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        start = time.monotonic()
        response, body = request(srv.server_address[:2], "/scenes/scene.spc")
        elapsed = time.monotonic() - start
    finally:
        srv.shutdown()
        srv.server_close()
    assert response.status == 200 and body == SCENE
    assert elapsed >= 0.95 * len(SCENE) / 50_000


@given(size=st.integers(0, 5000), first=st.integers(0, 6000), length=st.integers(1, 6000))
def test_parse_range_matches_slicing(size, first, length):
    """A satisfiable ``a-b`` range names exactly the bytes ``[a, min(b, size-1)]``; others 416."""
    last = first + length - 1
    if first >= size:
        with pytest.raises(RangeNotSatisfiable):
            parse_range(f"bytes={first}-{last}", size)
        return
    assert parse_range(f"bytes={first}-{last}", size) == (first, min(last, size - 1))
    suffix = parse_range(f"bytes=-{length}", size)
    assert suffix == (max(0, size - length), size - 1)


def test_make_server_rejects_bad_arguments(tmp_path):
    with pytest.raises(UsageError, match="no such file"):
        make_server([tmp_path / "missing.spc"], port=0)
    scene = tmp_path / "s.spc"
    scene.write_bytes(SCENE)
    with pytest.raises(UsageError, match="throttle"):
        make_server([scene], port=0, throttle_kbps=0)
    busy = make_server([scene], port=0, web_root=tmp_path)
    try:
        with pytest.raises(UsageError, match="in use"):
            make_server([scene], port=busy.server_address[1], web_root=tmp_path)
    finally:
        busy.server_close()


def test_cli_serve_fails_with_one_line(capsys, tmp_path):
    code = main(["serve", str(tmp_path / "nope.spc"), "--port", "0"])
    _, err = capsys.readouterr()
    assert code == 2 and err.count("\n") == 1 and "no such file" in err


def test_cli_serve_prints_a_url_that_serves_ranges_and_stops_on_ctrl_c(tmp_path):
    import re
    import signal
    import subprocess
    import sys

    scene = tmp_path / "scene.spc"
    scene.write_bytes(SCENE)
    # a shell's background job inherits SIGINT ignored, and Python then keeps it ignored: give the
    # command the default disposition a terminal would
    proc = subprocess.Popen([sys.executable, "-m", "spcodec.cli", "serve", str(scene), "--port", "0",
                             "--throttle", "100000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = proc.stdout.readline()
        match = re.search(r"http://([\d.]+):(\d+)/", line)
        assert match and "throttled to 100000 kbit/s" in line, line
        address = (match.group(1), int(match.group(2)))
        response, _ = request(address, "/")
        assert response.status == 302 and "scene.spc" in response.getheader("Location")
        response, body = request(address, "/scenes/scene.spc", {"Range": "bytes=16-31"})
        assert response.status == 206 and body == SCENE[16:32]
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0 and "stopped" in out and "Traceback" not in err


def test_serve_up_reaches_the_page_for_files_that_do_not_store_it(tmp_path):
    scene = tmp_path / "scene.ply"
    scene.write_bytes(b"ply\n")
    (tmp_path / "viewer").mkdir()
    srv = make_server([scene], port=0, web_root=tmp_path, up="+z")
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    try:
        response, _ = request(srv.server_address[:2], "/")
        query = urllib.parse.parse_qs(urllib.parse.urlsplit(response.getheader("Location")).query)
        assert query == {"src": ["/scenes/scene.ply"], "up": ["+z"]}
    finally:
        srv.shutdown()
        srv.server_close()


def wheel_web_patterns() -> list[str]:
    """setup.py's VIEWER_FILES: the files of web/ a wheel carries (read, not imported: importing
    setup.py would run setup())."""
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "VIEWER_FILES":
            return ast.literal_eval(node.value)
    raise AssertionError("setup.py has no VIEWER_FILES")


def test_web_readme_says_where_the_example_pages_are_served(tmp_path):
    """web/README.md said `spcodec serve` serves /examples/ pages; an installed spcodec answered
    404. Lay out the web folder a wheel carries (setup.py's patterns, as its build copies them),
    serve it, and hold the README's paragraph on the examples to what that server answers."""
    web = REPO / "web"
    for pattern in wheel_web_patterns():
        for source in web.glob(pattern):
            target = tmp_path / "web" / source.relative_to(web)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, target)
    scene = tmp_path / "scene.spc"
    scene.write_bytes(SCENE)
    srv = make_server([scene], port=0, web_root=tmp_path / "web")
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        viewer = request(srv.server_address[:2], "/viewer/index.html")[0].status
        example = request(srv.server_address[:2], "/examples/playcanvas.html")[0].status
    finally:
        srv.shutdown()
        srv.server_close()
    assert viewer == 200
    shipped = any(fnmatch.fnmatch("examples/playcanvas.html", p) for p in wheel_web_patterns())
    assert example == (200 if shipped else 404)
    paragraph = next(p for p in (web / "README.md").read_text().split("\n\n") if "/examples/" in p)
    says_not_in_wheel = "does not carry them" in " ".join(paragraph.split())
    assert says_not_in_wheel == (example == 404), paragraph


@pytest.fixture()
def tileset_server(tmp_path):
    """A server for a tileset folder (an index and two nodes, a hidden file, a file beside it)."""
    folder = tmp_path / "tiled"
    (folder / "nodes").mkdir(parents=True)
    (folder / "tileset.json").write_text('{"asset": {"version": "1.1"}, "root": {}}')
    (folder / "nodes" / "n.spc").write_bytes(SCENE)
    (folder / "nodes" / "n0.spc").write_bytes(SCENE[:100])
    (folder / "nodes" / ".hidden").write_text("hidden")
    (tmp_path / "beside.txt").write_text("outside the web root")
    srv = make_server([folder], port=0, web_root=tmp_path / "web")
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield srv.server_address[:2]
    srv.shutdown()
    srv.server_close()


def test_a_tileset_folder_is_served_whole_and_opened_at_its_index(tileset_server):
    response, _ = request(tileset_server, "/")
    assert response.status == 302
    location = urllib.parse.urlsplit(response.getheader("Location"))
    assert urllib.parse.parse_qs(location.query) == {"src": ["/scenes/tiled/tileset.json"]}
    response, body = request(tileset_server, "/scenes/tiled/tileset.json")
    assert response.status == 200 and response.getheader("Content-Type") == "application/json"
    assert body.startswith(b'{"asset"')
    response, body = request(tileset_server, "/scenes/tiled/nodes/n.spc", {"Range": "bytes=100-199"})
    assert response.status == 206 and body == SCENE[100:200]
    assert response.getheader("Content-Range") == f"bytes 100-199/{len(SCENE)}"
    assert request(tileset_server, "/scenes/tiled/nodes/n0.spc")[1] == SCENE[:100]


@pytest.mark.parametrize("path", ["/scenes/tiled", "/scenes/tiled/", "/scenes/tiled/nodes",
                                  "/scenes/tiled/nodes/.hidden", "/scenes/tiled/../beside.txt",
                                  "/scenes/tiled/%2e%2e/beside.txt", "/scenes/tiled/nodes/n9.spc",
                                  "/scenes/tiled/%00/x", "/scenes/other/tileset.json"])
def test_nothing_outside_a_tileset_folder_or_hidden_in_it_is_served(tileset_server, path):
    response, body = request(tileset_server, path)
    assert response.status == 404 and b"outside" not in body and b"hidden" not in body


@pytest.mark.parametrize("index, message", [
    (None, "must hold a tileset.json"),
    ("{not json", "not a JSON document"),
    ('["a list"]', "not a 3D Tiles tileset"),
    ('{"asset": {"version": "1.1"}}', "no root tile"),
])
def test_a_folder_that_is_no_tileset_fails_with_one_line(tmp_path, capsys, index, message):
    folder = tmp_path / "out"
    folder.mkdir()
    if index is not None:
        (folder / "tileset.json").write_text(index)
    with pytest.raises(UsageError, match=message):
        make_server([folder], port=0)
    code = main(["serve", str(folder), "--port", "0"])
    _, err = capsys.readouterr()
    assert code == 2 and err.count("\n") == 1 and message in err


def test_a_tileset_index_goes_gzipped_to_a_client_that_accepts_it(tileset_server, tmp_path):
    """The index is compressed only where gzip is accepted and no range is asked; the tiles (binary,
    read by range) never are. A HEAD answers with the compressed length."""
    index = tmp_path / "tiled" / "tileset.json"
    children = [{"boundingVolume": {"box": [k * 0.125] * 12}, "geometricError": k / 3,
                 "content": {"uri": f"nodes/n{k:04d}.spc"}} for k in range(200)]
    index.write_text(json.dumps({"asset": {"version": "1.1"}, "root": {"children": children}}))
    path = "/scenes/tiled/tileset.json"
    response, body = request(tileset_server, path, {"Accept-Encoding": "gzip, deflate, br"})
    assert response.status == 200 and response.getheader("Content-Encoding") == "gzip"
    assert response.getheader("Vary") == "Accept-Encoding"
    assert gzip.decompress(body) == index.read_bytes() and len(body) < index.stat().st_size / 3
    assert int(response.getheader("Content-Length")) == len(body)
    head, nothing = request(tileset_server, path, {"Accept-Encoding": "gzip"}, method="HEAD")
    assert nothing == b"" and head.getheader("Content-Length") == str(len(body))
    for headers in ({}, {"Accept-Encoding": "gzip;q=0"}, {"Accept-Encoding": "identity"},
                    {"Accept-Encoding": "gzip", "Range": "bytes=0-9"}):
        response, plain = request(tileset_server, path, headers)
        assert response.getheader("Content-Encoding") is None, headers
        assert plain == index.read_bytes()[:10 if "Range" in headers else None], headers
    response, tile = request(tileset_server, "/scenes/tiled/nodes/n.spc", {"Accept-Encoding": "gzip"})
    assert response.getheader("Content-Encoding") is None and tile == SCENE


@pytest.mark.parametrize("header, accepted", [
    (None, False), ("", False), ("gzip", True), ("GZIP", True), ("deflate, gzip;q=0.5", True),
    ("gzip;q=0", False), ("gzip; q=0.0", False), ("gzip;q=x", False), ("br, identity", False),
    ("x-gzip", False), ("gzip;level=1", True),
])
def test_accepts_gzip_reads_the_weights(header, accepted):
    assert accepts_gzip(header) is accepted
