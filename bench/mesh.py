"""Mesh export against the procedural samples' true surfaces: per-frame meshes and one deforming mesh.

    python bench/mesh.py [--json OUT.json] [--samples spinner,wave,morph,texture] [--frames 12] [--resolution 128]
                         [--methods fused,density,deforming-fused,deforming-density] [--bundled-frames 48]

For each sample's exact model (`splatreel.samples.build_model`, 20k Gaussians) and each method (per-frame surfaces
fused from rendered depth, the default; per-frame density iso-surfaces; the deforming mesh on either): the two-way Chamfer
distance to the true surface (mean of both directions' mean nearest distances over 5k surface samples and the mesh's
vertices, as a share of the object's size; mean over frames and worst frame), normal consistency (mean |n · n_true|
of each mesh vertex against its nearest true sample's face normal), vertices, pieces and seconds. For the deforming
mesh also the slide: how far its vertices wander from the material points of the true surface they started on
(tests/test_deforming.py explains the measure).

Then the bundled trained model (samples/spinner.safetensors) through the command line, ``--bundled-frames`` frames at
the default resolution with each method: seconds (the whole command, start-up and mesh_sequence.usd included),
vertices and pieces, and its Chamfer distance to the spinner sample's true surface (which it was trained to show).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def surface_metrics(mesh, name: str, t: float) -> tuple[float, float]:
    import trimesh
    from scipy.spatial import cKDTree

    from splatreel.samples import mesh_at

    vertices, faces, _ = mesh_at(name, t)
    truth = trimesh.Trimesh(vertices, faces, process=False)
    points, face_ids = trimesh.sample.sample_surface_even(truth, 5000, seed=0)
    size = float(np.linalg.norm(truth.bounds[1] - truth.bounds[0]))
    d_mesh, nearest = cKDTree(points).query(mesh.vertices)
    chamfer = 0.5 * (float(cKDTree(mesh.vertices).query(points)[0].mean()) + float(d_mesh.mean())) / size
    consistency = float(np.abs((mesh.vertex_normals * truth.face_normals[face_ids[nearest]]).sum(1)).mean())
    return chamfer, consistency


def slide(meshes, name: str, times, ref: int) -> float:
    from splatreel.samples.truth import material_slide

    return max(material_slide([m.vertices for m in meshes], name, times, ref))


METHODS = ("fused", "density", "deforming-fused", "deforming-density")


def surface_of(method: str) -> str:
    return "density" if method.endswith("density") else "fused"


def run(samples: list[str], frames: int, resolution: int, methods=METHODS) -> list[dict]:
    import trimesh

    from splatreel.export import frame_times
    from splatreel.export.mesh import MeshOptions, write_mesh_sequence
    from splatreel.samples import build_model

    rows = []
    for name in samples:
        model = build_model(name, num_gaussians=20000)
        times = frame_times(model.time_range, frames)
        for method in methods:
            with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                start = time.perf_counter()
                paths = write_mesh_sequence(model, Path(tmp) / "m", times, MeshOptions(
                    resolution=resolution, usd=False, deforming=method.startswith("deforming"),
                    surface=surface_of(method)))
                seconds = time.perf_counter() - start
                meshes = [trimesh.load(p, process=False) for p in paths[:frames]]
                metrics = [surface_metrics(m, name, float(t)) for m, t in zip(meshes, times)]
                row = {"sample": name, "method": method, "frames": frames, "resolution": resolution,
                       "chamfer_mean": round(float(np.mean([c for c, _ in metrics])), 4),
                       "chamfer_worst": round(float(np.max([c for c, _ in metrics])), 4),
                       "normal_consistency": round(float(np.mean([n for _, n in metrics])), 3),
                       "vertices": int(np.mean([len(m.vertices) for m in meshes])),
                       "pieces": int(max(len(m.split(only_watertight=False)) for m in meshes)),
                       "seconds": round(seconds, 1)}
                if method.startswith("deforming"):
                    ref = json.loads(paths[-1].read_text())["deforming"]["reference_frame"]
                    row["slide_worst"] = round(slide(meshes, name, times, ref), 4)
                rows.append(row)
    return rows


def run_bundled(frames: int, methods=METHODS) -> list[dict]:
    """The bundled trained model through ``splatreel export mesh`` (a fresh process per method, as a user runs it)."""
    import subprocess
    import sys

    import trimesh

    from splatreel.checkpoint import load_checkpoint
    from splatreel.export import frame_times
    from splatreel.samples import trained_checkpoint

    ckpt = trained_checkpoint("spinner")
    times = frame_times(load_checkpoint(ckpt).model.time_range, frames)
    rows = []
    for method in methods:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "m"
            cmd = [sys.executable, "-m", "splatreel", "export", "mesh", str(ckpt), "--out", str(out), "--quiet",
                   "--frame-count", str(frames), "--surface", surface_of(method)]
            cmd += ["--deforming"] if method.startswith("deforming") else []
            start = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            seconds = time.perf_counter() - start
            meshes = [trimesh.load(p, process=False) for p in sorted(out.glob("mesh_*.ply"))]
            chamfers = [surface_metrics(m, "spinner", float(t))[0] for m, t in zip(meshes, times)]
            rows.append({"model": "bundled spinner", "method": method, "frames": frames,
                         "chamfer_mean": round(float(np.mean(chamfers)), 4),
                         "chamfer_worst": round(float(np.max(chamfers)), 4),
                         "vertices": int(np.mean([len(m.vertices) for m in meshes])),
                         "pieces": int(max(len(m.split(only_watertight=False)) for m in meshes)),
                         "seconds": round(seconds, 1)})
    return rows


def main() -> None:
    from splatreel.export.mesh import MeshOptions

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", metavar="OUT", help="also write the rows as JSON")
    p.add_argument("--samples", default="spinner,wave,morph,texture")
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--resolution", type=int, default=MeshOptions.resolution)
    p.add_argument("--methods", default=",".join(METHODS),
                   help="fused (TSDF of rendered depth), density (iso-surface), deforming-fused, deforming-density")
    p.add_argument("--bundled-frames", type=int, default=48, help="frames of the bundled model (0: skip it)")
    args = p.parse_args()
    methods = args.methods.split(",")
    rows = run(args.samples.split(","), args.frames, args.resolution, methods)
    print(f"{'sample':<9}{'method':<19}{'chamfer':>9}{'worst':>8}{'normals':>9}{'verts':>7}{'pieces':>7}"
          f"{'slide':>7}{'s':>7}")
    for r in rows:
        print(f"{r['sample']:<9}{r['method']:<19}{r['chamfer_mean']:>9.4f}{r['chamfer_worst']:>8.4f}"
              f"{r['normal_consistency']:>9.3f}{r['vertices']:>7}{r['pieces']:>7}"
              f"{r.get('slide_worst', float('nan')):>7.3f}{r['seconds']:>7.1f}")
    bundled = run_bundled(args.bundled_frames, methods) if args.bundled_frames else []
    if bundled:
        print(f"\nbundled model, {args.bundled_frames} frames, resolution {MeshOptions.resolution}, the whole command")
        print(f"{'method':<19}{'chamfer':>9}{'worst':>8}{'verts':>7}{'pieces':>7}{'s':>7}")
        for r in bundled:
            print(f"{r['method']:<19}{r['chamfer_mean']:>9.4f}{r['chamfer_worst']:>8.4f}{r['vertices']:>7}"
                  f"{r['pieces']:>7}{r['seconds']:>7.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "bundled": bundled}, indent=2) + "\n")


if __name__ == "__main__":
    main()
