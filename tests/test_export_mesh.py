"""Mesh export (`splatreel.export.mesh`): the density field, per-frame surfaces and their files, against the moving
ball of tests/test_export.py, the procedural samples' known motion and the bundled trained model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from splatreel.cli import main
from splatreel.export import frame_times
from splatreel.export.mesh import MeshOptions, write_mesh_sequence
from splatreel.export.surface import Grid, _density_at, density_field, grid_for_box, inverse_covariances

from splatreel.export.usd import PRIM_PATHS

from test_export import BUNDLED_MESH_ATOL, TIMES, VELOCITY, _np, ball, frames, mesh_dir  # noqa: F401  (fixtures)

#: Chamfer distance (share of the object's size) within which the fused surface of each sample's exact model lies
FUSED_BOUND = 0.015

# --- meshes --------------------------------------------------------------------------------------------------

def test_density_field_matches_the_dense_reference(frames):
    f = frames[2]
    live = f.opacities > 0
    box = np.stack([(f.means - f.radii)[live].min(0), (f.means + f.radii)[live].max(0)])
    grid = grid_for_box(box, 12)
    inv = inverse_covariances(f.scales[live], f.quats[live])
    field = density_field(grid, f.means[live], inv, f.opacities[live], f.radii[live])
    ref = _density_at(grid.points(), f.means[live].astype(np.float64), inv, f.opacities[live].astype(np.float64))
    np.testing.assert_allclose(field.reshape(-1), ref, rtol=1e-5, atol=1e-6)
    assert field.max() > 1.0  # overlapping opaque Gaussians: a solid inside
    assert isinstance(grid, Grid) and np.all(field[0] == 0) and np.all(field[:, :, -1] == 0)  # empty margin



def test_meshes_are_closed_outward_and_follow_the_motion(ball, mesh_dir):
    import trimesh

    meshes = [trimesh.load(p) for p in mesh_dir if p.suffix == ".ply"]
    assert len(meshes) == len(TIMES)
    centres = []
    for m in meshes:
        assert m.volume > 0.2 and m.is_watertight  # a ball of radius ~0.5..0.6: outward winding
        # vertex normals point away from the centre
        out = ((m.vertices - m.vertices.mean(0)) * m.vertex_normals).sum(1)
        assert (out > 0).mean() > 0.95
        assert m.visual.vertex_colors.shape == (len(m.vertices), 4)
        centres.append(m.bounds.mean(0))
    # the ball moves by VELOCITY * dt between frames (within a voxel plus the flicker Gaussians' jitter)
    expected = np.asarray(centres[0]) + np.outer(TIMES - TIMES[0], VELOCITY)
    np.testing.assert_allclose(np.asarray(centres), expected, atol=0.06)
    sizes = np.array([m.extents for m in meshes])
    np.testing.assert_allclose(sizes, sizes.mean(0, keepdims=True).repeat(len(meshes), 0), atol=0.08)


def test_meshes_of_a_procedural_sample_follow_its_known_motion(tmp_path):
    import trimesh

    from splatreel.samples import build_model, object_bounds

    # the spinner: a rigid box travelling along an arc while it spins, covered by flat surface Gaussians
    model = build_model("spinner", num_gaussians=6000, frames=5)
    times = frame_times(model.time_range, 3)
    paths = write_mesh_sequence(model, tmp_path / "spinner", times, MeshOptions(resolution=48, usd=False))
    volumes, centres = [], []
    for path, t in zip(paths, times):
        m = trimesh.load(path)
        assert m.is_watertight and m.volume > 0
        box = np.stack(object_bounds("spinner", float(t)))
        np.testing.assert_allclose(m.bounds, box, atol=0.06)  # ~2 voxels: sheet thickness + disc overhang
        volumes.append(m.volume)
        centres.append(m.bounds.mean(0))
    assert np.ptp(volumes) < 0.05 * np.mean(volumes)  # rigid: the (filled) volume does not change
    assert np.linalg.norm(centres[-1] - centres[0]) > 0.4  # and it did travel


@pytest.mark.parametrize("name", ["spinner", "wave", "morph", "texture"])
def test_the_default_fused_surface_lies_closer_to_the_truth_than_the_density_iso_surface(name, tmp_path):
    import trimesh

    from splatreel.samples import build_model
    from splatreel.samples.truth import chamfer

    model = build_model(name, num_gaussians=6000, frames=5)
    times = frame_times(model.time_range, 2)
    distances = {}
    for surface in ("density", MeshOptions().surface):  # the default ('auto') fuses every bounded sample
        paths = write_mesh_sequence(model, tmp_path / surface, times, MeshOptions(resolution=48, usd=False,
                                                                                   surface=surface))
        surface = json.loads(paths[-1].read_text())["surface"]
        meshes = [trimesh.load(p) for p in paths[:len(times)]]
        assert all(m.is_watertight and m.volume > 0 for m in meshes)
        assert all(len(m.split(only_watertight=False)) == 1 for m in meshes)  # no floaters, no inner shells
        distances[surface] = [chamfer(m.vertices, name, float(t)) for m, t in zip(meshes, times)]
        colors = np.concatenate([m.visual.vertex_colors[:, :3] for m in meshes]).astype(float) / 255
        assert colors.std(0).max() > 0.04  # the object's colours (the wave's soft stripes: 0.1), not one grey
    assert max(distances["fused"]) < 0.8 * min(distances["density"]), distances
    assert max(distances["fused"]) < FUSED_BOUND, distances


def test_auto_falls_back_to_the_density_surface_where_fusing_loses_an_open_floor(tmp_path):
    """A signed distance cannot hold an open sheet seen from both sides: on the floor sample the fused surface keeps
    a few per cent of the model's solid parts. The default ('auto') notices on the middle frame, says so in one
    warning and in the manifest, and meshes the density iso-surface, which holds the floor."""
    import trimesh

    from splatreel.samples import build_model

    model = build_model("floor", num_gaussians=6000)
    times = frame_times(model.time_range, 2)
    with pytest.warns(UserWarning, match="using the density iso-surface.*--surface fused forces it"):
        auto = write_mesh_sequence(model, tmp_path / "auto", times, MeshOptions(resolution=48, usd=False))
    forced = write_mesh_sequence(model, tmp_path / "fused", times, MeshOptions(resolution=48, usd=False,
                                                                               surface="fused"))
    assert json.loads(auto[-1].read_text())["surface"] == "density"
    assert "floor" in json.loads(auto[-1].read_text())["surface_reason"]
    assert json.loads(forced[-1].read_text())["surface"] == "fused"
    floor = trimesh.load(auto[0], process=False)
    assert np.ptp(floor.vertices[:, :2], 0).min() > 4.0  # the floor runs across the whole scene
    assert len(trimesh.load(forced[0], process=False).vertices) < 0.2 * len(floor.vertices)


def test_the_bundled_trained_checkpoint_exports_to_usd_and_to_meshes_of_its_object(tmp_path, capsys):
    """End to end on a real trained model (samples/spinner.safetensors, 50k Gaussians): the USD splats are its
    slices, and its meshes have the sample object's known box at each time."""
    import trimesh
    from pxr import Usd, UsdGeom, UsdVol

    from splatreel.checkpoint import load_checkpoint
    from splatreel.samples import object_bounds, trained_checkpoint

    ckpt = trained_checkpoint("spinner")
    model = load_checkpoint(ckpt).model
    usd = tmp_path / "spinner.usdc"
    assert main(["export", "usd", str(ckpt), "--out", str(usd), "--frame-count", "3", "--what", "splats",
                 "--quiet"]) == 0
    stage = Usd.Stage.Open(str(usd))  # keep the stage alive while its prims are read
    assert UsdGeom.GetStageUpAxis(stage) == "Z"  # the sample is +Z up, and its checkpoint says so
    splats = UsdVol.ParticleField3DGaussianSplat(stage.GetPrimAtPath(PRIM_PATHS["splats"]))
    for tc, t in enumerate(frame_times(model.time_range, 3)):
        np.testing.assert_allclose(_np(splats.GetPositionsAttr().Get(tc)), model.slice(float(t)).means.numpy(),
                                   atol=1e-5)
    out = tmp_path / "meshes"
    assert main(["export", "mesh", str(ckpt), "--out", str(out), "--frame-count", "3", "--resolution", "48",
                 "--format", "ply", "--no-usd", "--quiet"]) == 0
    meshes = sorted(out.glob("*.ply"))
    assert len(meshes) == 3
    for path, t in zip(meshes, frame_times(model.time_range, 3)):
        m = trimesh.load(path)
        assert m.is_watertight and m.volume > 0
        # the body is the object's box; a trained model may leave a speck or two of floaters around it
        parts = sorted(m.split(only_watertight=False), key=lambda part: part.area)
        assert sum(part.area for part in parts[:-1]) < 0.01 * m.area
        np.testing.assert_allclose(parts[-1].bounds, np.stack(object_bounds("spinner", float(t))),
                                   atol=BUNDLED_MESH_ATOL)


