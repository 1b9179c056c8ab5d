"""``export mesh --deforming``: one topology for every frame, carried by the model's own motion, against the
procedural samples' true surfaces (a rigid and a bending one)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from splatreel.export import frame_times
from splatreel.export.mesh import MeshOptions, write_mesh_sequence
from splatreel.samples import build_model, mesh_at

from test_gltf import validate  # noqa: F401  (the Khronos glTF-Validator fixture)

FRAMES = 8


def surface_error(path, name: str, t: float) -> float:
    """Mean two-way distance from the mesh file's vertices to the sample's true surface, as a share of its size."""
    import trimesh
    from scipy.spatial import cKDTree

    mesh = trimesh.load(path, process=False)
    vertices, faces, _ = mesh_at(name, t)
    truth = trimesh.Trimesh(vertices, faces, process=False)
    points = truth.sample(4000, seed=0)
    size = float(np.linalg.norm(truth.bounds[1] - truth.bounds[0]))
    return 0.5 * (cKDTree(mesh.vertices).query(points)[0].mean() + cKDTree(points).query(mesh.vertices)[0].mean()) / size


@pytest.mark.parametrize("name", ["spinner", "wave"])  # rigid (turns and travels), bending
def test_one_topology_follows_the_true_surface_as_closely_as_per_frame_meshes(name, tmp_path):
    import trimesh
    from pxr import Usd, UsdGeom

    model = build_model(name, num_gaussians=12000)
    times = frame_times(model.time_range, FRAMES)
    deforming = write_mesh_sequence(model, tmp_path / "d", times, MeshOptions(resolution=48, deforming=True))
    per_frame = write_mesh_sequence(model, tmp_path / "p", times, MeshOptions(resolution=48, usd=False))
    meshes = [trimesh.load(p, process=False) for p in deforming[:FRAMES]]
    assert all(np.array_equal(m.faces, meshes[0].faces) for m in meshes)  # one topology
    assert np.linalg.norm(meshes[-1].vertices.mean(0) - meshes[0].vertices.mean(0)) > 0.05 or name == "wave"
    errors = [surface_error(p, name, float(t)) for p, t in zip(deforming[:FRAMES], times)]
    reference = [surface_error(p, name, float(t)) for p, t in zip(per_frame[:FRAMES], times)]
    # within 2 % of the object's size of the truth at every time (the fused surfaces; measured 1.6 % spinner, 1.2 %
    # wave), and no more than 0.8 % worse than re-meshing every frame (measured 0.5 %, 0.05 %)
    assert max(errors) < 0.02 and max(e - r for e, r in zip(errors, reference)) < 0.008, (errors, reference)
    manifest = json.loads(deforming[-1].read_text())
    assert manifest["topology"] == "constant (deforming)" and manifest["deforming"]["max_drift"] < 0.02
    # USD: one Mesh, faces authored once (no time samples), points time-sampled at every frame
    stage = Usd.Stage.Open(str(next(p for p in deforming if p.name == "mesh_sequence.usd")))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh"))
    assert mesh.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0
    assert mesh.GetPointsAttr().GetNumTimeSamples() == FRAMES
    np.testing.assert_allclose(np.asarray(mesh.GetPointsAttr().Get(FRAMES - 1)), meshes[-1].vertices, atol=1e-5)
    from test_export import usd_validation_errors

    assert usd_validation_errors(stage.GetRootLayer().realPath) == []


def test_the_cli_takes_a_reference_time_only_with_deforming(tmp_path, capsys):
    from splatreel.checkpoint import save_checkpoint
    from splatreel.cli import main

    ckpt = save_checkpoint(tmp_path / "m.safetensors", build_model("spinner", num_gaussians=3000))
    out = tmp_path / "meshes"
    assert main(["export", "mesh", str(ckpt), "--out", str(out), "--frame-count", "4", "--resolution", "24",
                 "--reference-time", "0.5", "--quiet"]) == 1
    assert "add --deforming" in capsys.readouterr().err
    assert main(["export", "mesh", str(ckpt), "--out", str(out), "--frame-count", "4", "--resolution", "24",
                 "--deforming", "--reference-time", "1", "--quiet"]) == 0
    assert json.loads((out / "manifest.json").read_text())["deforming"]["reference_frame"] == 3


def test_the_morph_target_animation_plays_the_frames_and_validates(tmp_path, validate):
    import pygltflib as gl
    import trimesh

    model = build_model("wave", num_gaussians=6000)
    times = frame_times(model.time_range, 5)
    paths = write_mesh_sequence(model, tmp_path / "d", times,
                                MeshOptions(resolution=32, deforming=True, usd=False, up_axis="Z", fps=10.0))
    glb = next(p for p in paths if p.name == "mesh_animation.glb")
    doc = gl.GLTF2().load(str(glb))
    blob = doc.binary_blob()

    def read(index):
        acc = doc.accessors[index]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc.type]
        view = doc.bufferViews[acc.bufferView]
        return np.frombuffer(blob, np.float32, acc.count * width, view.byteOffset).reshape(acc.count, width)

    prim = doc.meshes[0].primitives[0]
    assert len(prim.targets) == 5 and doc.animations[0].channels[0].target.path == "weights"
    np.testing.assert_allclose(read(doc.animations[0].samplers[0].input)[:, 0], np.arange(5) / 10.0)
    base = read(prim.attributes.POSITION)
    for k, path in enumerate(paths[:5]):  # frame k = base + target k, turned +Y up
        v = trimesh.load(path, process=False).vertices
        want = np.stack([v[:, 0], v[:, 2], -v[:, 1]], 1)
        np.testing.assert_allclose(base + read(prim.targets[k]["POSITION"]), want, atol=1e-5)
    report = validate(glb)[0]
    assert report["numErrors"] == 0 and report["numWarnings"] == 0, report["messages"][:5]


def test_uv_gives_one_atlas_and_a_texture_usd_and_blender_read(tmp_path):
    from pxr import Usd, UsdGeom, UsdShade

    model = build_model("wave", num_gaussians=6000)
    times = frame_times(model.time_range, 4)
    paths = write_mesh_sequence(model, tmp_path / "d", times, MeshOptions(resolution=32, deforming=True, uv=True))
    names = {p.name for p in paths}
    assert {"texture.png", "mesh_sequence.usd"} <= names
    import cv2

    texture = cv2.imread(str(tmp_path / "d" / "texture.png"))
    assert texture.shape == (1024, 1024, 3) and texture.std() > 5  # colours, not an empty image
    stage = Usd.Stage.Open(str(tmp_path / "d" / "mesh_sequence.usd"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Mesh"))
    st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("st")
    uvs = np.asarray(st.Get())
    assert len(uvs) == len(mesh.GetPointsAttr().Get(0)) and uvs.min() >= 0 and uvs.max() <= 1
    assert st.GetInterpolation() == "vertex" and not st.GetAttr().GetNumTimeSamples()  # fixed while vertices move
    material, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    assert material and material.GetPath() == "/World/Looks/Texture"
    from test_export import usd_validation_errors

    assert usd_validation_errors(tmp_path / "d" / "mesh_sequence.usd") == []
    with pytest.raises(Exception, match="add --deforming"):
        MeshOptions(uv=True)


@pytest.mark.parametrize("name, bound", [("spinner", 0.08), ("wave", 0.06)])
def test_vertices_stay_on_their_material_points(name, bound, tmp_path):
    """Correspondence, not only shape: each vertex of the reference frame is pinned to the point of the true surface
    it lies on (barycentric in the sample's own triangle, whose topology is fixed); at every frame the deformed vertex
    must stay near that material point as the object turns or bends. Carrying by local rigid motions in sub-steps
    shorter than the Gaussians' lives keeps it within `bound` of the object's size (measured on fused surfaces: 0.061
    spinner, 0.029 wave); moving vertices by their carriers' mean displacement over whole frame steps slid them up to
    0.23."""
    import trimesh

    from splatreel.samples.truth import material_slide

    model = build_model(name, num_gaussians=12000)
    times = frame_times(model.time_range, FRAMES)
    paths = write_mesh_sequence(model, tmp_path / "d", times, MeshOptions(resolution=48, deforming=True, usd=False))
    ref = json.loads(paths[-1].read_text())["deforming"]["reference_frame"]
    vertices = [trimesh.load(p, process=False).vertices for p in paths[:FRAMES]]
    slides = material_slide(vertices, name, times, ref, samples=100000)
    assert max(slides) < bound, slides


def test_motion_states_follow_the_accelerations_as_the_slice_does():
    from dataclasses import replace

    import torch

    from splatreel.export.deforming import motion_states
    from splatreel.viewer.synthetic import synthetic_model

    model = synthetic_model(300, seed=2, speed=0.4)
    g = torch.Generator().manual_seed(0)
    model = replace(model, accelerations=torch.randn(len(model), 3, generator=g, dtype=model.means.dtype))
    for state, t in zip(motion_states(model, [0.2, 0.9]), (0.2, 0.9)):
        np.testing.assert_allclose(state.means, model.slice(t).means.double().numpy(), atol=1e-5)
