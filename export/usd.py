"""OpenUSD export of a 4D model: time-sampled 3DGS splats, a point-instancer and a points fallback on one stage.

Stage layout (``/World`` is the default prim)::

    /World                       Xform
    /World/Splats                ParticleField3DGaussianSplat   (--what splats)
    /World/Instancer             PointInstancer                 (--what instancer)
    /World/Instancer/Prototypes  over, holding UnitSphere (radius 1)
    /World/Points                Points                         (--what points)
    /World/Looks/DisplayColor    UsdPreviewSurface reading displayColor / displayOpacity (instancer, points)

Time: frame i is time code i (0 .. F-1); ``timeCodesPerSecond = framesPerSecond = --fps``; model time at time
code i is ``customLayerData["splatreel"]["model_time_start"] + i * ["model_time_step"]``.

Every per-particle attribute is authored at every time code, with the same N and order at every sample
(invisible Gaussians keep their slot with opacity 0), so a reader interpolating between samples blends the same
Gaussian: positions lerp (exact for native 4D Gaussians, which move linearly), orientations slerp, opacities and SH
lerp (a piecewise-linear approximation of the temporal Gaussian and of the cosine colour terms).

Splats (OpenUSD's ``UsdVol.ParticleField3DGaussianSplat`` schema, OpenUSD >= 26.03, ``pxr/usd/usdVol/schema.usda``):
positions, orientations (quatf), scales (linear std-devs), opacities (linear),
``radiance:sphericalHarmonicsCoefficients`` (raw 3DGS coefficients, per particle K = (d+1)^2 RGB triplets in 3DGS order;
``elementSize = K``), uniform ``radiance:sphericalHarmonicsDegree`` (always authored), a DC ``primvars:displayColor``
fallback, and an extent per sample covering the 3-sigma ellipsoid of every Gaussian visible at that sample or a
neighbouring one (so interpolated times are covered too).

Instancer: one unit-sphere prototype; per instance positions, ``orientations`` (quath, read by Blender) and
``orientationsf`` (quatf, preferred by USD >= 26.11), ``scales = instance_sigmas * std-devs`` (the sphere becomes the
k-sigma ellipsoid), ``ids`` = model index, ``velocities`` in units per second, ``invisibleIds`` of the Gaussians
invisible at that sample, vertex ``primvars:displayColor``/``displayOpacity``.

Points: ``points``, ``widths = 2 * instance_sigmas * mean std-dev`` (0 for invisible Gaussians), ``ids``,
``velocities``, vertex displayColor/displayOpacity (Blender's importer drops instancer primvars, not these).

Colour: displayColor is the DC colour decoded from sRGB to linear (USD treats displayColor as linear); the SH stay
raw 3DGS coefficients, whose evaluation (+0.5) gives sRGB-encoded colour as in every 3DGS tool. When splats are
written together with a fallback, the fallbacks get ``purpose = "proxy"`` and the splats ``proxyPrim`` -> the
instancer (or points), the USD way to pair a heavy prim with a light stand-in.

Readers that predate the splat schema: the splat prim also carries the attributes of a ``Points`` prim, and the
stage's ``fallbackPrimTypes`` metadata names ``Points`` as its fallback type (an OpenUSD mechanism for new schemas:
an older reader uses the first fallback it knows). Blender 5.0 (OpenUSD 25.08) skips proxy prims at its default
import options and knows no splat schema; through the fallback it imports the splats as an animated point cloud
with displayColor, so the default export is never an empty scene.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from splatreel.colorspace import srgb_to_linear
from splatreel.fileio import atomic_path

from .base import (ExportError, SplatFrame, box_of, iter_frames, live_near, resolve_up_axis,
                   time_step, with_neighbours)

#: The prim kinds ``--what`` chooses from, in authoring order.
USD_PRIM_KINDS: tuple[str, ...] = ("splats", "instancer", "points")
#: File suffixes `write_usd` accepts (``.usd`` is binary crate).
USD_SUFFIXES: tuple[str, ...] = (".usd", ".usda", ".usdc", ".usdz")
#: OpenUSD's zip reader has no ZIP64: every layer packed in a .usdz must stay below this.
USDZ_LAYER_LIMIT = 4 * 1024 ** 3 - 1

ROOT = "/World"
PRIM_PATHS = {"splats": f"{ROOT}/Splats", "instancer": f"{ROOT}/Instancer", "points": f"{ROOT}/Points"}
PROTOTYPE_PATH = f"{PRIM_PATHS['instancer']}/Prototypes/UnitSphere"
MATERIAL_PATH = f"{ROOT}/Looks/DisplayColor"
#: stage metadata: readers whose OpenUSD predates the splat schema read the splat prim as this type instead
FALLBACK_PRIM_TYPES = {"ParticleField3DGaussianSplat": ["Points"]}
#: a .usda (text) stage above this many bytes gets a warning suggesting .usdc
LARGE_TEXT_STAGE = 64 * 2 ** 20


@dataclass(frozen=True)
class UsdOptions:
    """How `build_usd_stage` lays out the stage.

    Attributes:
        what: prim kinds to author, a subset of `USD_PRIM_KINDS`.
        fps: time codes (= frames) per second.
        up_axis: "Y" or "Z", the model's up axis, written as stage metadata (data is not rotated).
        meters_per_unit: stage ``metersPerUnit``.
        instance_sigmas: k: instancer spheres are the k-sigma ellipsoids, points are 2 k mean-sigma wide.
    """

    what: tuple[str, ...] = USD_PRIM_KINDS
    fps: float = 24.0
    up_axis: str = "Y"
    meters_per_unit: float = 1.0
    instance_sigmas: float = 2.0

    def __post_init__(self) -> None:
        parse_what(",".join(self.what))  # raises on unknown kinds
        if self.up_axis not in ("Y", "Z"):
            raise ExportError(f"--up must be y or z for USD, got {self.up_axis!r}")
        for name in ("fps", "meters_per_unit", "instance_sigmas"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ExportError(f"--{name.replace('_', '-')} must be a positive number, got {v}")


def parse_what(text: str) -> tuple[str, ...]:
    """``"splats,points"`` -> ``("splats", "points")`` in `USD_PRIM_KINDS` order (ExportError on unknown kinds)."""
    parts = [p.strip().lower() for p in text.split(",") if p.strip()]
    unknown = [p for p in parts if p not in USD_PRIM_KINDS]
    if unknown or not parts:
        raise ExportError(f"--what: unknown prim kind(s) {', '.join(unknown) or '(none given)'}; "
                          f"choose from {','.join(USD_PRIM_KINDS)}")
    return tuple(k for k in USD_PRIM_KINDS if k in parts)


# --- numpy -> Vt ---------------------------------------------------------------------------------------------

def _vec3f(a: np.ndarray):
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32).reshape(-1, 3))


def _floats(a: np.ndarray):
    from pxr import Vt

    return Vt.FloatArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32).reshape(-1))


def _int64s(a: np.ndarray):
    from pxr import Vt

    return Vt.Int64Array.FromNumpy(np.ascontiguousarray(a, dtype=np.int64).reshape(-1))


def _quats(wxyz: np.ndarray, half: bool = False):
    """``[N, 4]`` w-first quaternions -> Vt.QuatfArray (or QuathArray); FromNumpy wants (x, y, z, w)."""
    from pxr import Vt

    xyzw = np.ascontiguousarray(np.roll(wxyz, -1, axis=1), dtype=np.float16 if half else np.float32)
    return (Vt.QuathArray if half else Vt.QuatfArray).FromNumpy(xyzw)


def _author(attr, value, frame_index: int) -> None:
    """Set the time sample of frame `frame_index`; frame 0 also becomes the default value, which readers of static
    assets see (``Get()`` without a time returns None on sample-only attributes). Crate files store the shared array
    once."""
    attr.Set(value, frame_index)
    if frame_index == 0:
        attr.Set(value)


# --- stage ---------------------------------------------------------------------------------------------------

def configure_stage(stage, num_frames: int, fps: float, up_axis: str = "Y", meters_per_unit: float = 1.0,
                    times: Sequence[float] | None = None) -> None:
    """Stage metadata every splatreel USD file carries: /World as default prim, up axis, metersPerUnit,
    timeCodesPerSecond = framesPerSecond = fps, start/end time codes 0 .. F-1, and (given `times`) the time code
    -> model time map in ``customLayerData["splatreel"]``."""
    from pxr import UsdGeom

    world = UsdGeom.Xform.Define(stage, ROOT).GetPrim()
    stage.SetDefaultPrim(world)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(max(num_frames - 1, 0))
    if times is not None:
        stage.GetRootLayer().customLayerData = {"splatreel": {
            "model_time_start": float(times[0]), "model_time_step": time_step(times), "num_frames": len(times),
            "frame_to_model_time": "model_time_start + timeCode * model_time_step"}}


def _display_material(stage):
    """A UsdPreviewSurface whose diffuse colour and opacity read the displayColor/displayOpacity primvars (Storm and
    most renderers ignore per-instance displayOpacity without it)."""
    from pxr import Sdf, UsdGeom, UsdShade

    UsdGeom.Scope.Define(stage, MATERIAL_PATH.rsplit("/", 1)[0])
    material = UsdShade.Material.Define(stage, MATERIAL_PATH)
    surface = UsdShade.Shader.Define(stage, f"{MATERIAL_PATH}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    for name, kind, typ in (("displayColor", "float3", Sdf.ValueTypeNames.Float3),
                            ("displayOpacity", "float", Sdf.ValueTypeNames.Float)):
        reader = UsdShade.Shader.Define(stage, f"{MATERIAL_PATH}/{name}")
        reader.CreateIdAttr(f"UsdPrimvarReader_{kind}")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set(name)  # string, not token (UsdPreviewSurface spec, UsdPrimvarReader)
        out = reader.CreateOutput("result", typ)
        target = "diffuseColor" if name == "displayColor" else "opacity"
        surface.CreateInput(target, Sdf.ValueTypeNames.Color3f if target == "diffuseColor" else typ
                            ).ConnectToSource(out)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return material


def _bind(prim, material) -> None:
    from pxr import UsdShade

    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def _set_vertex_primvar(gprim, name: str, type_name, value, time) -> None:
    from pxr import UsdGeom

    pv = UsdGeom.PrimvarsAPI(gprim).CreatePrimvar(name, type_name, UsdGeom.Tokens.vertex)
    _author(pv.GetAttr(), value, time)


#: the splat prim's Points fallback: spheres out to 1 std-dev (the Gaussian's core), none for Gaussians fainter than
#: FALLBACK_MIN_OPACITY (an opaque sphere would show a faint halo Gaussian as a solid blob)
FALLBACK_SIGMAS = 1.0
FALLBACK_MIN_OPACITY = 0.1


def points_widths(frame: SplatFrame, sigmas: float, min_opacity: float = 0.0) -> np.ndarray:
    """``[N]`` widths of the points that stand for `frame`'s Gaussians: ``2 k`` mean std-devs, 0 when invisible
    (or fainter than `min_opacity`)."""
    shown = frame.visible & (frame.opacities >= min_opacity)
    return np.where(shown, 2.0 * sigmas * frame.scales.mean(1), 0.0)


class _SplatsWriter:
    """Authors `/World/Splats` (ParticleField3DGaussianSplat), one time sample per `write` call.

    The prim also carries what a ``Points`` prim reads (``points``, ``widths``, ``velocities``, displayColor and
    displayOpacity, the display material), and the stage names ``Points`` as the splat type's fallback
    (``fallbackPrimTypes``, `FALLBACK_PRIM_TYPES`): an OpenUSD that predates the splat schema (Blender 5.0 bundles
    25.08) reads the same prim as animated, coloured points instead of skipping it.
    """

    def __init__(self, stage, sh_degree: int, sigmas: float, material):
        from pxr import UsdGeom, UsdVol

        del sigmas  # the fallback's spheres are FALLBACK_SIGMAS wide, whatever the instancer's are
        self.prim = UsdVol.ParticleField3DGaussianSplat.Define(stage, PRIM_PATHS["splats"])
        self.fallback = UsdGeom.Points(self.prim.GetPrim())
        self.fallback_attrs = {"points": self.fallback.CreatePointsAttr(), "widths": self.fallback.CreateWidthsAttr(),
                               "velocities": self.fallback.CreateVelocitiesAttr()}
        self.fallback.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        _bind(self.prim.GetPrim(), material)
        self.prim.CreateRadianceSphericalHarmonicsDegreeAttr().Set(int(sh_degree))
        self.prim.CreateProjectionModeHintAttr().Set("perspective")
        self.prim.CreateSortingModeHintAttr().Set("cameraDistance")
        self.sh = self.prim.CreateRadianceSphericalHarmonicsCoefficientsAttr()
        # Pixar's and NVIDIA's converters tag the SH like a primvar; readers written against them look for it.
        self.sh.SetMetadata("elementSize", (sh_degree + 1) ** 2)
        self.sh.SetMetadata("interpolation", "vertex")
        self.attrs = {"positions": self.prim.CreatePositionsAttr(), "orientations": self.prim.CreateOrientationsAttr(),
                      "scales": self.prim.CreateScalesAttr(), "opacities": self.prim.CreateOpacitiesAttr(),
                      "extent": self.prim.CreateExtentAttr()}

    def write(self, frame: SplatFrame, near: np.ndarray, velocity_scale: float, color: np.ndarray) -> None:
        from pxr import Sdf

        tc = frame.index
        _author(self.attrs["positions"], _vec3f(frame.means), tc)
        _author(self.attrs["orientations"], _quats(frame.quats), tc)
        _author(self.attrs["scales"], _vec3f(frame.scales), tc)
        _author(self.attrs["opacities"], _floats(frame.opacities), tc)
        _author(self.sh, _vec3f(frame.sh), tc)
        _author(self.attrs["extent"], _vec3f(box_of(frame.means, frame.radii, near)), tc)
        _set_vertex_primvar(self.prim, "displayColor", Sdf.ValueTypeNames.Color3fArray, _vec3f(color), tc)
        # the Points fallback (a crate file stores the positions array once for both attributes)
        fa = self.fallback_attrs
        _author(fa["points"], _vec3f(frame.means), tc)
        _author(fa["widths"], _floats(points_widths(frame, FALLBACK_SIGMAS, FALLBACK_MIN_OPACITY)), tc)
        _author(fa["velocities"], _vec3f(frame.velocities * velocity_scale), tc)
        _set_vertex_primvar(self.prim, "displayOpacity", Sdf.ValueTypeNames.FloatArray, _floats(frame.opacities),
                            tc)


class _InstancerWriter:
    """Authors `/World/Instancer` (PointInstancer over one unit sphere)."""

    def __init__(self, stage, count: int, sigmas: float, material):
        from pxr import Sdf, UsdGeom, Vt

        self.sigmas = sigmas
        self.prim = UsdGeom.PointInstancer.Define(stage, PRIM_PATHS["instancer"])
        sphere = UsdGeom.Sphere.Define(stage, PROTOTYPE_PATH)
        sphere.CreateRadiusAttr(1.0)
        sphere.CreateExtentAttr(_vec3f(np.array([[-1, -1, -1], [1, 1, 1]])))
        # Defining the sphere re-specifies its parent as `def`; prototypes live under an `over` so that plain
        # traversals (and renderers) do not draw the prototype itself.
        stage.GetPrimAtPath(PROTOTYPE_PATH).GetParent().SetSpecifier(Sdf.SpecifierOver)
        _bind(sphere.GetPrim(), material)
        self.prim.CreatePrototypesRel().SetTargets([Sdf.Path(PROTOTYPE_PATH)])
        self.prim.CreateProtoIndicesAttr().Set(Vt.IntArray.FromNumpy(np.zeros(count, np.int32)))
        self.prim.CreateIdsAttr().Set(_int64s(np.arange(count)))
        self.attrs = {"positions": self.prim.CreatePositionsAttr(), "orientations": self.prim.CreateOrientationsAttr(),
                      "orientationsf": self.prim.CreateOrientationsfAttr(), "scales": self.prim.CreateScalesAttr(),
                      "velocities": self.prim.CreateVelocitiesAttr(),
                      "invisibleIds": self.prim.CreateInvisibleIdsAttr(), "extent": self.prim.CreateExtentAttr()}

    def write(self, frame: SplatFrame, near: np.ndarray, velocity_scale: float, color: np.ndarray) -> None:
        from pxr import Sdf

        tc, k = frame.index, self.sigmas
        a = self.attrs
        _author(a["positions"], _vec3f(frame.means), tc)
        _author(a["orientations"], _quats(frame.quats, half=True), tc)
        _author(a["orientationsf"], _quats(frame.quats), tc)
        _author(a["scales"], _vec3f(k * frame.scales), tc)
        _author(a["velocities"], _vec3f(frame.velocities * velocity_scale), tc)
        _author(a["invisibleIds"], _int64s(np.flatnonzero(~frame.visible)), tc)
        _author(a["extent"], _vec3f(box_of(frame.means, frame.radii * (k / 3.0), near)), tc)
        _set_vertex_primvar(self.prim, "displayColor", Sdf.ValueTypeNames.Color3fArray, _vec3f(color), tc)
        _set_vertex_primvar(self.prim, "displayOpacity", Sdf.ValueTypeNames.FloatArray, _floats(frame.opacities),
                            tc)


class _PointsWriter:
    """Authors `/World/Points` (UsdGeom.Points with per-point colour, for importers that drop instancer primvars)."""

    def __init__(self, stage, count: int, sigmas: float, material):
        from pxr import UsdGeom

        self.sigmas = sigmas
        self.prim = UsdGeom.Points.Define(stage, PRIM_PATHS["points"])
        _bind(self.prim.GetPrim(), material)
        self.prim.CreateIdsAttr().Set(_int64s(np.arange(count)))
        self.widths = self.prim.CreateWidthsAttr()
        self.prim.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        self.attrs = {"points": self.prim.CreatePointsAttr(), "velocities": self.prim.CreateVelocitiesAttr(),
                      "extent": self.prim.CreateExtentAttr()}

    def write(self, frame: SplatFrame, near: np.ndarray, velocity_scale: float, color: np.ndarray) -> None:
        from pxr import Sdf

        tc = frame.index
        full = 2.0 * self.sigmas * frame.scales.mean(1)  # [N] width when visible
        _author(self.attrs["points"], _vec3f(frame.means), tc)
        _author(self.widths, _floats(points_widths(frame, self.sigmas)), tc)
        _author(self.attrs["velocities"], _vec3f(frame.velocities * velocity_scale), tc)
        # points visible at a neighbouring sample are interpolated towards their full width: cover that width
        _author(self.attrs["extent"], _vec3f(box_of(frame.means, 0.5 * full[:, None], near)), tc)
        _set_vertex_primvar(self.prim, "displayColor", Sdf.ValueTypeNames.Color3fArray, _vec3f(color), tc)
        _set_vertex_primvar(self.prim, "displayOpacity", Sdf.ValueTypeNames.FloatArray, _floats(frame.opacities),
                            tc)


_WRITERS = {"splats": _SplatsWriter, "instancer": _InstancerWriter, "points": _PointsWriter}


def build_usd_stage(model, times: Sequence[float], options: UsdOptions = UsdOptions(), progress: bool = False):
    """Author the whole animation on a new in-memory stage and return it (nothing touches disk).

    Args:
        model: any model with ``slice(t)`` (Gaussians4D, KeyframedGaussians, SkinnedGaussians).
        times: ``[F]`` model times of the frames (`splatreel.export.frame_times`), uniformly spaced.
        options: `UsdOptions`.
    Returns:
        ``pxr.Usd.Stage`` (anonymous root layer).
    """
    from pxr import Usd, UsdGeom

    times = [float(t) for t in times]
    if not times:
        raise ExportError("no frames to export")
    stage = Usd.Stage.CreateInMemory()
    configure_stage(stage, len(times), options.fps, options.up_axis, options.meters_per_unit, times)
    if "splats" in options.what:
        from pxr import Vt

        stage.SetMetadata("fallbackPrimTypes", {k: Vt.TokenArray(v) for k, v in FALLBACK_PRIM_TYPES.items()})
    material = _display_material(stage)
    # velocities: model units per model time -> units per second = * (model time per time code) * (codes per s)
    velocity_scale = time_step(times) * options.fps
    writers = None
    for prev, frame, nxt in with_neighbours(iter_frames(model, times, progress, desc="usd")):
        if writers is None:
            writers = []
            for kind in options.what:
                args = (stage, frame.sh_degree) if kind == "splats" else (stage, len(frame))
                args += (options.instance_sigmas, material)
                writers.append(_WRITERS[kind](*args))
        near = live_near(prev, frame, nxt)
        color = srgb_to_linear(frame.dc_rgb())
        for w in writers:
            w.write(frame, near, velocity_scale, color)
    if "splats" in options.what and len(options.what) > 1:
        proxies = [PRIM_PATHS[k] for k in ("instancer", "points") if k in options.what]
        for path in proxies:
            UsdGeom.Imageable(stage.GetPrimAtPath(path)).CreatePurposeAttr(UsdGeom.Tokens.proxy)
        UsdGeom.Imageable(stage.GetPrimAtPath(PRIM_PATHS["splats"])).CreateProxyPrimRel().SetTargets([proxies[0]])
    return stage


def save_stage(stage, path: str | Path, force: bool = False) -> Path:
    """Write `stage` to `path` (.usd/.usda/.usdc, or .usdz packed from a .usdc) atomically.

    Raises:
        ExportError: unknown suffix, or a .usdz whose layer would pass the 4 GiB zip limit.
    """
    from pxr import Sdf, UsdUtils

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in USD_SUFFIXES:
        raise ExportError(f"{path}: unknown USD suffix {path.suffix or '(none)'}; use one of "
                          f"{', '.join(USD_SUFFIXES)}")
    with atomic_path(path, force) as tmp:
        if suffix != ".usdz":
            if not stage.GetRootLayer().Export(str(tmp)):
                raise ExportError(f"{path}: USD could not write the layer")
            return path
        work = Path(tempfile.mkdtemp(prefix=".usdz.", dir=path.parent))
        try:
            layer = work / f"{path.stem}.usdc"
            stage.GetRootLayer().Export(str(layer))
            if layer.stat().st_size > USDZ_LAYER_LIMIT:
                raise ExportError(f"{path}: the layer is {layer.stat().st_size / 2**30:.1f} GiB, over the 4 GiB "
                                  f"limit of .usdz (no ZIP64); write .usdc instead or export fewer frames")
            tmp.unlink()  # the packager refuses to overwrite the placeholder mkstemp made
            if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(layer)), str(tmp)):
                raise ExportError(f"{path}: USD could not create the .usdz package")
        finally:
            shutil.rmtree(work, ignore_errors=True)
    return path


def write_usd(model, path: str | Path, times: Sequence[float], options: UsdOptions = UsdOptions(),
              force: bool = False, progress: bool = False) -> Path:
    """`build_usd_stage` then `save_stage`; refuses an existing `path` without `force` before any work."""
    from splatreel.fileio import check_writable

    path = check_writable(path, force)
    if path.suffix.lower() not in USD_SUFFIXES:
        raise ExportError(f"{path}: unknown USD suffix {path.suffix or '(none)'}; use one of "
                          f"{', '.join(USD_SUFFIXES)}")
    written = save_stage(build_usd_stage(model, times, options, progress), path, force)
    if path.suffix.lower() == ".usda" and written.stat().st_size > LARGE_TEXT_STAGE:
        import warnings

        warnings.warn(f"{path} holds {written.stat().st_size / 2 ** 20:.0f} MiB of text; the same stage as .usdc "
                      "(binary crate) is over 10x smaller and opens faster", stacklevel=2)
    return written


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export usd`` (its entry in `splatreel.formats`)."""
    from splatreel.argtypes import positive_number

    p.add_argument("--what", default=",".join(USD_PRIM_KINDS), metavar="KINDS",
                   help=f"comma-separated prim kinds to write, from {','.join(USD_PRIM_KINDS)} (default: all)")
    p.add_argument("--instance-sigmas", type=positive_number, default=2.0,
                   help="instancer spheres are the k-sigma ellipsoids; points are 2k mean-sigma wide (default 2)")


def run(model, times, out, args) -> list[Path]:
    """``splatreel export usd``: write `model` at `times` to `out` as the parsed `args` say."""
    up = resolve_up_axis(args.up_axis, getattr(args, "provenance", None))
    options = UsdOptions(what=parse_what(args.what), fps=args.fps, up_axis=up,
                         meters_per_unit=args.meters_per_unit, instance_sigmas=args.instance_sigmas)
    return [write_usd(model, out, times, options, force=args.force, progress=args.progress)]
