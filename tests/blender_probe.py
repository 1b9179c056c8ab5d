"""Run inside Blender's Python (the `bpy` module, its own venv): import files the way a person clicks
File > Import (default options) and record what arrived, for tests/test_blender.py.

    python blender_probe.py OUT_DIR FILE [FILE ...]

For each FILE (in a new empty scene) it writes ``OUT_DIR/<i>.npz`` with, per object and per frame (the scene's
first and last), the world-space positions of its points or vertices (modifiers evaluated: MeshSequenceCache
animation), and ``OUT_DIR/<i>.json`` with each object's type, attribute names, instance count and matrix.
A point instancer's points are read with its instancing node group switched off.
"""

import json
import sys
from pathlib import Path

import bpy
import numpy as np

IMPORTERS = {".usd": "usd", ".usda": "usd", ".usdc": "usd", ".usdz": "usd", ".glb": "gltf", ".obj": "obj",
             ".ply": "ply"}


def import_file(path: str) -> None:
    kind = IMPORTERS[Path(path).suffix.lower()]
    if kind == "usd":
        bpy.ops.wm.usd_import(filepath=path)
    elif kind == "gltf":
        bpy.ops.import_scene.gltf(filepath=path)
    elif kind == "obj":
        bpy.ops.wm.obj_import(filepath=path)
    else:
        bpy.ops.wm.ply_import(filepath=path)


def world_positions(obj, depsgraph) -> np.ndarray:
    data = obj.evaluated_get(depsgraph).data
    attr = data.attributes.get("position")
    if attr is None or len(attr.data) == 0:
        return np.zeros((0, 3))
    co = np.zeros(len(attr.data) * 3)
    attr.data.foreach_get("vector", co)
    m = np.array(obj.matrix_world)
    return co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]


def probe(path: str, out: Path, index: int) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    import_file(path)
    scene = bpy.context.scene
    frames = (scene.frame_start, scene.frame_end)
    arrays, objects = {}, []
    for f in frames:
        scene.frame_set(f)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        instances = {}
        for inst in depsgraph.object_instances:
            if inst.is_instance and inst.parent is not None:
                instances[inst.parent.name] = instances.get(inst.parent.name, 0) + 1
        for obj in bpy.data.objects:
            if obj.type not in ("MESH", "POINTCLOUD"):
                continue
            nodes = [m for m in obj.modifiers if m.type == "NODES"]
            for m in nodes:  # an instancer: its points, not the instanced spheres
                m.show_viewport = False
            depsgraph = bpy.context.evaluated_depsgraph_get()
            arrays[f"{obj.name}@{f}"] = world_positions(obj, depsgraph)
            data = obj.evaluated_get(depsgraph).data
            color = data.attributes.get("displayColor")
            if color is not None and len(color.data):
                key = "vector" if color.data_type == "FLOAT_VECTOR" else "color"  # Color3f or RGBA
                width = 3 if key == "vector" else 4
                values = np.zeros(len(color.data) * width)
                color.data.foreach_get(key, values)
                arrays[f"{obj.name}@{f}:displayColor"] = values.reshape(-1, width)[:, :3]
            objects.append({"name": obj.name, "type": obj.type, "frame": f, "instances": instances.get(obj.name, 0),
                            "attributes": sorted(a.name for a in data.attributes),
                            "modifiers": [m.type for m in obj.modifiers],
                            "shape_keys": len(obj.data.shape_keys.key_blocks) if getattr(obj.data, "shape_keys", None)
                            else 0,
                            "images": sorted(Path(n.image.filepath).name for m in obj.data.materials if m and m.node_tree
                                             for n in m.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage"
                                             and n.image),
                            "matrix": np.array(obj.matrix_world).tolist()})
            for m in nodes:
                m.show_viewport = True
    np.savez(out / f"{index}.npz", **arrays)
    (out / f"{index}.json").write_text(json.dumps({"file": path, "frames": frames, "objects": objects,
                                                   "names": [o.name for o in bpy.data.objects]}))


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    out_dir = Path(args[0])
    for i, file in enumerate(args[1:]):
        probe(file, out_dir, i)
