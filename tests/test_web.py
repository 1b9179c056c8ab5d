"""``splatreel export web``: the page, drawn by a real browser (headless Chromium, WebGL2 on SwiftShader), shows the
same image as the desktop renderer (`render_image`) for the same camera and time.

Chromium is driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``: NUL-terminated JSON on fds 3
and 4; https://chromedevtools.github.io/devtools-protocol/), so no driver package is needed; the page says when its
first frame at the requested view and time is drawn (``data-ready`` on the root element), and the canvas is read
with ``toDataURL``. Debian's ``chromium`` is installed when missing.
"""

from __future__ import annotations

import base64
import functools
import http.server
import io
import json
import os
import select
import shutil
import subprocess
import tempfile
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image

from splatreel.cameras import look_at
from splatreel.checkpoint import save_checkpoint
from splatreel.cli import main
from splatreel.errors import OutputExistsError
from splatreel.export import ExportError
from splatreel.export.web import DATA_NAME, MAGIC, web_data, write_web
from splatreel.viewer.renderer import RenderSettings, render_image
from splatreel.viewer.synthetic import synthetic_model

from test_model import keyframed
from test_viewer_sort import gaussians_from_motion, swapping_pair

FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--disable-component-update", "--no-first-run", "--disable-sync",
         "--disable-quic", "--hide-scrollbars", "--mute-audio"]
W, H = 96, 72
BACKGROUND = (0.2, 0.3, 0.4)
MIN_PSNR = 35.0


def chromium() -> str:
    found = shutil.which("chromium")
    if found is None:
        subprocess.run(["apt-get", "install", "-y", "-q", "chromium"], check=True, capture_output=True)
        found = shutil.which("chromium")
    assert found, "chromium is not installed and apt-get could not install it"
    return found