def test_mesh_sequence_usd_matches_the_frame_files(mesh_dir):
    import trimesh
    from pxr import Usd, UsdGeom

    usd = next(p for p in mesh_dir if p.name == "mesh_sequence.usd")
    stage = Usd.Stage.Open(str(usd))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh"))
    assert mesh.GetSubdivisionSchemeAttr().Get() == "none" and mesh.GetNormalsInterpolation() == "vertex"
    for tc, p in enumerate(p for p in mesh_dir if p.suffix == ".ply"):
        m = trimesh.load(p, process=False)
        np.testing.assert_allclose(_np(mesh.GetPointsAttr().Get(tc)), m.vertices, atol=1e-5)
        np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get(tc)).reshape(-1, 3), m.faces)
        ext = _np(mesh.GetExtentAttr().Get(tc))
        np.testing.assert_allclose(ext, m.bounds, atol=1e-5)
    manifest = json.loads(next(p for p in mesh_dir if p.name == "manifest.json").read_text())
    assert manifest["grid"]["shape"] and manifest["usd"] == "mesh_sequence.usd" and manifest["surface"] == "fused"


@pytest.mark.parametrize("fmt", ["obj", "glb"])
def test_mesh_formats_round_trip_through_trimesh(ball, tmp_path, fmt):
    import trimesh

    paths = write_mesh_sequence(ball, tmp_path / fmt, TIMES[:1], MeshOptions(format=fmt, resolution=24, usd=False))
    assert [p.name for p in paths] == [f"mesh_000000.{fmt}", "manifest.json"]
    m = trimesh.load(paths[0], force="mesh")
    assert m.volume > 0.2 and len(m.visual.vertex_colors) == len(m.vertices)
    # a +Z-up model: the PLY keeps its axes, the GLB/OBJ are turned +Y up, (x, y, z) -> (x, z, -y)
    z_up = write_mesh_sequence(ball, tmp_path / f"{fmt}-z", TIMES[:1],
                               MeshOptions(format=fmt, resolution=24, usd=False, up_axis="Z"))
    ply = write_mesh_sequence(ball, tmp_path / "ply-z", TIMES[:1], MeshOptions(resolution=24, usd=False, up_axis="Z"))
    turned, native = trimesh.load(z_up[0], force="mesh", process=False), trimesh.load(ply[0], process=False)
    want = np.stack([native.vertices[:, 0], native.vertices[:, 2], -native.vertices[:, 1]], 1)
    np.testing.assert_allclose(turned.vertices, want, atol=1e-5)
    assert json.loads(z_up[-1].read_text())["mesh_up_axis"] == "Y"
    assert json.loads(ply[-1].read_text())["mesh_up_axis"] == "Z"


