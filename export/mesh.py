"""Per-frame surface meshes and their files (`splatreel export mesh`): the surfaces of `splatreel.export.surface`
(the density iso-surface, or the one fused from renders) on one grid for all frames, or one deforming mesh
(`splatreel.export.deforming`).

Output folder: ``mesh_%06d.{obj,ply,glb}`` per frame, ``mesh_sequence.usd`` (a ``UsdGeom.Mesh`` at /World/Mesh
with time-sampled points, topology, vertex normals, vertex displayColor and extent; frame i = time code i, the
stage metadata of `splatreel.export.usd`) and ``manifest.json``. Colour spaces: PLY/OBJ hold 8-bit (PLY) or float
(OBJ) sRGB-encoded colour; GLB ``COLOR_0`` and USD displayColor hold linear colour (their specs say linear).
Axes: PLY and the USD keep the model's (the stage declares its up axis); GLB and OBJ are turned +Y up (glTF's
definition, and what OBJ importers assume), recorded as ``mesh_up_axis`` in the manifest.
"""
from __future__ import annotations

import argparse
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from splatreel.colorspace import srgb_to_linear
from splatreel.fileio import atomic_dir

from .base import (Y_UP_FORMATS, ExportError, box_of, frame_file_name, iter_frames, manifest, resolve_up_axis,
                   slice_frame, to_y_up)
from .surface import DILATION_VOXELS, FrameMesh, Grid, density_mesh, grid_for_box

MESH_FORMATS: tuple[str, ...] = ("obj", "ply", "glb")
SURFACES: tuple[str, ...] = ("auto", "fused", "density")


@dataclass(frozen=True)
class MeshOptions:
    """Attributes:
        format: per-frame file format, one of `MESH_FORMATS`.
        resolution: voxels along the longest side of the global grid (8 .. 1024).
        iso: density level of the surface (> 0).
        fill: treat cavities enclosed by the surface as inside (a solid, not a double wall).
        color_neighbors: Gaussians blended into each vertex colour (>= 1).
        usd: also write ``mesh_sequence.usd``.
        fps, up_axis, meters_per_unit: metadata of ``mesh_sequence.usd`` and the manifest.
        deforming: one mesh whose vertices move (`splatreel.export.deforming`) instead of one surface per frame.
        reference_time: with `deforming`, the model time at which the surface is extracted (None: the frame that
            shows the most).
    """

    format: str = "ply"
    resolution: int = 128
    iso: float = 0.5
    fill: bool = True
    color_neighbors: int = 8
    usd: bool = True
    fps: float = 24.0
    up_axis: str = "Y"
    meters_per_unit: float = 1.0
    deforming: bool = False
    reference_time: float | None = None
    #: pieces with less than this share of a frame's surface area are dropped (floaters); 0 keeps them all
    min_piece_share: float = 0.02
    #: with `deforming`: UVs (an xatlas atlas) and ``texture.png`` baked from the vertex colours, on the USD mesh
    uv: bool = False
    #: 'fused' (depth rendered from many views, fused into a TSDF: `splatreel.export.fused`), 'density' (the
    #: iso-surface of the Gaussians' density, faster; `splatreel.export.surface`) or 'auto' (`choose_surface`: fused
    #: unless it loses parts of the model). Measured against the procedural samples' true surfaces (bench/mesh.py),
    #: the fused surface lies 0.6-0.7 % of the object's size from them, the density iso-surface 0.9-1.2 %; but a
    #: signed distance cannot hold an open sheet seen from both sides, such as a floor
    surface: str = "auto"

    def __post_init__(self) -> None:
        if self.format not in MESH_FORMATS:
            raise ExportError(f"--format must be one of {', '.join(MESH_FORMATS)}, got {self.format!r}")
        if not 8 <= self.resolution <= 1024:
            raise ExportError(f"--resolution must be 8..1024, got {self.resolution}")
        if not (np.isfinite(self.iso) and self.iso > 0):
            raise ExportError(f"--iso must be a positive number, got {self.iso}")
        if self.surface not in SURFACES:
            raise ExportError(f"--surface must be one of {', '.join(SURFACES)}, got {self.surface!r}")
        if self.uv and not self.deforming:
            raise ExportError("--uv lays out the one topology --deforming keeps; add --deforming")
        if self.color_neighbors < 1:
            raise ExportError(f"--color-neighbors must be >= 1, got {self.color_neighbors}")