class Browser:
    """Headless Chromium over the DevTools protocol (a pipe), one page."""

    def __init__(self) -> None:
        self.profile = tempfile.mkdtemp(prefix="chromium-")
        to_child, self._w = os.pipe()
        self._r, from_child = os.pipe()

        def fds() -> None:  # the child reads commands on fd 3 and writes replies on fd 4
            a, b = os.dup(to_child), os.dup(from_child)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen([chromium(), *FLAGS, f"--user-data-dir={self.profile}", "--remote-debugging-pipe",
                                      "about:blank"], preexec_fn=fds, pass_fds=(3, 4), stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        os.close(to_child)
        os.close(from_child)
        self._buf, self._id, self.events = b"", 0, []
        page = next(t for t in self.send("Target.getTargets")["targetInfos"] if t["type"] == "page")
        self.session = self.send("Target.attachToTarget", targetId=page["targetId"], flatten=True)["sessionId"]
        for domain in ("Runtime", "Page", "Log"):
            self.call(f"{domain}.enable")

    def send(self, method: str, session: str | None = None, timeout: float = 30.0, **params):
        self._id += 1
        message = {"id": self._id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self._w, json.dumps(message).encode() + b"\0")
        end = time.monotonic() + timeout
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._id:
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply["result"]
                if "method" in reply:
                    self.events.append(reply)
            left = end - time.monotonic()
            if left <= 0 or not select.select([self._r], [], [], left)[0]:
                raise TimeoutError(f"no reply to {method}")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise RuntimeError("the browser exited")
            self._buf += chunk

    def call(self, method: str, **params):
        return self.send(method, session=self.session, **params)

    def eval(self, expression: str):
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in r:
            raise RuntimeError(str(r["exceptionDetails"]))
        return r["result"].get("value")

    def errors(self, since: int = 0) -> list[str]:
        """Console errors, uncaught exceptions and failed loads among the events from number `since` on."""
        out = []
        for e in self.events[since:]:
            method, p = e["method"], e.get("params", {})
            if method == "Runtime.exceptionThrown":
                out.append(p["exceptionDetails"].get("exception", {}).get("description", p["exceptionDetails"]["text"]))
            elif method == "Runtime.consoleAPICalled" and p["type"] in ("error", "assert"):
                out.append(" ".join(str(a.get("value", a.get("description"))) for a in p["args"]))
            elif method == "Log.entryAdded" and p["entry"]["level"] == "error":
                out.append(p["entry"]["text"])
        return out

    def render(self, url: str, width: int = W, height: int = H, timeout: float = 30.0) -> np.ndarray:
        """The page's canvas once its first frame at the URL's view and time is drawn: ``[H, W, 3]`` in [0, 1]."""
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False)
        self.call("Page.navigate", url=url)
        end = time.monotonic() + timeout
        while not self.eval("!!(document.documentElement && document.documentElement.dataset.ready === '1')"):
            if time.monotonic() > end:
                raise TimeoutError(f"{url}: no frame drawn; console: {self.errors()}")
            time.sleep(0.05)
        data = self.eval("document.getElementById('view').toDataURL('image/png')")
        png = Image.open(io.BytesIO(base64.b64decode(data.split(",", 1)[1]))).convert("RGB")
        return np.asarray(png, np.float64) / 255.0

    def close(self) -> None:
        try:
            self.send("Browser.close", timeout=5)
            self.proc.wait(10)
        except (RuntimeError, TimeoutError, OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        os.close(self._w)
        os.close(self._r)
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """(folder, base URL): a static file server on 127.0.0.1 over a fresh folder."""
    root = tmp_path_factory.mktemp("web")
    handler = functools.partial(_QuietHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield root, f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    #: every path requested, in order (the single-file page must ask for itself only)
    requested: list[str] = []

    def log_message(self, *args) -> None:
        pass

    def do_GET(self) -> None:
        _QuietHandler.requested.append(self.path.split("?", 1)[0])
        super().do_GET()


@pytest.fixture(scope="module")
def browser():
    b = Browser()
    yield b
    b.close()


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(((a - b) ** 2).mean())
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def reference(model, cam, t: float, **settings) -> np.ndarray:
    return np.clip(render_image(model, cam, t, RenderSettings(background=BACKGROUND, **settings))[..., :3], 0, 1)


def url(base: str, cam, t: float, **extra) -> str:
    pose = ",".join(repr(float(x)) for x in cam.c2w.flatten())
    fov = np.degrees(2 * np.arctan(0.5 * cam.height / cam.fy))
    query = "&".join(f"{k}={v}" for k, v in {"cam": pose, "fov": repr(float(fov)), "t": repr(float(t)), "paused": 1,
                                               "ui": 0, **extra}.items())
    return f"{base}?{query}"


def check_page(browser, page_url: str, model, cam, t: float, **settings) -> tuple[np.ndarray, float]:
    before = len(browser.events)
    img = browser.render(page_url, cam.width, cam.height)
    assert browser.errors(before) == []
    ref = reference(model, cam, t, **settings)
    return img, psnr(img, ref)


def test_data_file_layout_and_quantize():
    model = synthetic_model(50, sh_degree=2, sh_degree_t=1)
    data = web_data(model, background=BACKGROUND, up_axis="Z")
    assert data[:4] == MAGIC
    length = int(np.frombuffer(data[4:8], np.uint32)[0])
    header = json.loads(data[8:8 + length])
    assert (8 + length) % 16 == 0
    assert header["kind"] == "gaussians4d" and header["count"] == 50 and header["background"] == list(BACKGROUND)
    assert header["sh_degree"] == 2 and header["sh_degree_t"] == 1 and header["sh_texels"] == 14  # 18 * 3 / 4
    geom = header["arrays"]["geom"]
    assert geom["type"] == "f32" and geom["size"][0] * geom["size"][1] >= 4 * 50
    # the conditional mean's velocity and 1 / (2 Sigma_tt) as splatreel.viewer.splats computes them
    from splatreel.viewer.splats import to_arrays

    values = np.frombuffer(data, np.float32, count=geom["bytes"] // 4, offset=8 + length + geom["offset"])
    values = values[:4 * 4 * 50].reshape(50, 4, 4)
    arrays = to_arrays(model)
    np.testing.assert_allclose(values[:, 0], arrays.mean_t, rtol=1e-6)
    np.testing.assert_allclose(values[:, 1], arrays.motion, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(values[:, 3, 3], arrays.opacity, rtol=1e-6)
    small = web_data(model, background=BACKGROUND, quantize=True)
    assert len(small) < 0.5 * len(data)
    lowered = web_data(model, sh_degree=0)
    header0 = json.loads(lowered[8:8 + int(np.frombuffer(lowered[4:8], np.uint32)[0])])
    assert header0["sh_degree"] == 0 and header0["sh_texels"] == 2  # 2 time sets x 1 coefficient x rgb, padded


def accelerated(model, size: float, seed: int = 0):
    """`model` with random accelerations of std-dev `size` per axis (units per unit of time squared)."""
    g = torch.Generator().manual_seed(seed)
    return replace(model, accelerations=size * torch.randn(len(model), 3, generator=g, dtype=model.means.dtype))


def geometry_texels(data: bytes) -> tuple[dict, np.ndarray]:
    """(header, the geometry texels ``[count, geom_texels, 4]``) of an unquantized ``splats.bin``."""
    length = int(np.frombuffer(data[4:8], np.uint32)[0])
    header = json.loads(data[8:8 + length])
    geom, n, k = header["arrays"]["geom"], header["count"], header["geom_texels"]
    values = np.frombuffer(data, np.float32, count=geom["bytes"] // 4, offset=8 + length + geom["offset"])
    return header, values[:4 * k * n].reshape(n, k, 4)


def test_accelerations_take_a_fifth_texel_and_only_when_there_are_some():
    linear = synthetic_model(50, sh_degree=1)
    header, values = geometry_texels(web_data(linear))
    assert header["geom_texels"] == 4 and values.shape == (50, 4, 4)
    same = web_data(replace(linear, accelerations=torch.zeros(50, 3)))  # zero accelerations: the linear file
    assert same == web_data(linear)
    model = accelerated(linear, 2.0)
    header, values = geometry_texels(web_data(model))
    width, height = header["arrays"]["geom"]["size"]
    assert header["geom_texels"] == 5 and width * height >= 5 * 50
    np.testing.assert_allclose(values[:, 4, :3], model.accelerations.numpy(), rtol=1e-6)
    np.testing.assert_array_equal(values[:, :4], geometry_texels(web_data(linear))[1])  # the others unchanged
    keyed = json.loads((d := web_data(keyframed()))[8:8 + int(np.frombuffer(d[4:8], np.uint32)[0])])
    assert keyed["geom_texels"] == 4


def test_native_pair_swaps_depth_order_like_the_desktop_renderer(served, browser):
    root, base = served
    model = swapping_pair()
    write_web(model, root / "pair", background=BACKGROUND, up_axis="Z")
    cam = look_at((-4.0, 0.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=30, width=W, height=H)
    centre = (H // 2, W // 2)
    for t, front in ((0.0, 0), (1.0, 2)):  # red in front at t = 0, blue at t = 1
        img, db = check_page(browser, url(f"{base}/pair/index.html", cam, t), model, cam, t)
        assert db >= MIN_PSNR, (t, db)
        assert img[centre].argmax() == front


@pytest.mark.parametrize("quantize, accelerations", [(False, False), (True, False), (False, True), (True, True)])
def test_native_sh_and_time_terms_match_render(served, browser, quantize, accelerations):
    root, base = served
    linear = synthetic_model(300, sh_degree=2, sh_degree_t=1, scale=0.03, seed=6)
    model = accelerated(linear, 3.0, seed=2) if accelerations else linear
    name = f"syn{int(quantize)}{int(accelerations)}"
    write_web(model, root / name, background=BACKGROUND, up_axis="Z", quantize=quantize)
    cam = look_at((1.2, -1.5, 0.8), (0.0, 0.0, 0.0), "z", fov_deg=40, width=W, height=H)
    for t in (0.2, 0.75):
        img, db = check_page(browser, url(f"{base}/{name}/index.html", cam, t), model, cam, t)
        assert db >= MIN_PSNR, (quantize, t, db)
        if accelerations:  # they move the image: a page that ignored them would fail above
            assert psnr(img, reference(linear, cam, t)) < MIN_PSNR - 5, t


def test_accelerated_pair_swaps_depth_order(served, browser):
    """Red starts in front of blue and, accelerated away from the camera, ends behind it: the page's depth sort
    must follow the accelerations (its stored mean and velocity alone keep red in front)."""
    root, base = served
    pair = gaussians_from_motion([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], torch.eye(3) * 0.15 ** 2, [[0.0, 0.0, 0.0]],
                                 100.0, 5.0, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    model = replace(pair, accelerations=torch.tensor([[6.0, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64))
    write_web(model, root / "accpair", background=BACKGROUND, up_axis="Z")
    cam = look_at((-4.0, 0.0, 0.0), (0.0, 0.0, 0.0), "z", fov_deg=30, width=W, height=H)
    centre = (H // 2, W // 2)
    for t, front in ((0.0, 0), (1.0, 2)):  # red (x = -1) in front at t = 0; at t = 1 red is at x = 2, behind blue
        img, db = check_page(browser, url(f"{base}/accpair/index.html", cam, t), model, cam, t)
        assert db >= MIN_PSNR, (t, db)
        assert img[centre].argmax() == front


def test_lower_sh_degree_matches_render_at_that_degree(served, browser):
    root, base = served
    model = synthetic_model(200, sh_degree=2, sh_degree_t=1, scale=0.03, seed=3)
    write_web(model, root / "sh0", background=BACKGROUND, sh_degree=0)
    cam = look_at((1.2, -1.5, 0.8), (0.0, 0.0, 0.0), "z", fov_deg=40, width=W, height=H)
    _, db = check_page(browser, url(f"{base}/sh0/index.html", cam, 0.4), model, cam, 0.4, sh_degree=0)
    assert db >= MIN_PSNR, db


def test_keyframed_model_interpolates_like_slice(served, browser):
    root, base = served
    model = keyframed()
    write_web(model, root / "keys", background=BACKGROUND, up_axis="Z")
    cam = look_at((0.0, -6.0, 2.0), (0.0, 0.0, 0.0), "z", fov_deg=40, width=W, height=H)
    for t in (0.25, 1.6):  # between keys 0 and 1, then 1 and 2
        _, db = check_page(browser, url(f"{base}/keys/index.html", cam, t), model, cam, t)
        assert db >= MIN_PSNR, (t, db)


def test_single_file_gives_the_same_image(served, browser):
    root, base = served
    model = swapping_pair()
    write_web(model, root / "folder", background=BACKGROUND)
    (path,) = write_web(model, root / "one.html", background=BACKGROUND, single_file=True)
    assert path.is_file() and not (root / DATA_NAME).exists()
    assert 'id="splat-data"' in path.read_text()
    cam = look_at((-3.0, -2.0, 1.0), (0.0, 0.0, 0.0), "z", fov_deg=35, width=W, height=H)
    del _QuietHandler.requested[:]
    folder, _ = check_page(browser, url(f"{base}/folder/index.html", cam, 0.7), model, cam, 0.7)
    assert sorted(_QuietHandler.requested) == ["/folder/index.html", "/folder/player.js", "/folder/shaders.js",
                                               "/folder/skinning.js", f"/folder/{DATA_NAME}"]  # (loaded in parallel)
    del _QuietHandler.requested[:]
    single, db = check_page(browser, url(f"{base}/one.html", cam, 0.7), model, cam, 0.7)
    assert _QuietHandler.requested == ["/one.html"]  # nothing else, from anywhere: the page holds it all
    assert db >= MIN_PSNR
    np.testing.assert_array_equal(single, folder)


def test_cli_export_web(tmp_path, capsys):
    model = swapping_pair()
    ckpt = tmp_path / "pair.safetensors"
    save_checkpoint(ckpt, model.to(dtype=torch.float32), background=(1.0, 1.0, 1.0), provenance={"up_axis": "Z"})
    out = tmp_path / "player"
    assert main(["export", "web", str(ckpt), "--out", str(out), "--quantize", "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "player.js", "shaders.js", "skinning.js", DATA_NAME]
    data = (out / DATA_NAME).read_bytes()
    header = json.loads(data[8:8 + int(np.frombuffer(data[4:8], np.uint32)[0])])
    assert header["background"] == [1.0, 1.0, 1.0] and header["up"] == "z" and header["arrays"]["geom"]["type"] == "f16"
    assert "the whole animation" in capsys.readouterr().out
    with pytest.raises(OutputExistsError):
        write_web(model, out)
    assert main(["export", "web", str(ckpt), "--out", str(out), "--force", "--quiet"]) == 0
    assert main(["export", "web", str(ckpt), "--out", str(tmp_path / "p.html"), "--single-file", "--quiet"]) == 0
    with pytest.raises(ExportError, match="single-file"):
        write_web(model, tmp_path / "notes", single_file=True)
    assert main(["export", "web", str(ckpt), "--out", str(tmp_path / "x"), "--frame-count", "3"]) == 1
    assert "--frame-count" in capsys.readouterr().err


def _frame_after(browser, action, timeout: float = 20.0) -> np.ndarray:
    """Run `action`, then wait for a new frame drawn with the order of its own view and time; read the canvas."""
    frames = int(browser.eval("Number(document.documentElement.dataset.frames)"))
    action()
    end = time.monotonic() + timeout
    while not browser.eval(f"document.documentElement.dataset.frames > {frames} && "
                           "document.documentElement.dataset.sorted === '1'"):
        assert time.monotonic() < end, "no new frame"
        time.sleep(0.05)
    data = browser.eval("document.getElementById('view').toDataURL('image/png')")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(data.split(",", 1)[1]))).convert("RGB"), np.float64) / 255


def test_controls_orbit_reset_link_and_play(served, browser):
    root, base = served
    model = swapping_pair()
    write_web(model, root / "controls", background=BACKGROUND, up_axis="Z")
    page = f"{base}/controls/index.html?eye=-4,-1,0.5&target=0,0,0&fov=35&t=0.2&paused=1"
    before = len(browser.events)
    start = browser.render(page, 320, 240)  # room for the control bar at the bottom
    assert browser.eval("getComputedStyle(document.getElementById('bar')).display") != "none"

    def drag(dx: float, dy: float, button: str = "left"):
        def act():
            x, y = 160, 60
            buttons = 1 if button == "left" else 2
            browser.call("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, button=button, buttons=buttons,
                         clickCount=1)
            browser.call("Input.dispatchMouseEvent", type="mouseMoved", x=x + dx, y=y + dy, button=button,
                         buttons=buttons)
            browser.call("Input.dispatchMouseEvent", type="mouseReleased", x=x + dx, y=y + dy, button=button,
                         buttons=0, clickCount=1)
        return act

    orbited = _frame_after(browser, drag(60, 10))
    assert np.abs(orbited - start).max() > 0.2  # the view moved
    zoomed = _frame_after(browser, lambda: browser.call("Input.dispatchMouseEvent", type="mouseWheel", x=160,
                                                        y=60, deltaX=0, deltaY=-300))
    assert np.abs(zoomed - orbited).max() > 0.2
    def pinch():  # two fingers spreading apart: zoom in
        points = lambda d: [{"x": 160 - d, "y": 60, "id": 0}, {"x": 160 + d, "y": 60, "id": 1}]  # noqa: E731
        browser.call("Input.dispatchTouchEvent", type="touchStart", touchPoints=points(30))
        browser.call("Input.dispatchTouchEvent", type="touchMove", touchPoints=points(60))
        browser.call("Input.dispatchTouchEvent", type="touchEnd", touchPoints=[])

    pinched = _frame_after(browser, pinch)
    assert np.abs(pinched - zoomed).max() > 0.2
    reset = _frame_after(browser, lambda: browser.eval("document.getElementById('reset').click()"))
    np.testing.assert_array_equal(reset, start)
    # the Link button writes the view and time into the URL; loading it gives the same image
    moved = _frame_after(browser, drag(-40, 20))
    browser.eval("document.getElementById('link').click()")
    assert "cam=" in browser.eval("location.search")
    linked = browser.render(browser.eval("location.href"), 320, 240)
    assert psnr(linked, moved) > 45
    # playing advances the time slider
    browser.eval("document.getElementById('play').click()")
    time.sleep(0.5)
    assert float(browser.eval("document.getElementById('time').value")) > 0.2
    assert browser.errors(before) == []