def test_a_frame_below_the_iso_level_gives_an_empty_mesh_in_every_format(ball, tmp_path):
    from pxr import Usd

    for fmt in ("ply", "obj", "glb"):
        paths = write_mesh_sequence(ball, tmp_path / fmt, TIMES[:2], MeshOptions(format=fmt, resolution=16, iso=1e6,
                                                                                 surface="density"))
        assert all(p.stat().st_size > 0 for p in paths)
    stage = Usd.Stage.Open(str(tmp_path / "glb" / "mesh_sequence.usd"))
    assert len(stage.GetPrimAtPath("/World/Mesh").GetAttribute("points").Get(1)) == 0


# --- registry and CLI ----------------------------------------------------------------------------------------


def test_meshes_drop_floaters_unless_asked_to_keep_every_piece(tmp_path):
    """Stray Gaussians (a trained model's floaters; here a small opaque cluster added beside the spinner's model) make
    small blobs beside the object's density iso-surface: the default drops pieces under 2 % of a frame's area,
    --keep-all-pieces keeps them."""
    import dataclasses

    import torch
    import trimesh

    from splatreel.checkpoint import save_checkpoint
    from splatreel.model import static_gaussians4d
    from splatreel.samples import build_model

    model = build_model("spinner")  # native, as the strays are (the bundled trained model is skinned)
    g = torch.Generator().manual_seed(0)
    n = 6
    stray = static_gaussians4d(torch.tensor([0.75, 0.55, 0.45]) + 0.004 * torch.randn(n, 3, generator=g),
                               torch.full((n, 3), 0.012), torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(n, 4),
                               torch.full((n,), 0.99), torch.full((n, 3), 0.5), model.time_range)
    stray = dataclasses.replace(stray, accelerations=None if model.accelerations is None else torch.zeros(n, 3))
    model = dataclasses.replace(model, **{k: torch.cat([v, getattr(stray, k).to(v)]) for k, v in model.tensors().items()})
    ckpt = str(save_checkpoint(tmp_path / "with_floater.safetensors", model, background=(1.0, 1.0, 1.0)))
    counts = {}
    for name, extra in (("clean", []), ("all", ["--keep-all-pieces"])):
        out = tmp_path / name
        assert main(["export", "mesh", ckpt, "--out", str(out), "--frame-count", "12", "--resolution", "64",
                     "--surface", "density", "--no-usd", "--quiet", *extra]) == 0
        counts[name] = [len(trimesh.load(p, process=False).split(only_watertight=False))
                        for p in sorted(out.glob("mesh_*.ply"))]
    assert counts["clean"] == [1] * 12 and max(counts["all"]) > 1