def mesh_bytes(mesh: FrameMesh, fmt: str, up_axis: str = "Y") -> bytes:
    """The file bytes of `mesh` as ``obj`` (``v x y z r g b`` colours), ``ply`` (binary, uchar RGBA, normals) or
    ``glb`` (linear ``COLOR_0``, normals). OBJ and GLB are written +Y up (`to_y_up` from the model's `up_axis`),
    PLY in the model's own axes."""
    from trimesh.exchange.gltf import export_glb
    from trimesh.exchange.obj import export_obj
    from trimesh.exchange.ply import export_ply

    if fmt in Y_UP_FORMATS:
        mesh = replace(mesh, vertices=to_y_up(mesh.vertices, up_axis), normals=to_y_up(mesh.normals, up_axis))

    if fmt == "ply":
        return export_ply(mesh.trimesh(), encoding="binary", vertex_normal=True)
    if fmt == "obj":
        return export_obj(mesh.trimesh(), include_normals=True, include_color=True, include_texture=False).encode()
    if fmt == "glb":
        import trimesh

        return export_glb(trimesh.Scene(mesh.trimesh(linear_colors=True)), include_normals=True)
    raise ExportError(f"unknown mesh format {fmt!r}; choose from {', '.join(MESH_FORMATS)}")


class _UsdMeshSequence:
    """Builds ``mesh_sequence.usd``: /World/Mesh with one time sample per frame."""

    def __init__(self, times: Sequence[float], options: MeshOptions):
        from pxr import Usd, UsdGeom

        self.constant_topology = options.deforming  # faces authored once, not per time sample
        from .usd import ROOT, configure_stage

        self.stage = Usd.Stage.CreateInMemory()
        configure_stage(self.stage, len(times), options.fps, options.up_axis, options.meters_per_unit, times)
        self.mesh = UsdGeom.Mesh.Define(self.stage, f"{ROOT}/Mesh")
        self.mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        self.mesh.CreateNormalsAttr()
        self.mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        self.color = self.mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)

    def add(self, index: int, mesh: FrameMesh) -> None:
        from pxr import Vt

        from .usd import _author, _vec3f

        m = self.mesh
        _author(m.GetPointsAttr(), _vec3f(mesh.vertices), index)
        counts = Vt.IntArray.FromNumpy(np.full(len(mesh.faces), 3, np.int32))
        indices = Vt.IntArray.FromNumpy(mesh.faces.astype(np.int32).reshape(-1))
        colors = _vec3f(srgb_to_linear(mesh.colors))
        if self.constant_topology:  # one topology and colour: default values, which every time code reads
            if index == 0:
                m.GetFaceVertexCountsAttr().Set(counts)
                m.GetFaceVertexIndicesAttr().Set(indices)
                self.color.GetAttr().Set(colors)
        else:
            _author(m.GetFaceVertexCountsAttr(), counts, index)
            _author(m.GetFaceVertexIndicesAttr(), indices, index)
            _author(self.color.GetAttr(), colors, index)
        _author(m.GetNormalsAttr(), _vec3f(mesh.normals), index)
        _author(m.GetExtentAttr(), _vec3f(box_of(mesh.vertices, 0.0)), index)


def frame_mesh(frame, grid: Grid, options: MeshOptions) -> FrameMesh:
    """The surface (`options.surface`, 'fused' or 'density': `choose_surface` resolves 'auto' first) of one exported
    frame (`splatreel.export.SplatFrame`) on `grid`."""
    if options.surface == "fused":
        from .fused import fused_mesh

        return fused_mesh(frame, grid, options.fill, options.min_piece_share)
    return density_mesh(frame, grid, options.iso, options.color_neighbors, options.fill, options.min_piece_share)


def choose_surface(model, times: Sequence[float], grid: Grid, options: MeshOptions) -> tuple[str, str, dict]:
    """(surface, why, {frame index: its `FrameMesh`} already made) for `options.surface`. 'auto' fuses the middle
    frame and takes 'fused' when the fused surface holds at least `splatreel.export.fused.MIN_COVERAGE` of the
    density iso-surface's solid, else 'density'; the middle frame's fused mesh is kept, not made again."""
    if options.surface != "auto":
        return options.surface, "asked for", {}
    from .fused import MIN_COVERAGE, fuse_frame, mesh_of_fields, surface_coverage

    middle = len(times) // 2
    frame = slice_frame(model, float(times[middle]), middle)
    fields = fuse_frame(frame, grid, options.fill)
    coverage = surface_coverage(frame, grid, fields[0], options.iso)
    if coverage >= MIN_COVERAGE:
        return ("fused", f"the fused surface holds {coverage:.0%} of the model's solid parts",
                {middle: mesh_of_fields(fields, grid, options.min_piece_share)})
    return "density", (f"the fused surface holds only {coverage:.0%} of the model's solid parts (thin open sheets "
                       "such as a floor)"), {}


