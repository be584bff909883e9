"""`spcodec serve`: byte ranges (206, Content-Range, 416), routing, confinement and pacing."""

from __future__ import annotations

import http.client
import threading
import time
import urllib.parse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from spcodec.cli import main
from spcodec.errors import UsageError
from spcodec.serve import RangeNotSatisfiable, make_server, parse_range

SCENE = bytes(range(256)) * 40  # 10,240 distinct-looking bytes


@pytest.fixture(scope="module")
def server(tmp_path_factory):
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
    srv = make_server([scene], port=0, web_root=web)
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
                                  "/nothing.html", "/src/"])
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
