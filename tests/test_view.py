"""`gspc view` (gspc/view.py): what it serves and refuses, byte ranges, and its one-line errors. The viewer
itself runs in tests/test_browser.py."""

import threading
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from cli_runs import assert_one_line_error, run

from gspc.errors import InputError
from gspc.view import byte_range, make_server, view_site


def fake_web(root: Path) -> Path:
    """A web/ folder with the viewer's page and stand-ins for the npm packages it needs."""
    web = root / "web"
    (web / "viewer").mkdir(parents=True)
    (web / "viewer" / "index.html").write_text("<!doctype html>viewer")
    (web / "src").mkdir()
    (web / "src" / "a.mjs").write_text("export const a = 1;")
    for name in ("fzstd", "three", "@sparkjsdev/spark"):
        (web / "node_modules" / name).mkdir(parents=True)
        (web / "node_modules" / name / "package.json").write_text("{}")
    (root / "secret.txt").write_text("not served")
    return web


def test_byte_range():
    assert byte_range(None, 100) is None
    assert byte_range("bytes=0-19", 100) == (0, 19)
    assert byte_range("bytes=90-", 100) == (90, 99)
    assert byte_range("bytes=90-500", 100) == (90, 99)
    assert byte_range("bytes=-10", 100) == (90, 99)
    assert byte_range("bytes=0-1,5-6", 100) is None  # several ranges: the whole file
    with pytest.raises(ValueError):
        byte_range("bytes=100-", 100)
    with pytest.raises(ValueError):
        byte_range("bytes=5-2", 100)


def test_view_site_names_what_is_missing(tmp_path):
    scene = tmp_path / "s.gspc"
    scene.write_bytes(b"x")
    with pytest.raises(InputError, match="no such file"):
        view_site(tmp_path / "none.gspc", fake_web(tmp_path))
    with pytest.raises(InputError, match="web/ folder"):
        view_site(scene, tmp_path / "nowhere")
    web = tmp_path / "web"
    (web / "node_modules" / "three" / "package.json").unlink()
    with pytest.raises(InputError, match=r"\(three\) are not installed: run `npm ci --prefix"):
        view_site(scene, web)


def test_serves_the_viewer_and_the_scene_with_ranges_and_nothing_else(tmp_path):
    web = fake_web(tmp_path)
    scene = tmp_path / "my scene.gspc"
    scene.write_bytes(bytes(range(256)) * 4)
    server = make_server(view_site(scene, web), 0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}"

    def get(path: str, **headers) -> tuple[int, dict, bytes]:
        req = urllib.request.Request(base + path, headers=headers)
        try:
            with urllib.request.urlopen(req) as res:
                return res.status, dict(res.headers), res.read()
        except urllib.error.HTTPError as e:
            return e.code, dict(e.headers), b""

    try:
        status, headers, body = get("/")  # redirected to the viewer with the scene
        assert status == 200 and body == b"<!doctype html>viewer"
        status, headers, body = get("/scene/my%20scene.gspc", Range="bytes=1000-")
        assert status == 206 and body == scene.read_bytes()[1000:]
        assert headers["Content-Range"] == "bytes 1000-1023/1024"
        status, headers, body = get("/scene/my%20scene.gspc")
        assert status == 200 and body == scene.read_bytes() and headers["Accept-Ranges"] == "bytes"
        assert get("/scene/my%20scene.gspc", Range="bytes=2000-")[0] == 416
        status, headers, _ = get("/src/a.mjs")
        assert status == 200 and headers["Content-Type"] == "text/javascript"
        outside = ("/secret.txt", "/../secret.txt", "/src/../../secret.txt", "/src/%2e%2e/%2e%2e/secret.txt")
        for path in outside:
            assert get(path)[0] == 404, path
    finally:
        server.shutdown()
        server.server_close()


def test_cli_errors_are_one_line(tmp_path):
    assert_one_line_error(run("view", tmp_path / "none.gspc"), "no such file")
    scene = tmp_path / "s.gspc"
    scene.write_bytes(b"x")
    assert_one_line_error(run("view", scene, "--port", "70000"), "--port")