def sequence_grid(model, times: Sequence[float], resolution: int, progress: bool = False) -> Grid:
    """The one grid for every frame: the box of every visible Gaussian's 3-sigma support over `times`."""
    if model.kind == "gaussians4d":
        # the conditional covariances of native 4D Gaussians do not change with time: one slice gives the radii,
        # and only the centres move (a tenth of a slice's cost per time)
        import torch

        radii = slice_frame(model, float(times[0])).radii
        with torch.no_grad():
            centres = [(m.numpy(), v.numpy()) for m, v in model.centres([float(t) for t in times])]
        boxes = [box_of(m, radii, v) for m, v in centres if v.any()]
    else:
        boxes = [box_of(f.means, f.radii, f.visible)
                 for f in iter_frames(model, times, progress, desc="mesh bounds") if f.visible.any()]
    if not boxes:
        raise ExportError("no Gaussian is visible at any exported frame: nothing to mesh")
    box = np.stack([np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)])
    return grid_for_box(box, resolution)


def write_mesh_sequence(model, outdir: str | Path, times: Sequence[float], options: MeshOptions = MeshOptions(),
                        force: bool = False, progress: bool = False) -> list[Path]:
    """Write the per-frame meshes, ``mesh_sequence.usd`` (unless ``options.usd`` is off) and ``manifest.json``
    to `outdir`, which appears atomically. Returns the written paths."""
    from splatreel.fileio import check_writable

    outdir = check_writable(outdir, force)
    grid = sequence_grid(model, times, options.resolution, progress)
    surface, surface_reason, made = choose_surface(model, times, grid, options)
    if surface != options.surface and surface == "density":
        warnings.warn(f"using the density iso-surface: {surface_reason} (--surface fused forces it)",
                      stacklevel=2)
    options = replace(options, surface=surface)

    def surface_of(frame) -> FrameMesh:
        mesh = made.pop(frame.index, None)
        return frame_mesh(frame, grid, options) if mesh is None else mesh

    usd = _UsdMeshSequence(times, options) if options.usd else None
    names: list[str] = []
    drift = None
    if options.deforming:
        from .deforming import deforming_meshes

        reference = None if options.reference_time is None else \
            int(np.argmin(np.abs(np.asarray(times, np.float64) - options.reference_time)))
        meshes, drift = deforming_meshes(model, times, grid, surface_of, reference, progress)
        layout = None
        if options.uv and len(meshes[0].faces):
            from .uv import atlas, bake_colors, with_atlas

            layout = atlas(meshes[0].vertices, meshes[0].faces)
            texture = bake_colors(layout, meshes[0].colors)
            meshes = with_atlas(meshes, layout)
    else:
        meshes = (surface_of(frame) for frame in iter_frames(model, times, progress, desc="mesh"))
    with atomic_dir(outdir, force) as tmp:
        for index, mesh in enumerate(meshes):
            names.append(frame_file_name("mesh", index, options.format))
            (tmp / names[-1]).write_bytes(mesh_bytes(mesh, options.format, options.up_axis))
            if usd is not None:
                usd.add(index, mesh)
        extra = []
        if options.deforming:
            from .deforming import morph_animation_glb

            (tmp / "mesh_animation.glb").write_bytes(morph_animation_glb(meshes, options.fps, options.up_axis))
            extra.append("mesh_animation.glb")
        if options.uv and layout is not None:
            import cv2

            from .uv import texture_material

            (tmp / "texture.png").write_bytes(cv2.imencode(".png", cv2.cvtColor(texture, cv2.COLOR_RGB2BGR))[1])
            extra.append("texture.png")
            if usd is not None:
                texture_material(usd.stage, usd.mesh, layout.uvs, "./texture.png")
        if usd is not None:
            from .usd import save_stage

            save_stage(usd.stage, tmp / "mesh_sequence.usd")
            extra.append("mesh_sequence.usd")
        (tmp / "manifest.json").write_bytes(manifest(
            "mesh-sequence", times, names, options.fps, time_range=list(model.time_range),
            mesh_format=options.format, surface=options.surface, surface_reason=surface_reason,
            resolution=options.resolution, filled=options.fill,
            **({"iso": options.iso, "dilation_voxels": DILATION_VOXELS} if options.surface == "density" else {}),
            grid={"origin": grid.origin.tolist(), "voxel": grid.voxel, "shape": list(grid.shape)},
            up_axis=options.up_axis, meters_per_unit=options.meters_per_unit,
            mesh_up_axis="Y" if options.format in Y_UP_FORMATS else options.up_axis,
            vertex_colors="linear" if options.format == "glb" else "srgb",
            usd="mesh_sequence.usd" if usd is not None else None,
            animation="mesh_animation.glb" if options.deforming else None,
            topology="constant (deforming)" if options.deforming else "per frame", deforming=drift))
    return [outdir / n for n in names + extra + ["manifest.json"]]


