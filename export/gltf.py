"""glTF 2.0 binary (``.glb``) with Khronos ``KHR_gaussian_splatting``: the model at one time per file.

Layout, per the extension's README (KhronosGroup/glTF, ``extensions/2.0/Khronos/KHR_gaussian_splatting``): one mesh
with one ``POINTS`` primitive whose attributes are ``POSITION`` (with min/max), ``KHR_gaussian_splatting:ROTATION``
(unit quaternion, x y z w), ``:SCALE`` (linear std-devs), ``:OPACITY`` (linear, after the sigmoid, times the
temporal factor), ``:SH_DEGREE_l_COEF_i`` (raw 3DGS coefficients, RGB, ascending m within a degree, every degree up
to the model's) and a ``COLOR_0`` fallback (linear RGBA: the DC colour decoded from sRGB, alpha the opacity) that
viewers without the extension draw as a point cloud. The extension object says ``kernel: ellipse``,
``colorSpace: srgb_rec709_display`` (3DGS colours are sRGB-encoded), ``projection: perspective``,
``sortingMethod: cameraDistance``. Every attribute is float32, tightly packed, with ``target = ARRAY_BUFFER``.

Axes: glTF is +Y up. The data stay in the model's coordinates (so the SH need no rotation) and the node's rotation
turns a +Z-up model upright, as the spec's node rules allow (a viewer rotates the SH with the node).

Time: core glTF has no time-varying splat attributes, so a 4D model is written as one ``.glb`` per frame
(``OUTDIR/splats_000000.glb`` ... + ``manifest.json``), or one file for one frame. Every frame keeps every Gaussian
in model order; one the slice hides has opacity 0.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from splatreel.colorspace import srgb_to_linear
from splatreel.fileio import atomic_dir, atomic_write_bytes

from .base import ExportError, SplatFrame, frame_file_name, iter_frames, manifest, resolve_up_axis

EXTENSION = "KHR_gaussian_splatting"
#: The extension object every primitive carries.
EXTENSION_OBJECT = {"kernel": "ellipse", "colorSpace": "srgb_rec709_display", "projection": "perspective",
                    "sortingMethod": "cameraDistance"}
ARRAY_BUFFER = 34962
FLOAT = 5126
POINTS = 0
#: Node rotation (x, y, z, w) that stands a model upright in glTF's +Y-up world: -90 degrees about X for +Z up.
UPRIGHT = {"Y": [0.0, 0.0, 0.0, 1.0], "Z": [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]}


def sh_attribute_names(degree: int) -> list[str]:
    """The SH attribute semantics of degrees 0..`degree`, in 3DGS coefficient order."""
    return [f"{EXTENSION}:SH_DEGREE_{d}_COEF_{i}" for d in range(degree + 1) for i in range(2 * d + 1)]


def frame_attributes(frame: SplatFrame) -> dict[str, np.ndarray]:
    """Semantic -> ``[N, C]`` float32 array of one frame's primitive."""
    from splatreel.sh import SH_C0

    quats = frame.quats / np.linalg.norm(frame.quats, axis=1, keepdims=True)
    dc = np.clip(0.5 + SH_C0 * frame.sh[:, 0], 0.0, 1.0)
    attrs = {"POSITION": frame.means,
             f"{EXTENSION}:ROTATION": np.roll(quats, -1, axis=1),  # w first -> x, y, z, w
             f"{EXTENSION}:SCALE": frame.scales,
             f"{EXTENSION}:OPACITY": frame.opacities[:, None],
             "COLOR_0": np.concatenate([srgb_to_linear(dc), frame.opacities[:, None]], 1)}
    for k, name in enumerate(sh_attribute_names(frame.sh_degree)):
        attrs[name] = frame.sh[:, k]
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in attrs.items()}


def glb_bytes(frame: SplatFrame, up_axis: str = "Y", name: str = "splats") -> bytes:
    """The ``.glb`` of one frame (see module doc)."""
    import pygltflib as gl

    attrs = frame_attributes(frame)
    blob, views, accessors, semantic_index = bytearray(), [], [], {}
    types = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}
    for semantic, data in attrs.items():
        offset = len(blob)
        blob += data.tobytes()
        views.append(gl.BufferView(buffer=0, byteOffset=offset, byteLength=data.nbytes, target=ARRAY_BUFFER))
        accessor = gl.Accessor(bufferView=len(views) - 1, componentType=FLOAT, count=len(data),
                               type=types[data.shape[1]])
        if semantic == "POSITION":  # required by the core spec
            accessor.min = data.min(0).tolist() if len(data) else [0.0] * 3
            accessor.max = data.max(0).tolist() if len(data) else [0.0] * 3
        accessors.append(accessor)
        semantic_index[semantic] = len(accessors) - 1
    primitive = gl.Primitive(attributes=gl.Attributes(), mode=POINTS,
                             extensions={EXTENSION: dict(EXTENSION_OBJECT)})
    primitive.attributes = semantic_index  # pygltflib writes the dict as is: extension semantics included
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator="splatreel"),
        extensionsUsed=[EXTENSION], scene=0, scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(mesh=0, name=name, rotation=UPRIGHT[str(up_axis).upper()])],
        meshes=[gl.Mesh(primitives=[primitive], name=name)],
        accessors=accessors, bufferViews=views, buffers=[gl.Buffer(byteLength=len(blob))])
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


def write_gltf(model, out: str | Path, times: Sequence[float], up_axis: str = "Y", fps: float = 24.0,
               force: bool = False, progress: bool = False) -> list[Path]:
    """`model` at `times` as ``.glb``: one file `out` (``*.glb``, one time) or a folder of one file per time
    plus ``manifest.json``. Returns the files written."""
    out = Path(out)
    if out.suffix.lower() == ".glb":
        if len(times) != 1:
            raise ExportError(f"{out}: one .glb holds one time; give a folder name for {len(times)} frames "
                              "(one .glb each), or --frame-count 1")
        frame = next(iter_frames(model, times))
        return [atomic_write_bytes(out, glb_bytes(frame, up_axis, out.stem), force)]
    if out.suffix:
        raise ExportError(f"{out}: export gltf writes NAME.glb (one time) or a folder (one .glb per frame)")
    names = []
    with atomic_dir(out, force) as tmp:
        for frame in iter_frames(model, times, progress, desc="gltf"):
            names.append(frame_file_name("splats", frame.index, "glb"))
            (tmp / names[-1]).write_bytes(glb_bytes(frame, up_axis, f"splats_{frame.index:06d}"))
        (tmp / "manifest.json").write_bytes(manifest(
            "gltf-gaussian-splatting-sequence", times, names, fps, time_range=list(model.time_range),
            sh_degree=int(model.sh_degree), up_axis=str(up_axis).upper(), extension=EXTENSION))
    return [out / n for n in names] + [out / "manifest.json"]


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export gltf`` (none beyond the common ones)."""


def run(model, times, out, args) -> list[Path]:
    """``splatreel export gltf``: write `model` at `times` to `out` as the parsed `args` say."""
    return write_gltf(model, out, times, up_axis=resolve_up_axis(args.up_axis, getattr(args, "provenance", None)),
                      fps=args.fps, force=args.force, progress=args.progress)
