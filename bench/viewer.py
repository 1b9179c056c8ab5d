"""Frame time of the GL viewer (EGL, offscreen) against the trainer's rasterizer forward pass for the same frame.

    python bench/viewer.py [--json OUT.json] [--cases sample,200k,1m] [--sizes 512x512,1280x720] [--frames N]

Cases: the bundled sample (``splatreel.samples.trained_checkpoint("spinner")``, a skinned model of about 23k trained
Gaussians) and synthetic native 4D models of 200k and 1M Gaussians (SH degree 3, moving and fading; points in a ball of radius
0.5, std-devs 0.01 x e^(+-0.5), camera at distance 1.5 with a 60 degree field of view). Every measured frame has a new camera (2 degrees further round) and
a new model time, so each one re-sorts, as a playing, orbiting viewer does.

Per case the JSON holds ``n``, ``size``, ``frame_ms`` (median wall time of one frame: sort + pre-pass + draw +
resolve, GPU finished; read-back excluded), its median split ``sort_ms`` / ``draw_ms``, ``raster_fwd_ms`` (median
of ``model.slice(t)`` + ``rasterize(...)`` under no_grad, the trainer's way to make the same image) and
``speedup`` (the median over frames of raster ms / GL ms for that frame), plus ``fps``, ``visible`` (after the
time / near / frustum culls), ``drawn`` (after skipping Gaussians hidden behind opaque pixels) and the device.
The two are measured interleaved, frame by frame (GL frame i, then the rasterizer on the same view), so that both
see the same load on this shared machine: the per-frame ratio is the comparable number, the absolute times drift
by 2x and more between runs.

``--max-std-dev`` / ``--max-screen-radius`` measure the viewer with those footprint caps (the performance guards of
`splatreel.viewer.sorting.Footprint`; recorded in each row), against the uncapped rasterizer as always.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time


def synthetic(n: int):
    from splatreel.viewer.synthetic import synthetic_model

    return synthetic_model(n, seed=0, radius=0.5, scale=0.01, speed=0.2, lifetime=0.35, sh_degree=3)


def build_case(name: str):
    """(model, orbit distance, fov, up) for a case name."""
    if name == "sample":
        from splatreel.checkpoint import load_checkpoint
        from splatreel.samples import trained_checkpoint
        from splatreel.viewer.trajectory import frame_model

        model = load_checkpoint(trained_checkpoint("spinner")).model
        framing = frame_model(model)
        return model, framing.center, framing.distance(40.0), 40.0
    n = {"200k": 200_000, "1m": 1_000_000}[name]
    return synthetic(n), (0.0, 0.0, 0.0), 1.5, 60.0


def measure(model, center, distance, fov, size, frames: int, composite: str, caps: dict) -> dict:
    import torch

    from splatreel.cameras import orbit
    from splatreel.rasterize import rasterize
    from splatreel.viewer.renderer import RenderSettings, SplatRenderer, headless_context

    w, h = size
    t0, t1 = model.time_range
    views = [(orbit(20, 30 + 2 * i, distance, fov, w, h, "z", center), t0 + (t1 - t0) * (0.3 + 0.013 * i))
             for i in range(frames + 1)]
    renderer = SplatRenderer(headless_context(), model)
    settings = RenderSettings(background=(1.0, 1.0, 1.0), composite=composite, **caps)
    total, sort, draw, visible, drawn, raster = [], [], [], [], [], []
    with torch.no_grad():
        renderer.render(*views[0], settings)  # warm-up: shader compile, numba load, targets
        rasterize(model.slice(views[0][1]), views[0][0], (1.0, 1.0, 1.0))  # warm-up (numba kernels)
        for cam, t in views[1:]:
            start = time.perf_counter()
            s = renderer.render(cam, t, settings)
            total.append((time.perf_counter() - start) * 1e3)
            start = time.perf_counter()
            rasterize(model.slice(t), cam, (1.0, 1.0, 1.0))
            raster.append((time.perf_counter() - start) * 1e3)
            sort.append(s.sort_ms)
            draw.append(s.draw_ms + s.upload_ms)
            visible.append(s.visible)
            drawn.append(s.drawn)
    renderer.release()
    frame_ms = statistics.median(total)
    ratios = [r / g for r, g in zip(raster, total)]
    return {"n": len(model), "size": f"{w}x{h}", "frame_ms": round(frame_ms, 2),
            "sort_ms": round(statistics.median(sort), 2), "draw_ms": round(statistics.median(draw), 2),
            "raster_fwd_ms": round(statistics.median(raster), 2), "speedup": round(statistics.median(ratios), 2),
            "speedup_range": [round(min(ratios), 2), round(max(ratios), 2)],
            "fps": round(1e3 / frame_ms, 1), "visible": int(statistics.median(visible)),
            "drawn": int(statistics.median(drawn)), "frames": frames, "composite": composite, **caps}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", metavar="OUT", help="write results here")
    ap.add_argument("--cases", default="sample,200k,1m", help="comma-separated: sample, 200k, 1m")
    ap.add_argument("--sizes", default="512x512,1280x720", help="comma-separated WxH")
    ap.add_argument("--frames", type=int, default=None, help="frames per case, each drawn by GL and by the "
                                                              "rasterizer (default 15 / 9 / 5 by size of model)")
    ap.add_argument("--composite", default="front-to-back", choices=("front-to-back", "back-to-front"))
    from splatreel.viewer.options import add_footprint_args, parse_size

    add_footprint_args(ap)  # the GL side only: the rasterizer draws every splat out to its cut-off
    args = ap.parse_args()
    caps = {k: getattr(args, k) for k in ("max_std_dev", "max_screen_radius", "near_plane", "temporal_fade")
            if getattr(args, k) != ap.get_default(k)}

    from splatreel.viewer.renderer import headless_context

    ctx = headless_context()
    device = f"{ctx.info['GL_RENDERER']} / {ctx.info['GL_VERSION']}"
    sizes = [parse_size(s) for s in args.sizes.split(",")]
    rows = []
    for name in args.cases.split(","):
        model, center, distance, fov = build_case(name.strip().lower())
        frames = args.frames or {"sample": 15, "200k": 9}.get(name, 5)
        for size in sizes:
            row = {"case": name, **measure(model, center, distance, fov, size, frames, args.composite, caps)}
            rows.append(row)
            print(json.dumps(row), flush=True)
        del model

    print(f"\n{device} on {platform.processor() or platform.machine()}\n")
    head = f"{'case':<8}{'N':>10}{'size':>11}{'frame ms':>10}{'sort':>8}{'draw':>9}{'FPS':>7}" \
           f"{'raster fwd':>12}{'speedup':>9}{'(range)':>14}"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['case']:<8}{r['n']:>10,}{r['size']:>11}{r['frame_ms']:>10.1f}{r['sort_ms']:>8.1f}"
              f"{r['draw_ms']:>9.1f}{r['fps']:>7.1f}{r['raster_fwd_ms']:>12.1f}{r['speedup']:>8.2f}x"
              f"{'':>3}{r['speedup_range'][0]:.2f}-{r['speedup_range'][1]:.2f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"device": device, "machine": platform.platform(), "cases": rows}, f, indent=2)


if __name__ == "__main__":
    main()