def add_args(p: argparse.ArgumentParser) -> None:
    """The format's own options of ``splatreel export mesh`` (its entry in `splatreel.formats`)."""
    from splatreel.argtypes import count, finite_number, positive_number

    from .fused import FUSION_VIEWS

    d = MeshOptions
    p.add_argument("--format", choices=MESH_FORMATS, default=d.format, help=f"per-frame mesh format (default {d.format})")
    p.add_argument("--resolution", type=count, default=d.resolution,
                   help=f"voxels along the longest side of the grid shared by all frames (default {d.resolution})")
    p.add_argument("--surface", choices=SURFACES, default=d.surface,
                   help=f"fused: depth and colour rendered from {FUSION_VIEWS} views around the model, fused into a "
                        "signed distance field (closer to what the renders show); density: the iso-surface of the "
                        "Gaussians' density (2-4x faster; holds open sheets such as floors); auto: fused unless "
                        f"it loses parts of the model (tried on the middle frame) (default {d.surface})")
    p.add_argument("--iso", type=positive_number, default=d.iso,
                   help=f"density level of the surface, with --surface density (default {d.iso})")
    p.add_argument("--no-fill", action="store_true",
                   help="keep cavities enclosed by the surface empty (default: fill them, one surface per solid)")
    p.add_argument("--color-neighbors", type=count, default=d.color_neighbors,
                   help="with --surface density: nearest Gaussians blended into each vertex colour "
                        f"(default {d.color_neighbors})")
    p.add_argument("--no-usd", action="store_true", help="do not write mesh_sequence.usd")
    p.add_argument("--keep-all-pieces", action="store_true",
                   help="keep every piece of the surface (default: drop pieces under 2%% of a frame's surface area, "
                        "the floaters a trained model's stray Gaussians make)")
    p.add_argument("--deforming", action="store_true",
                   help="one mesh whose vertices move with the model (the same faces at every frame, which DCC "
                        "tools animate as one object) instead of one surface per frame")
    p.add_argument("--uv", action="store_true",
                   help="with --deforming: UVs (an xatlas atlas, fixed while the vertices move) and texture.png "
                        "baked from the vertex colours, bound on mesh_sequence.usd through a UsdPreviewSurface")
    p.add_argument("--reference-time", type=finite_number, default=None, metavar="T",
                   help="with --deforming: the model time whose surface is carried through the animation "
                        "(default: the frame that shows the most)")


def run(model, times, out, args) -> list[Path]:
    """``splatreel export mesh``: write `model` at `times` to `out` as the parsed `args` say."""
    if Path(out).suffix.lower() in (".ply", ".obj", ".glb", ".usd", ".usdc", ".usda"):
        raise ExportError(f"{out}: export mesh writes a folder (mesh_000000.{args.format} ..., mesh_sequence.usd and "
                          "manifest.json): give a folder name")
    options = MeshOptions(format=args.format, resolution=args.resolution, iso=args.iso, fill=not args.no_fill,
                          color_neighbors=args.color_neighbors, usd=not args.no_usd, fps=args.fps,
                          up_axis=resolve_up_axis(args.up_axis, getattr(args, "provenance", None)),
                          meters_per_unit=args.meters_per_unit, deforming=args.deforming,
                          min_piece_share=0.0 if args.keep_all_pieces else MeshOptions.min_piece_share,
                          reference_time=args.reference_time, uv=args.uv, surface=args.surface)
    if args.reference_time is not None and not args.deforming:
        raise ExportError("--reference-time picks the surface --deforming carries; add --deforming")
    return write_mesh_sequence(model, out, times, options, force=args.force, progress=args.progress)
