"""``splatreel export web``: a static WebGL2 player of the whole model (``index.html`` + ``shaders.js`` +
``skinning.js`` + ``player.js`` + ``splats.bin``, or one self-contained HTML file with ``--single-file``). No build
step, no network at view time.

The page evaluates the model at time t on the GPU exactly as the desktop renderer does (`splatreel.viewer.renderer`,
``shaders/splat_preprocess.glsl`` and ``splat_draw.glsl``, constants from `splatreel.constants` written into the
data file):

* native 4D (Yang et al., "Real-time Photorealistic Dynamic Scene Representation and Rendering with 4D Gaussian
  Splatting", ICLR 2024): per Gaussian the conditional mean at its temporal centre mu_x, the velocity
  v = Σ_xt / Σ_tt, 1 / (2 Σ_tt), and the constant conditional covariance Σ_xx - Σ_xt Σ_xtᵀ / Σ_tt
  (`splatreel.covariance.condition_on_time`) as scales and a rotation (`decompose_covariance_3d`), and the
  acceleration a when the model has non-zero `Gaussians4D.accelerations` (the quadratic motion of Spacetime
  Gaussians, Li et al. CVPR 2024). At t the mean is mu_x + v (t - mu_t) + a (t - mu_t)^2 / 2 (a = 0 without
  accelerations) and the opacity sigmoid(o) exp(-(t - mu_t)^2 / (2 Σ_tt)), culled at or below TEMPORAL_CULL of
  its peak; the colour is the SH of the kept degree with the time terms summed with cos(2 pi n (mu_t - t) / T)
  (`splatreel.sh.collapse_time`), + 0.5 clamped at 0;
* keyframed: every key's means, rotations, scales, opacities and SH; the page interpolates between the two keys
  around t as `KeyframedGaussians.slice` does (lerp, slerp along the shorter arc; held outside the keys);
* skinned (`splatreel.skinned.SkinnedGaussians`): the canonical native 4D Gaussians as above (without
  accelerations, which do not move them), each one's skin (4 nodes and weights) and the control nodes' keys. Per
  displayed time the page computes the M node poses as `splatreel.skinned.node_poses` does (``skinning.js``:
  Catmull-Rom positions, normalised lerp of the rotations, the end poses held outside the keys) into a small float
  texture, and the vertex shader carries each native Gaussian's canonical mean and conditional covariance by its
  nodes (linear blend skinning, SC-GS, Huang et al. CVPR 2024: ``shaders/splat_skin.glsl``, the desktop one).

Projection as the trainer's rasterizer: EWA Jacobian at the clamped x/z, y/z, + EPS2D px^2, near-plane cull, alpha
clamped at MAX_ALPHA and cut where it falls below ALPHA_THRESHOLD, inside the reference's tile rectangle. The page
sorts the Gaussians back to front by their depth at t (the evaluated mean) in a Web Worker (16-bit counting sort)
whenever the view or t changes, and blends premultiplied colour with "over".

``splats.bin`` layout (little-endian): the 4 bytes ``SRWB``, u32 L, L bytes of UTF-8 JSON (`_header`: what the
model is, the constants, the camera to start from, and each array's byte offset after the header, type and shape),
then the arrays, each starting on a 16-byte boundary: ``geom``, ``geom_texels`` RGBA texels per Gaussian (and key),
and ``sh``, the colour coefficients (coefficient-major r g b, zero-padded to whole texels); a skinned model's
``node_canonical`` ``[M, 3]``, ``node_positions`` ``[F, M, 3]`` and ``node_rotations`` ``[F, M, 4]`` (w first,
unnormalised) follow as float32 (``node_count`` M and ``node_times`` [F] are in the header). The geometry texels:

=====  ==============================  ===============================  ==================================
texel  native 4D                       skinned                          keyframed (a row per key and
                                                                        Gaussian)
=====  ==============================  ===============================  ==================================
0      mu_x (xyz), mu_t                canonical mean mu_x (xyz), mu_t  mean (xyz), opacity
1      v = Σ_xt / Σ_tt (xyz),          v (unused), 1 / (2 Σ_tt)         0
       1 / (2 Σ_tt)
2      rotation (w, x, y, z)           rotation (w, x, y, z)            rotation (w, x, y, z)
3      scales (xyz), sigmoid(o)        scales (xyz), sigmoid(o)         scales (xyz), 0
4      acceleration (xyz), 0: only     4 node indices                   (none)
       when ``geom_texels`` is 5
5      (none)                          their 4 blend weights            (none)
=====  ==============================  ===============================  ==================================

``geom_texels`` is 5 for a native model with non-zero accelerations, 6 for a skinned one and 4 otherwise (linear
native models and keyframed ones keep the 4-texel layout and size). ``--quantize`` stores the geometry as half
floats (node indices exact up to 2048 nodes) and the colour coefficients as 8 bits per value with a per-texel-slot
linear range (``lo + step * byte``); the node keys stay float32.
"""

