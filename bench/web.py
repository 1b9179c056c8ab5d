"""The web player (``export web``) in headless Chromium beside the desktop GL renderer, in the same run.

    python bench/web.py [--json OUT.json] [--cases sample,200k] [--seconds 6]

For each case (the bundled sample, the synthetic 200k native 4D model of bench/viewer.py) at 1280x720: the export's
size, full and ``--quantize``; the page's frames per second while it plays (Chromium headless, WebGL2 on
SwiftShader: software, on the same CPU cores; the page's own frame counter over ``--seconds``); and the desktop
renderer's frames per second on the same model, view size and machine (EGL on llvmpipe, bench/viewer.py's
measurement), with the ratio. Chromium is driven as tests/test_web.py drives it (the DevTools protocol on a pipe).
"""

from __future__ import annotations

import argparse
import http.server
import json
import sys
import tempfile
import threading
import time
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "bench")]

from test_web import Browser  # noqa: E402  (the tests' Chromium driver)
from viewer import build_case, measure  # noqa: E402  (bench/viewer.py)

SIZE = (1280, 720)


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # no line per request in the table's output
        pass


def serve(folder: Path) -> tuple[str, http.server.ThreadingHTTPServer]:
    handler = partial(_QuietHandler, directory=str(folder))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return f"http://127.0.0.1:{server.server_address[1]}", server


def page_fps(browser: Browser, url: str, seconds: float) -> float:
    """Frames the playing page draws per second (its ``data-frames`` counter), after its first frame."""
    browser.call("Emulation.setDeviceMetricsOverride", width=SIZE[0], height=SIZE[1], deviceScaleFactor=1,
                 mobile=False)
    browser.call("Page.navigate", url=url)
    count = "Number((document.documentElement && document.documentElement.dataset.frames) || 0)"
    end = time.monotonic() + 120.0
    while browser.eval(count) < 2:  # loaded, uploaded, drawing
        if time.monotonic() > end:
            raise TimeoutError(f"{url}: the page drew nothing; console: {browser.errors()}")
        time.sleep(0.1)
    start, t0 = browser.eval(count), time.monotonic()
    time.sleep(seconds)
    return (browser.eval(count) - start) / (time.monotonic() - t0)


def run(cases: list[str], seconds: float) -> list[dict]:
    from splatreel.checkpoint import save_checkpoint
    from splatreel.cli import main

    rows = []
    browser = Browser()
    try:
        for name in cases:
            model, center, distance, fov = build_case(name)
            with tempfile.TemporaryDirectory() as tmp:
                tmp = Path(tmp)
                ckpt = save_checkpoint(tmp / "m.safetensors", model, background=(1.0, 1.0, 1.0))
                sizes = {}
                for kind, extra in (("full", []), ("quantized", ["--quantize"])):
                    out = tmp / kind
                    assert main(["export", "web", str(ckpt), "--out", str(out), "--quiet", *extra]) == 0
                    sizes[kind] = sum(p.stat().st_size for p in out.iterdir())
                base, server = serve(tmp / "full")
                try:
                    eye = ",".join(f"{c:g}" for c in (center[0] + distance, center[1], center[2] + 0.3 * distance))
                    target = ",".join(f"{c:g}" for c in center)
                    fps = page_fps(browser, f"{base}/index.html?eye={eye}&target={target}&fov={fov:g}&up=z&ui=0",
                                   seconds)
                finally:
                    server.shutdown()
            desktop = measure(model, center, distance, fov, SIZE, 8, "front-to-back", {})
            rows.append({"case": name, "n": len(model), "size": f"{SIZE[0]}x{SIZE[1]}",
                         "bytes_full": sizes["full"], "bytes_quantized": sizes["quantized"],
                         "web_fps": round(fps, 2), "desktop_fps": desktop["fps"],
                         "web_over_desktop": round(fps / desktop["fps"], 2)})
    finally:
        browser.close()
    return rows


def main_cli() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", metavar="OUT", help="also write the rows as JSON")
    p.add_argument("--cases", default="sample,200k")
    p.add_argument("--seconds", type=float, default=6.0, help="how long the page plays while its frames are counted")
    args = p.parse_args()
    rows = run(args.cases.split(","), args.seconds)
    print(f"{'case':<8}{'N':>10}{'size':>10}{'full MiB':>10}{'quant MiB':>10}{'web FPS':>9}{'GL FPS':>8}{'ratio':>7}")
    for r in rows:
        print(f"{r['case']:<8}{r['n']:>10,}{r['size']:>10}{r['bytes_full'] / 2**20:>10.1f}"
              f"{r['bytes_quantized'] / 2**20:>10.1f}{r['web_fps']:>9.2f}{r['desktop_fps']:>8.1f}"
              f"{r['web_over_desktop']:>7.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main_cli()