from __future__ import annotations

import argparse
import base64
import json
import math
from importlib import resources
from pathlib import Path

import numpy as np

from splatreel.constants import (ALPHA_THRESHOLD, EIGEN_FLOOR, EPS2D, FRUSTUM_CLAMP, MAX_ALPHA, NEAR_PLANE,
                                 RADIUS_SIGMAS, TEMPORAL_CULL, TILE_SIZE)
from splatreel.fileio import atomic_dir, atomic_write_bytes

from .base import ExportError, resolve_up_axis

MAGIC = b"SRWB"
DATA_NAME = "splats.bin"
#: the page's scripts, in loading order: the shaders and the node poses, then the player that uses them
SCRIPT_NAMES = ("shaders.js", "skinning.js", "player.js")
#: texels per row of the data textures (WebGL2 guarantees MAX_TEXTURE_SIZE >= 2048; SwiftShader and GPUs give more)
TEXTURE_WIDTH = 2048
#: --single-file refuses models whose data is larger than this (base64 in an HTML file grows by 4/3)
SINGLE_FILE_LIMIT = 64 * 2**20
#: the largest finite half float: 1 / (2 Sigma_tt) is clamped to it when quantized
HALF_MAX = 65504.0
#: half floats hold every integer up to this: the most nodes a quantized skinned model's indices can name
HALF_INTEGERS = 2048


def _decompose(cov3):
    from splatreel.covariance import decompose_covariance_3d

    scales, quats = decompose_covariance_3d(cov3)
    return scales.numpy(), quats.numpy()


def _sh_slots(coeffs: np.ndarray, degree: int, degree_t: int, keep: int) -> np.ndarray:
    """``[..., K (degree_t + 1), 3]`` coefficients -> ``[..., S]`` float32 (S = 4 ceil(3 M / 4)), keeping SH degree
    `keep` of every time set (coefficient-major, r g b per coefficient, zero-padded as splatreel.viewer.splats)."""
    k, k_keep = (degree + 1) ** 2, (keep + 1) ** 2
    sets = [coeffs[..., n * k:n * k + k_keep, :] for n in range(degree_t + 1)]
    kept = np.concatenate(sets, axis=-2)
    flat = kept.reshape(kept.shape[:-2] + (-1,))
    width = 4 * ((flat.shape[-1] + 3) // 4)
    out = np.zeros(flat.shape[:-1] + (width,), np.float32)
    out[..., :flat.shape[-1]] = flat
    return out


def _geometry(model) -> tuple[np.ndarray, np.ndarray, dict]:
    """(geometry ``[rows, T texels, 4]``, SH ``[rows, S]`` before degree lowering, model fields of the header);
    T = 5 for a native model with non-zero accelerations, 6 for a skinned one, else 4 (see module doc)."""
    import torch

    if model.kind == "gaussians4d":
        return _native_geometry(model)
    if model.kind == "skinned":  # the canonical native Gaussians and their skin; the node keys go to _node_arrays
        from splatreel.skinned import padded_skin

        geom, sh, fields = _native_geometry(model.gaussians, skin=padded_skin(model.skin))
        return geom, sh, {**fields, "kind": "skinned", "node_count": model.num_nodes,
                          "node_times": model.node_times.tolist()}
    if model.kind != "keyframed":
        raise ExportError(f"export web plays native 4D, keyframed and skinned models, not a {model.kind} model")
    with torch.no_grad():
        m = model.to(device="cpu", dtype=torch.float64)
        f, n = m.num_frames, len(m)
        geom = np.zeros((f, n, 4, 4), np.float64)
        geom[:, :, 0, :3], geom[:, :, 0, 3] = m.means.numpy(), m.opacities.numpy()
        geom[:, :, 2] = m.quats.numpy()
        geom[:, :, 3, :3] = m.scales.numpy()
        geom = geom.reshape(f * n, 4, 4)
        sh = m.sh.numpy().reshape(f * n, -1, 3)
    t0, t1 = m.time_range
    fields = {"kind": "keyframed", "count": n, "keys": f, "key_times": m.times.tolist(), "geom_texels": 4,
              "sh_degree": m.sh_degree, "sh_degree_t": 0, "duration": float(t1 - t0) or 1.0}
    return _finite(geom, sh), sh, fields


def _native_geometry(model, skin=None) -> tuple[np.ndarray, np.ndarray, dict]:
    """`_geometry` of a native 4D model; with `skin` (its ``[N, 4]`` nodes and weights: a skinned model's canonical
    Gaussians) two texels of them instead of the accelerations, which do not move a skinned Gaussian."""
    import torch

    from splatreel.covariance import condition_on_time

    with torch.no_grad():
        m = model.detach().to(device="cpu", dtype=torch.float64)
        cov3, velocity, var_t = condition_on_time(m.covariance_4d())
        scales, quats = _decompose(cov3)
        n = len(m)
        accelerated = skin is None and m.accelerations is not None and bool((m.accelerations != 0).any())
        geom = np.zeros((n, 6 if skin is not None else 5 if accelerated else 4, 4), np.float64)
        geom[:, 0, :3], geom[:, 0, 3] = m.means.numpy(), m.t_means.numpy()
        geom[:, 1, :3], geom[:, 1, 3] = velocity.numpy(), 0.5 / var_t.numpy()
        geom[:, 2] = quats
        geom[:, 3, :3], geom[:, 3, 3] = scales, m.opacities.numpy()
        if accelerated:
            geom[:, 4, :3] = m.accelerations.numpy()
        if skin is not None:
            geom[:, 4], geom[:, 5] = (x.detach().to("cpu", torch.float64).numpy() for x in skin)
        sh = m.sh_coeffs.numpy()
    fields = {"kind": "gaussians4d", "count": n, "keys": 1, "key_times": [], "geom_texels": geom.shape[1],
              "sh_degree": m.sh_degree, "sh_degree_t": m.sh_degree_t, "duration": float(m.duration)}
    return _finite(geom, sh), sh, fields


def _finite(geom: np.ndarray, sh: np.ndarray) -> np.ndarray:
    if not (np.isfinite(geom).all() and np.isfinite(sh).all()):
        raise ExportError("the model has NaN or infinite values (bad covariances or temporal scales)")
    return geom


def _node_arrays(model) -> dict[str, np.ndarray]:
    """A skinned model's node keys as float32 arrays (none for other models): canonical positions ``[M, 3]``, key
    positions ``[F, M, 3]`` and rotations ``[F, M, 4]`` (w first, unnormalised); the key times are in the header."""
    import torch

    if model.kind != "skinned":
        return {}
    return {name: getattr(model, name).detach().to("cpu", torch.float32).numpy()
            for name in ("node_canonical", "node_positions", "node_rotations")}


def _texture(values: np.ndarray, dtype) -> tuple[np.ndarray, list[int]]:
    """``[rows, 4 k]`` values (k RGBA texels per row) -> the texels in order, ``[height * width, 4]`` zero-padded
    (width = TEXTURE_WIDTH, or fewer for a small model), and [width, height]."""
    flat = values.reshape(-1, 4).astype(dtype)
    total = flat.shape[0]
    width = min(TEXTURE_WIDTH, max(total, 1))
    height = max(1, -(-total // width))
    image = np.zeros((height * width, 4), dtype)
    image[:total] = flat
    return image, [width, height]


def _quantize_u8(sh: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``[rows, S]`` -> bytes ``[rows, S]``, per-slot lo ``[S]`` and step ``[S]`` (value = lo + step * byte)."""
    lo, hi = sh.min(0), sh.max(0)
    step = np.where(hi > lo, (hi - lo) / 255.0, 1.0)
    q = np.clip(np.round((sh - lo) / step), 0, 255).astype(np.uint8)
    return q, lo.astype(np.float32), step.astype(np.float32)


def default_view(model, up_axis: str) -> dict:
    """The starting camera: eye, target and vertical FOV, framing the model's bounds from the front-left, above."""
    from splatreel.model import model_bounds

    lo, hi = (b.double().numpy() for b in model_bounds(model))
    centre, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    fov = 50.0
    d = np.array([0.6, -0.7, 0.4]) if up_axis == "Z" else np.array([0.6, 0.4, 0.7])
    eye = centre + 1.1 * radius / math.sin(math.radians(fov) / 2) * d / np.linalg.norm(d)
    return {"eye": eye.tolist(), "target": centre.tolist(), "fov": fov}


def web_data(model, *, sh_degree: int | None = None, quantize: bool = False, background=(0.0, 0.0, 0.0),
             up_axis: str = "Y", title: str = "splatreel") -> bytes:
    """The bytes of ``splats.bin`` for `model` (see module doc)."""
    geom, sh, fields = _geometry(model)
    degree = fields["sh_degree"] if sh_degree is None else min(int(sh_degree), fields["sh_degree"])
    if degree < 0:
        raise ExportError(f"--sh-degree must be 0..3, got {sh_degree}")
    sh = _sh_slots(sh, fields["sh_degree"], fields["sh_degree_t"], degree)
    fields["sh_degree"] = degree
    arrays: dict[str, tuple[np.ndarray, dict]] = {}
    if quantize and fields.get("node_count", 0) > HALF_INTEGERS:
        raise ExportError(f"--quantize stores node indices as half floats, exact up to {HALF_INTEGERS} nodes; this "
                          f"model has {fields['node_count']} (export without --quantize)")
    if quantize:
        g = geom.copy()
        g[..., 1, 3] = np.minimum(g[..., 1, 3], HALF_MAX)
        image, size = _texture(g.reshape(len(g), -1), np.float16)
        arrays["geom"] = (image, {"type": "f16", "size": size})
        q, lo, step = _quantize_u8(sh)
        image, size = _texture(q, np.uint8)
        arrays["sh"] = (image, {"type": "u8", "size": size, "lo": lo.tolist(), "step": step.tolist()})
    else:
        image, size = _texture(geom.reshape(len(geom), -1), np.float32)
        arrays["geom"] = (image, {"type": "f32", "size": size})
        image, size = _texture(sh, np.float32)
        arrays["sh"] = (image, {"type": "f32", "size": size})
    for name, values in _node_arrays(model).items():  # float32 even with --quantize
        arrays[name] = (values, {"type": "f32", "shape": list(values.shape)})
    header = {"format": "splatreel-web", "version": 1, "title": title, **fields,
              "time_range": [float(x) for x in model.time_range], "sh_texels": sh.shape[1] // 4,
              "background": [float(c) for c in background], "up": up_axis.lower(),
              "view": default_view(model, up_axis),
              "constants": {"ALPHA_THRESHOLD": ALPHA_THRESHOLD, "MAX_ALPHA": MAX_ALPHA, "EPS2D": EPS2D,
                            "NEAR_PLANE": NEAR_PLANE, "FRUSTUM_CLAMP": FRUSTUM_CLAMP, "RADIUS_SIGMAS": RADIUS_SIGMAS,
                            "EIGEN_FLOOR": EIGEN_FLOOR, "TEMPORAL_CULL": TEMPORAL_CULL, "TILE_SIZE": TILE_SIZE},
              "arrays": {}}
    payload, offset = [], 0
    for name, (image, meta) in arrays.items():
        raw = np.ascontiguousarray(image).tobytes()
        header["arrays"][name] = {**meta, "offset": offset, "bytes": len(raw)}
        pad = -len(raw) % 16
        payload += [raw, b"\0" * pad]
        offset += len(raw) + pad
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-(len(text) + 8) % 16)  # the arrays start 16-byte aligned in the file
    return MAGIC + np.uint32(len(text)).tobytes() + text + b"".join(payload)


def _asset(name: str) -> str:
    """A file of the player; ``shaders.js`` gets the desktop renderer's footprint and skinning code in its vertex
    shader and its splat alpha in its fragment shader (one copy of each in GLSL: shaders/splat_footprint.glsl,
    splat_skin.glsl, splat_alpha.glsl)."""
    text = resources.files("splatreel.export").joinpath("web_player", name).read_text(encoding="utf-8")
    if name == "shaders.js":
        from splatreel.gl import shader_source

        for part in ("splat_footprint", "splat_alpha", "splat_skin"):
            text = text.replace(f"/*{part.upper()}*/", shader_source(part).replace("`", "'"))
    return text


def page_html(title: str, data_b64: str | None = None) -> str:
    """``index.html``: loads the scripts and ``splats.bin`` beside it, or (with `data_b64`) holds them all inline."""
    html = _asset("index.html").replace("{{TITLE}}", _escape(title))
    if data_b64 is None:
        tags = "\n".join(f'<script src="{name}"></script>' for name in SCRIPT_NAMES)
        return html.replace("{{DATA}}", "").replace("{{SCRIPT}}", tags)
    inline = "\n".join("<script>\n" + _asset(name).replace("</script", "<\\/script") + "</script>"
                       for name in SCRIPT_NAMES)
    data = f'<script id="splat-data" type="application/octet-stream">{data_b64}</script>'
    return html.replace("{{DATA}}", data).replace("{{SCRIPT}}", inline)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def write_web(model, out: str | Path, *, single_file: bool = False, force: bool = False, **options) -> list[Path]:
    """Write the player of `model` to folder `out` (or, with `single_file`, the one HTML file `out`) atomically;
    `options` go to `web_data`. Returns the files written."""
    out = Path(out)
    title = options.pop("title", None) or out.stem
    data = web_data(model, title=title, **options)
    if single_file:
        if out.suffix.lower() not in (".html", ".htm"):
            raise ExportError(f"{out}: --single-file writes one .html file")
        if len(data) > SINGLE_FILE_LIMIT:
            raise ExportError(f"{out}: the model's data is {len(data) / 2**20:.0f} MiB; --single-file takes at most "
                              f"{SINGLE_FILE_LIMIT // 2**20} MiB (write a folder instead)")
        html = page_html(title, base64.b64encode(data).decode("ascii"))
        return [atomic_write_bytes(out, html.encode("utf-8"), force)]
    with atomic_dir(out, force) as tmp:
        (tmp / "index.html").write_text(page_html(title), encoding="utf-8")
        for name in SCRIPT_NAMES:
            (tmp / name).write_text(_asset(name), encoding="utf-8")
        (tmp / DATA_NAME).write_bytes(data)
    return [out / "index.html", *(out / name for name in SCRIPT_NAMES), out / DATA_NAME]


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export web``."""
    p.add_argument("--single-file", action="store_true",
                   help="write one self-contained OUT.html (data inlined as base64) instead of a folder")
    p.add_argument("--sh-degree", type=int, choices=(0, 1, 2, 3), default=None,
                   help="lower the SH degree kept for the colour (default: the model's)")
    p.add_argument("--quantize", action="store_true",
                   help="half-float geometry and 8-bit colour coefficients (about half to a third the size)")
    p.add_argument("--title", default=None, help="page title (default: the output name)")


def run(model, times, out, args) -> list[Path]:
    """``splatreel export web``: the whole model (the page animates it; the frame options do not apply)."""
    provenance = getattr(args, "provenance", None)
    background = getattr(args, "background", None)
    return write_web(model, out, single_file=args.single_file, force=args.force, sh_degree=args.sh_degree,
                     quantize=args.quantize, background=(0.0, 0.0, 0.0) if background is None else background,
                     up_axis=resolve_up_axis(getattr(args, "up_axis", None), provenance), title=args.title)
